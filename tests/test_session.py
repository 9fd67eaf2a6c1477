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
