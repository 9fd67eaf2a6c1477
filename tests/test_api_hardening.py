"""The Python API refuses what it cannot use, whole: `Session.set_state` all or nothing, run and step
inputs that are not finite real numbers, and non-finite results as a `ModelError`."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from prsm_sim import InputError, ModelError, PrsmError, Session, SessionConfig, Simulator, preset
from prsm_sim.actuator import ActuatorParams, Fault, MotorParams
from prsm_sim.errors import NonFiniteStateError


def _session(actuator: bool = True) -> Session:
    act = ActuatorParams(motor=MotorParams()) if actuator else None
    s = Session(preset("s30"), "jones2016", 1e-3, act, interface="velocity" if actuator else "effort")
    for _ in range(5):
        s.step(5.0 if actuator else 0.02, 100.0)
    return s


def _tamper(saved: dict, path: tuple, value) -> dict:
    data = copy.deepcopy(saved)
    d = data
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value
    return data


@pytest.mark.parametrize("path, value, field", [
    (("session", "$dict", "load_n"), {"$float": "nan"}, "session.load_n"),
    (("session", "$dict", "load_n"), "100", "session.load_n"),
    (("session", "$dict", "_paused"), "yes", "session._paused"),
    (("session", "$dict", "nut_position_m"), 1.0, "session.nut_position_m"),
    (("session", "$dict", "fault"), 3, "session.fault"),
    (("gate", "$dict", "value"), {"$float": "inf"}, "gate.value"),
    (("simulator", "$dict", "nut_position_m"), 1.0, "state.nut_position_m"),
    (("simulator", "$dict", "nstep"), -1, "state.nstep"),
])
def test_set_state_checks_the_whole_state_before_changing_anything(path, value, field):
    """Each tampered entry is refused naming its field, and the session is exactly as it was (the
    session-level entries are checked before the simulator's, which once was restored first)."""
    s = _session()
    saved = s.get_state()
    target = _session()
    target.step(1.0, 0.0)
    before = json.dumps(target.get_state(), sort_keys=True)
    with pytest.raises(InputError, match=field.replace(".", r"\.")):
        target.set_state(_tamper(saved, path, value))
    assert json.dumps(target.get_state(), sort_keys=True) == before


def test_set_state_refuses_a_tampered_screw_state_by_field():
    s = _session(actuator=False)
    saved = s.get_state()
    fields = saved["simulator"]["$dict"]["state"]["fields"]
    for name, bad in (("screw_speed_rad_s", "fast"), ("screw_angle_rad", {"$float": "nan"})):
        data = copy.deepcopy(saved)
        data["simulator"]["$dict"]["state"]["fields"][name] = bad
        data["simulator"]["$dict"]["packed"] = None
        fresh = _session(actuator=False)
        with pytest.raises(InputError, match=name):
            fresh.set_state(data)
    assert "screw_speed_rad_s" in fields


def test_set_state_refuses_a_tampered_actuator_state_by_field():
    s = _session()
    data = copy.deepcopy(s.get_state())
    data["simulator"]["$dict"]["state"]["fields"]["brake_engaged"] = "yes"
    with pytest.raises(InputError, match="brake_engaged"):
        _session().set_state(data)


@pytest.mark.parametrize("bad, match", [
    (np.array([1 + 2j, 0.1]), "complex"),
    ([0.1, 1j], "complex"),
    (np.array(["0.1", "0.2"]), "strings"),
    (["0.1"], "strings"),
    (np.array([], dtype=float), "empty"),
    ([], "empty"),
    ([10**400], "numbers"),
    ([True, False], "booleans"),
])
def test_run_refuses_inputs_that_are_not_real_numbers(bad, match):
    sim = Simulator(preset("s30"), "jones2016", 1e-3)
    sim.step(0.01, 0.0)
    before = sim.state
    with pytest.raises(InputError, match=match):
        sim.run(bad)
    with pytest.raises(InputError, match="load_n"):
        sim.run([0.1, 0.1], bad if np.size(bad) else "x")
    assert sim.state is before and sim.nstep == 1


def test_run_with_a_huge_torque_is_a_model_error_and_keeps_the_state():
    """1e308 N·m overflows the step to inf/NaN: refused as a non-finite state, never returned."""
    sim = Simulator(preset("s30"), "jones2016", 1e-3)
    before = sim.state
    with np.errstate(all="ignore"), pytest.raises(ModelError, match="non-finite state"):
        sim.run(np.full(5, 1e308))
    assert sim.state is before and sim.nstep == 0


@pytest.mark.parametrize("value", [10**400, -(10**400), 1 + 0j, "1.0", [1.0], np.array([1.0])])
def test_session_step_refuses_inputs_naming_the_field(value):
    s = _session(actuator=False)
    t = s.time_s
    for kw in ("command", "load_n"):
        with pytest.raises(InputError, match=kw):
            s.step(**{kw: value})
    assert s.time_s == t and s.fault is None


def test_simulator_step_with_a_non_finite_nut_is_a_model_error_and_keeps_the_state():
    sim = Simulator(preset("s30"), "jones2016", 1e-3)
    before = sim.state
    with np.errstate(all="ignore"), pytest.raises(NonFiniteStateError):
        for _ in range(3):
            sim.step(1e308, 0.0)
    assert sim.nstep <= 2 and np.isfinite(sim.state.screw_angle_rad)
    assert before.time_s == 0.0


def test_session_from_config_builds_what_the_constructor_builds():
    act = ActuatorParams(motor=MotorParams())
    cfg = SessionConfig(params=preset("s30"), model="jones2016", dt_s=1e-3, actuator=act,
                        faults=(Fault("friction_surge", start_s=0.001, duration_s=0.002, value=2.0),),
                        interface="velocity", nut_position_m=0.01, load_n=200.0, initial_load_n=200.0,
                        max_effort_nm=20.0, cmd_timeout_s=0.5, timeout_behaviour="hold", paused=True)
    a = Session.from_config(cfg)
    b = Session(cfg.params, cfg.model, cfg.dt_s, ActuatorParams(motor=MotorParams(), faults=cfg.faults),
                nut_position_m=0.01, load_n=200.0, initial_load_n=200.0, interface="velocity",
                max_effort_nm=20.0, cmd_timeout_s=0.5, timeout_behaviour="hold")
    assert a.paused and not b.paused
    b.pause()
    for _ in range(5):
        assert a.step(3.0).scalar_values() == b.step(3.0).scalar_values()
    assert a.status() == b.status()
    with pytest.raises(PrsmError, match="faults"):
        Session.from_config(SessionConfig(params=preset("s30"), faults=cfg.faults))
    with pytest.raises(PrsmError, match="nut_position_m"):
        Session.from_config(SessionConfig(params=preset("s30"), nut_position_m=1.0))
