"""`prsm_sim.Session`: the runtime session every transport drives (gate, load, faults, pause, reset)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prsm_sim import OUTPUT_FIELDS, InputError, ModelError, ParamError, Session, Simulator, preset
from prsm_sim.actuator import ActuatorParams, BrakeParams, MotorParams


def test_step_command_goes_through_the_gate_and_load_is_kept():
    """Oracle: a Simulator given the gated (saturated) torque and the held load step for step."""
    p = preset("s30")
    s = Session(p, "jones2016", 1e-3, max_effort_nm=2.0)
    sim = Simulator(p, "jones2016", 1e-3)
    a, b = s.step(5.0, load_n=100.0), sim.step(2.0, 100.0)  # 5 N·m saturates to the 2 N·m limit
    assert a.scalars() == pytest.approx(b.scalars(), nan_ok=True) and s.gate.counters.saturated == 1
    a, b = s.step(), sim.step(2.0, 100.0)  # command and load kept
    np.testing.assert_array_equal(list(a.scalars().values()), list(b.scalars().values()))
    assert s.status()["counters"]["received"] == 1 and s.nstep == 2 and s.last is a


@pytest.mark.parametrize("kw, field", [({"command": math.nan}, "command"), ({"command": "1"}, "command"),
                                       ({"load_n": math.inf}, "load_n"), ({"load_n": True}, "load_n")])
def test_bad_step_input_names_the_field_and_changes_nothing(kw, field):
    s = Session(preset("s30"), "ideal", 1e-3)
    with pytest.raises(InputError, match=f"^{field} = ") as e:
        s.step(**kw)
    assert "\n" not in str(e.value) and s.nstep == 0 and s.gate.counters.received == 0 and s.fault is None


def test_gate_limits_refused_as_param_errors():
    with pytest.raises(ParamError, match="max_effort_nm = -1"):
        Session(preset("s30"), "ideal", 1e-3, max_effort_nm=-1)
    with pytest.raises(ParamError, match="timeout_behaviour = 'coast'"):
        Session(preset("s30"), "ideal", 1e-3, timeout_behaviour="coast")
    with pytest.raises(ParamError, match="bare model"):
        Session(preset("s30"), "ideal", 1e-3, interface="velocity")


def test_model_failure_is_a_model_error_held_until_reset():
    p = preset("s30").with_overrides({"mass.moved_mass_kg": 1e-300, "mass.screw_inertia_kgm2": 0.0,
                                      "mass.roller_mass_kg": 0.0, "mass.roller_inertia_kgm2": 0.0})
    s = Session(p, "fu2018", 1e-3)
    with pytest.raises(ModelError, match="non-finite state"):
        s.step(1.0)
    assert s.status()["fault"] == s.fault and s.time_s == 0.0
    s.reset()
    assert s.fault is None


@pytest.mark.parametrize("model", ["jones2016", "elastic"])
def test_rest_outputs_with_an_actuator_describe_the_reset_state(model):
    """At rest after a reset: the nut where it was put, the sensors' last reading in the measured block,
    the stored energy that of a screw at rest (zero), and the measured joint state readable from it."""
    a = ActuatorParams(motor=MotorParams(), brake=BrakeParams(holding_torque_nm=5.0))
    s = Session(preset("s30"), model, 1e-3, a, nut_position_m=0.02, load_n=50.0, interface="velocity")
    for _ in range(3):
        s.step(5.0)
    s.reset()
    out = s.last
    assert out is not None and not s.stepped and out.time_s == 0.0
    assert set(out.scalars()) == {f for f, _ in OUTPUT_FIELDS} and out.internal.shape == (s.layout.size,)
    assert out.nut_position_m == pytest.approx(0.02) and out.nut_force_n == 50.0 and out.stored_energy_j == 0.0
    measured = s.actuator.measured(out)
    assert measured.nut_position_m == pytest.approx(0.02) and measured.screw_speed_rad_s == 0.0


def test_pause_and_status_are_plain_data():
    import json
    s = Session(preset("s30"), "ideal", 1e-3, ActuatorParams(motor=MotorParams()))
    s.pause()
    assert s.paused and json.loads(json.dumps(s.status()))["paused"] is True
    s.resume()
    assert not s.paused


# One process saves a session mid-run (a drive fault active, the brake engaged, noisy delayed
# sensors, the watchdog armed); another builds the same session fresh, restores the JSON and
# continues. Both print the continued outputs' bytes: equal bytes are equal runs, bit for bit.
_SESSION_SCRIPT = r'''
import json, sys
import numpy as np
from prsm_sim import Session, preset
from prsm_sim.actuator import ActuatorParams, BrakeParams, Fault, MotorParams, SensorParams

model, role, path = sys.argv[1:4]
act = ActuatorParams(motor=MotorParams(), brake=BrakeParams(holding_torque_nm=5.0),
                     sensors=SensorParams(load_cell_noise_n=2.0, latency_steps=2, encoder_counts_per_rev=4096, seed=7))
s = Session(preset("s30"), model, 1e-3, act, interface="velocity", load_n=300.0, cmd_timeout_s=0.05)
if role == "save":
    for i in range(15):
        s.step(30.0 + i)
    assert s.inject(Fault("drive_fault", start_s=s.time_s, duration_s=0.02)) is None
    assert s.brake(True) is None
    for i in range(4):
        s.step()
    with open(path, "w") as f:
        json.dump(s.get_state(), f, allow_nan=False)  # strict JSON
else:
    with open(path) as f:
        s.set_state(json.load(f))
rows = []
for i in range(40):  # through the fault's end, a brake release and a load change
    if i == 25:
        assert s.brake(False) is None
    out = s.step(10.0 + 0.5 * i, load_n=250.0 if i >= 30 else None)
    rows.append(np.array(out.scalar_values()).tobytes().hex() + out.internal.tobytes().hex())
rows.append(json.dumps(s.status(), sort_keys=True) + repr(s.take_events()))
print("\n".join(rows))
'''


@pytest.mark.slow
@pytest.mark.parametrize("model", ["fu2018", "elastic"])
def test_state_saved_as_json_in_one_process_continues_bit_for_bit_in_another(model, tmp_path):
    """Oracle: the run itself — the saving process continues too; the restoring one must print the same bytes."""
    import subprocess
    import sys

    path = tmp_path / "state.json"

    def run(role):
        r = subprocess.run([sys.executable, "-c", _SESSION_SCRIPT, model, role, str(path)], capture_output=True,
                           text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        return r.stdout.splitlines()

    saved = run("save")
    restored = run("restore")
    assert len(saved) == 41 and "drive_fault" in saved[-1]
    assert restored == saved


def test_set_state_refuses_another_session_and_foreign_records():
    s = Session(preset("s30"), "ideal", 1e-3)
    s.step(1.0)
    data = s.get_state()
    with pytest.raises(InputError, match="state model = 'ideal': this session has model = 'jones2016'"):
        Session(preset("s30"), "jones2016", 1e-3).set_state(data)
    with pytest.raises(InputError, match="state actuator = False"):
        Session(preset("s30"), "ideal", 1e-3, ActuatorParams()).set_state(data)
    # a record type the state cannot hold is never looked up, whatever its name
    bad = dict(data, simulator=dict(data["simulator"]))
    bad["simulator"]["$dict"] = dict(bad["simulator"]["$dict"], state={"$dc": "os.system", "fields": {}})
    fresh = Session(preset("s30"), "ideal", 1e-3)
    with pytest.raises(InputError, match="record type 'os.system' is not one this state holds") as e:
        fresh.set_state(bad)
    assert "\n" not in str(e.value) and fresh.nstep == 0
    fresh.set_state(data)
    assert fresh.nstep == 1
    np.testing.assert_array_equal(fresh.last.scalar_values(), s.last.scalar_values())  # NaN == NaN here


@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018", "elastic"])
def test_simulator_state_round_trips_through_json_bit_for_bit(model):
    """Oracle: the simulator that saved continues beside the restored one; every output is identical."""
    import json
    a = Simulator(preset("s30"), model, 1e-3)
    for i in range(30):
        a.step(3.0, 200.0 + i)
    b = Simulator(preset("s30"), model, 1e-3)
    b.set_state(json.loads(json.dumps(a.get_state(), allow_nan=False)))
    for i in range(30):
        x, y = a.step(1.0 - 0.1 * i, 150.0), b.step(1.0 - 0.1 * i, 150.0)
        assert np.array(x.scalar_values()).tobytes() == np.array(y.scalar_values()).tobytes()
        assert x.internal.tobytes() == y.internal.tobytes()
    assert b.nstep == a.nstep == 60


def test_reset_keeps_the_load_unless_an_initial_load_is_given():
    s = Session(preset("s30"), "ideal", 1e-3, load_n=10.0)
    s.step(load_n=20.0)
    s.reset()
    assert s.load_n == 20.0
    s = Session(preset("s30"), "ideal", 1e-3, load_n=10.0, initial_load_n=5.0)
    s.step(load_n=20.0)
    s.reset(nut_position_m=0.01)
    assert s.load_n == 5.0 and s.time_s == 0.0 and s.rest_outputs().nut_position_m == pytest.approx(0.01)


@pytest.mark.parametrize("model, kernel, actuator", [("fu2018", "compiled", False), ("fu2018", "reference", False),
                                                     ("jones2016", "compiled", True)])
def test_simulator_undo_returns_to_the_state_before_the_last_step(model, kernel, actuator):
    """Oracle: a twin simulator that never took the undone step; the run after the undo matches it bit for bit."""
    p, a = preset("s30"), ActuatorParams(motor=MotorParams()) if actuator else None
    sim, twin = Simulator(p, model, 1e-3, actuator=a, kernel=kernel), Simulator(p, model, 1e-3, actuator=a, kernel=kernel)
    with pytest.raises(InputError, match="^undo: no step to undo"):
        sim.undo()
    for _ in range(3):
        sim.step(0.5, 100.0), twin.step(0.5, 100.0)
    sim.step(-3.0, 900.0)
    sim.undo()
    assert sim.nstep == 3 and sim.time_s == twin.time_s and sim.state == twin.state
    with pytest.raises(InputError, match="^undo: no step to undo"):  # once
        sim.undo()
    a_out, b_out = sim.step(0.5, 100.0), twin.step(0.5, 100.0)
    np.testing.assert_array_equal(list(a_out.scalars().values()), list(b_out.scalars().values()))
    sim.reset()
    with pytest.raises(InputError, match="^undo: no step to undo"):  # a new state is no step
        sim.undo()


@pytest.mark.parametrize("model", ["fu2018", "elastic"])
@pytest.mark.parametrize("field", ["screw_angle_rad", "screw_speed_rad_s", "carrier_angle_rad", "carrier_speed_rad_s",
                                   "nut_force_n"])
def test_state_is_finite_checks_each_state_scalar(model, field):
    """Oracle: math.isfinite on each field. The packed record (the node's per-step path) and a plain
    `Outputs` agree; values near the float limit are finite (no overflow in the test)."""
    from dataclasses import replace

    from prsm_sim.session import state_is_finite
    from prsm_sim.stepping.packed import PackedOutputs
    packed = Simulator(preset("s30"), model, 1e-3).step(0.5, 100.0)
    assert type(packed) is PackedOutputs and state_is_finite(packed) and state_is_finite(packed.to_outputs())
    index = {"screw_angle_rad": 1, "screw_speed_rad_s": 2, "carrier_angle_rad": 3, "carrier_speed_rad_s": 4}
    for value, finite in ((math.inf, False), (-math.inf, False), (math.nan, False), (1.7e308, True)):
        plain = replace(packed.to_outputs(), **{field: value})
        assert state_is_finite(plain) is finite
        if field in index:  # the record's state part, as the next step would read it
            rec = PackedOutputs(packed[:index[field]] + (value,) + packed[index[field] + 1:])
        else:
            rec = PackedOutputs(packed[:17] + (value,) + packed[18:])
        assert getattr(rec, field) == value or math.isnan(value)
        assert state_is_finite(rec) is finite
    internal = packed.to_outputs().internal.copy()
    internal[-1] = math.nan
    assert not state_is_finite(replace(packed.to_outputs(), internal=internal))  # a plain record's loads count too


@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018", "elastic"])
def test_stepping_builds_no_state_from_the_packed_record(model):
    """The per-step path reads time and finiteness off the packed record: `State` is built only
    when someone reads `simulator.state` (counted on the model's unpack_state)."""
    s = Session(preset("s30"), model, 1e-3, load_n=100.0)
    unpack = s.simulator.model.unpack_state
    calls = []
    s.simulator.model.unpack_state = lambda x: calls.append(1) or unpack(x)
    s.offer("effort", 0.5)
    for _ in range(5):
        s.step()
    s.step(0.25, 50.0)
    assert not calls and s.nstep == 6
    assert s.simulator.state.time_s == s.time_s and len(calls) == 1
