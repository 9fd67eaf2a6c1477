"""prsm-fmu: the actuator as FMI 2.0 and 3.0 co-simulation FMUs, driven through fmpy.

Oracle: the library itself. An FMU's slave is a `Session`, so the FMU's outputs under a prescribed
input must equal, bit for bit, a `Session.step` loop on the same inputs (held over each
communication step of K model steps), and lie within 1e-12 of `Simulator.run` on the same
sequence (the batch path, equal to rounding). fmpy's `validate_fmu` and
`read_model_description(validate=True)` are the independent check of the model descriptions.
Building an FMU takes about two seconds: one FMI 2.0 and one FMI 3.0 FMU run by default, the
whole matrix (s30; fu2018 and elastic; bare and an actuator in velocity mode) in the slow tier.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path
from time import time_ns

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.simulation import instantiate_fmu
from fmpy.validation import validate_fmu

import prsm_sim
from prsm_sim import ParamError, Session, Simulator, __version__, preset
from prsm_sim.actuator import ACTUATOR_QUANTITIES, ActuatorParams, DriveParams, Fault, MotorParams, StopParams
from prsm_ros.fmu.build import build_fmu
from prsm_ros.fmu.cli import main as cli_main
from prsm_ros.fmu.config import CONFIG_NAME, make_config, session_from_config
from prsm_ros.fmu.core import SlaveCore
from prsm_ros.fmu.driver import OK, FmuDriver

DT = 1e-3
K = 3  # model steps per communication step
N = 40  # communication steps
LOAD_N = 300.0
FMI_DISCARD, FMI_ERROR = 2, 3
COMMAND = {"effort": "screw_torque_nm", "velocity": "screw_speed_command_rad_s"}


def commands(interface: str) -> np.ndarray:
    """A prescribed command: steps and reversals (N·m, or screw rad/s in velocity mode)."""
    k = np.arange(N)
    if interface == "effort":
        return np.where(k < 5, 0.0, 2.5) - np.where(k > 25, 3.5, 0.0) + 0.25 * np.sin(0.7 * k)
    return np.where(k < 5, 0.0, 40.0) - np.where(k > 25, 70.0, 0.0)


def loads() -> np.ndarray:
    return LOAD_N + 50.0 * np.cos(0.3 * np.arange(N))


def actuator_for(case: str) -> ActuatorParams | None:
    return None if case == "bare" else ActuatorParams(motor=MotorParams())


def config_for(model: str, case: str, fmi: int = 2, **kw) -> dict:
    interface = "effort" if case == "bare" else "velocity"
    return make_config(preset("s30"), model, DT, actuator_for(case), interface=interface, load_n=LOAD_N, fmi=fmi,
                       preset_name="s30", **kw)


def expected_outputs(session: Session) -> dict[str, float]:
    """The FMU's outputs recomputed from the session's last Outputs (independently of prsm_ros.fmu.core)."""
    out = session.last
    row = {n: getattr(out, n) for n in ("nut_position_m", "nut_velocity_m_s", "nut_force_n", "screw_angle_rad",
                                        "screw_speed_rad_s", "efficiency", "energy_residual_j")}
    lay = session.layout
    names = {b.name for b in lay.blocks}
    if "per_tooth" in names:
        row["peak_tooth_load_n"] = float(np.abs(lay.view(out.internal, "per_tooth")).max())
        roller = lay.view(out.internal, "per_roller")[:, :2]  # screw and nut normal forces lead the block
        row["peak_roller_load_n"] = float(np.abs(roller).max())
    if session.actuator is not None:
        a = dict(zip((n for n, _ in ACTUATOR_QUANTITIES), lay.view(out.internal, "actuator")))
        m = lay.view(out.internal, "measured")
        row.update(motor_current_a=a["motor_current_a"], motor_torque_nm=a["motor_torque_nm"],
                   stop_force_n=a["stop_force_n"], measured_screw_angle_rad=m[1], measured_screw_speed_rad_s=m[2],
                   measured_nut_position_m=m[3], measured_nut_velocity_m_s=m[4], measured_nut_force_n=m[5])
    return {k: float(v) for k, v in row.items()}


def session_loop(config: dict, cmd: np.ndarray, load: np.ndarray, k: int = K) -> list[dict[str, float]]:
    """The oracle: `Session.step` with the inputs held over each communication step."""
    s = session_from_config(config)
    rows = []
    for u, f in zip(cmd.tolist(), load.tolist()):
        for _ in range(k):
            s.step(u, f)
        rows.append(expected_outputs(s))
    return rows


def assert_rows_equal(got: list[dict], want: list[dict]) -> None:
    assert len(got) == len(want)
    for i, (g, w) in enumerate(zip(got, want)):
        for name, value in w.items():
            # bit for bit; NaN (efficiency undefined) equals NaN
            assert g[name] == value or (math.isnan(g[name]) and math.isnan(value)), (i, name, g[name], value)


# -- the slave logic, without building an FMU ----------------------------------------------------------
def make_core(tmp_path, config: dict):
    res = tmp_path / "resources"
    res.mkdir(parents=True, exist_ok=True)
    (res / CONFIG_NAME).write_text(json.dumps(config), encoding="utf-8")
    logs: list[tuple[str, str]] = []
    core = SlaveCore(str(res), lambda msg, status: logs.append((status, msg)))
    core.enter_initialization()  # as an importer does before its first doStep
    core.exit_initialization()
    return core, logs


def core_run(core: SlaveCore, cmd, load, k: int = K, t0: int = 0) -> list[dict[str, float]]:
    names = [v.name for v in core.variables if v.causality == "output"]
    rows = []
    for i, (u, f) in enumerate(zip(cmd.tolist(), load.tolist())):
        core.set(core.command_name, u)
        core.set("load_force_n", f)
        assert core.do_step((t0 + i) * k * DT, k * DT) is None
        rows.append({n: core.get(n) for n in names})
    return rows


@pytest.mark.parametrize("case", ["bare", "velocity"])
def test_substeps_equal_a_session_loop(tmp_path, case):
    cfg = config_for("fu2018", case)
    core, logs = make_core(tmp_path, cfg)
    interface = "effort" if case == "bare" else "velocity"
    assert_rows_equal(core_run(core, commands(interface), loads()), session_loop(cfg, commands(interface), loads()))
    assert logs == []


def test_an_fmu_built_with_a_load_starts_in_equilibrium_under_it(tmp_path):
    """Oracle: static equilibrium (docs/model.md §4.4, starting in equilibrium): the frictionless holding
    torque F L/2π keeps the thread force within 1 % of F from the first step; a drive in the FMU's
    velocity interface starts holding that torque itself (its speed integrator), whatever the actuator's
    drive.mode (here the default, effort): a zero speed command keeps the thread force within 1 % of F."""
    f = 2000.0
    p = preset("s30")
    core, logs = make_core(tmp_path / "bare", make_config(p, "elastic", DT, None, interface="effort", load_n=f))
    assert core.get("load_force_n") == f
    core.set("screw_torque_nm", p.geometry.lead_per_rad_m * f)
    forces = []
    for i in range(50):
        assert core.do_step(i * DT, DT) is None
        forces.append(core.get("nut_force_n"))
    assert np.max(np.abs(np.array(forces) / f - 1.0)) < 0.01
    cfg = make_config(p, "elastic", DT, ActuatorParams(motor=MotorParams()), interface="velocity", load_n=f)
    assert cfg["actuator"]["drive"]["mode"] == "effort"  # the actuator as given: the interface decides
    core, logs = make_core(tmp_path / "velocity", cfg)
    assert core.session.simulator.state.integral_nm == pytest.approx(p.geometry.lead_per_rad_m * f, rel=1e-12)
    core.set("screw_speed_command_rad_s", 0.0)
    forces = []
    for i in range(100):
        assert core.do_step(i * DT, DT) is None
        forces.append(core.get("nut_force_n"))
    assert np.max(np.abs(np.array(forces) / f - 1.0)) < 0.01
    assert logs == []


def test_a_step_that_is_not_a_whole_multiple_is_refused(tmp_path):
    core, logs = make_core(tmp_path, config_for("jones2016", "bare"))
    reason = core.do_step(0.0, 1.5 * DT)
    assert reason is not None and "whole multiple" in reason and "0.0015" in reason
    assert logs == [("error", reason)]
    assert core.session.nstep == 0  # nothing stepped
    for h in (0.0, -DT, math.nan, math.inf):
        assert core.do_step(0.0, h) is not None
    assert core.do_step(0.0, 2 * DT) is None and core.session.nstep == 2


def test_nan_input_is_refused_by_name_and_the_step_fails_until_a_valid_value(tmp_path):
    cfg = config_for("jones2016", "bare")
    core, logs = make_core(tmp_path, cfg)
    core.set("screw_torque_nm", math.nan)
    assert logs and logs[0][0] == "error" and "screw_torque_nm = nan" in logs[0][1]
    reason = core.do_step(0.0, DT)
    assert reason is not None and "screw_torque_nm = nan" in reason and core.session.nstep == 0
    core.set("load_force_n", -math.inf)
    assert "load_force_n = -inf" in logs[-1][1]
    core.set("screw_torque_nm", 1.0)
    core.set("load_force_n", LOAD_N)
    assert core.do_step(0.0, DT) is None  # the refused values never reached the session
    assert_rows_equal([{n: core.get(n) for n in expected_outputs(core.session)}],
                      session_loop(cfg, np.array([1.0]), np.array([LOAD_N]), k=1))


def test_bad_parameters_are_refused_by_name_and_nothing_changes(tmp_path):
    core, logs = make_core(tmp_path, config_for("jones2016", "velocity"))
    kp = core.get("drive_speed_kp_nm_s_rad")
    for name, value in (("drive_speed_kp_nm_s_rad", -1.0), ("max_effort_nm", 0.0), ("motor_torque_limit_nm", math.nan),
                        ("drive_speed_limit_rad_s", math.inf)):
        core.set(name, value)
        assert logs[-1][0] == "error" and f"{name} = {value!r}" in logs[-1][1], logs[-1]
        assert core.do_step(0.0, DT) is not None
    assert core.get("drive_speed_kp_nm_s_rad") == kp == core.session.actuator.drive.speed_kp_nm_s_rad
    assert core.get("max_effort_nm") == 50.0 == core.session.gate.max_effort_nm
    for name in ("drive_speed_kp_nm_s_rad", "max_effort_nm", "motor_torque_limit_nm", "drive_speed_limit_rad_s"):
        core.set(name, core.get(name))  # valid values clear the refusals
    assert core.do_step(0.0, DT) is None


def test_tunable_parameters_act_as_the_library_built_with_them(tmp_path):
    cfg = config_for("jones2016", "velocity")
    core, logs = make_core(tmp_path, cfg)
    kp, ki = 2.0 * core.get("drive_speed_kp_nm_s_rad"), core.get("drive_speed_ki_nm_rad")
    core.set("drive_speed_kp_nm_s_rad", kp)  # the other gains keep the values they were tuned to
    core.set("motor_torque_limit_nm", 4.0)
    cmd = commands("velocity")
    got = core_run(core, cmd, loads())
    drive = DriveParams(mode="velocity", speed_kp_nm_s_rad=kp, speed_ki_nm_rad=ki)
    want_cfg = make_config(preset("s30"), "jones2016", DT, ActuatorParams(motor=MotorParams(torque_limit_nm=4.0),
                                                                         drive=drive),
                           interface="velocity", load_n=LOAD_N)
    assert_rows_equal(got, session_loop(want_cfg, cmd, loads()))
    assert logs == []


def test_effort_limit_is_tunable(tmp_path):
    cfg = config_for("jones2016", "bare")
    core, _ = make_core(tmp_path, cfg)
    core.set("max_effort_nm", 1.0)
    got = core_run(core, commands("effort"), loads())
    want = session_loop(config_for("jones2016", "bare", max_effort_nm=1.0), commands("effort"), loads())
    assert_rows_equal(got, want)


def test_model_failure_fails_the_step_with_its_reason(tmp_path):
    core, logs = make_core(tmp_path, config_for("fu2018", "bare", max_effort_nm=1e300))
    core.set("screw_torque_nm", 1e300)
    core.set("load_force_n", 1e300)
    reason = core.do_step(0.0, DT)
    assert reason is not None and "model failure" in reason and "non-finite state" in reason
    assert logs[-1] == ("error", reason)
    assert core.do_step(DT, DT) is not None  # stays failed until reset (a new instance)


def test_a_configuration_of_another_prsm_version_is_refused_naming_both(tmp_path):
    cfg = dict(config_for("jones2016", "bare"), prsm_version="0.0.1")
    with pytest.raises(ParamError, match=rf"built by prsm 0\.0\.1.* has prsm {__version__}"):
        make_core(tmp_path, cfg)


def test_state_round_trip_continues_bit_for_bit_in_a_new_instance(tmp_path):
    cfg = config_for("fu2018", "velocity")
    core, _ = make_core(tmp_path / "a", cfg)
    cmd, load = commands("velocity"), loads()
    core.set("drive_speed_kp_nm_s_rad", 1.5 * core.get("drive_speed_kp_nm_s_rad"))  # tunables travel too
    core_run(core, cmd[:15], load[:15])
    saved = json.dumps(core.get_state())
    want = core_run(core, cmd[15:], load[15:], t0=15)
    other, logs = make_core(tmp_path / "b", cfg)
    other.set_state(json.loads(saved))
    assert logs == [] and other.tunables == core.tunables
    assert_rows_equal(core_run(other, cmd[15:], load[15:], t0=15), want)


def test_a_foreign_state_is_refused_and_fails_the_step(tmp_path):
    core, logs = make_core(tmp_path, config_for("jones2016", "bare"))
    core.set_state({"format": "something else"})
    assert logs[-1][0] == "error" and "not a prsm FMU state" in logs[-1][1]
    assert core.do_step(0.0, DT) is not None


def test_cli_refuses_bad_options_in_one_line_exit_2(tmp_path, capsys):
    cases = [(["--actuator", "{motor: {bogus: 1}}", "--command-interface", "velocity"], "motor.bogus"),
             (["--dt", "0"], "dt_s"),
             (["--max-effort", "-1"], "max_effort_nm")]
    for extra, needle in cases:
        assert cli_main(["build", "--preset", "s30", *extra, "-o", str(tmp_path / "x.fmu")]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "x.fmu").exists()


# -- built FMUs through fmpy ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    """Build each FMU once per module: (fmi, model, case) → (path, config)."""
    built: dict = {}
    root = tmp_path_factory.mktemp("fmus")

    def get(fmi: int, model: str, case: str):
        key = (fmi, model, case)
        if key not in built:
            cfg = config_for(model, case, fmi=fmi)
            built[key] = (build_fmu(cfg, root / f"{model}_{case}_fmi{fmi}.fmu"), cfg)
        return built[key]
    return get


def fmu_run(drv: FmuDriver, interface: str, cmd, load, t0: int = 0, k: int = K) -> list[dict[str, float]]:
    outs = [v.name for v in drv.description.modelVariables if v.causality == "output"]
    out_refs, in_refs = drv.refs(outs), drv.refs([COMMAND[interface], "load_force_n"])
    rows = []
    for i, (u, f) in enumerate(zip(cmd.tolist(), load.tolist())):
        drv.set(in_refs, [u, f])
        assert drv.do_step((t0 + i) * k * DT, k * DT) == OK, drv.messages
        rows.append(dict(zip(outs, drv.get(out_refs))))
    return rows


def check_fmu(fmus, fmi: int, model: str, case: str) -> None:
    path, cfg = fmus(fmi, model, case)
    assert validate_fmu(str(path)) == []
    interface = "effort" if case == "bare" else "velocity"
    cmd, load = commands(interface), loads()
    with FmuDriver(path) as drv:
        assert float(drv.description.defaultExperiment.stepSize) == DT
        got = fmu_run(drv, interface, cmd, load)
    assert_rows_equal(got, session_loop(cfg, cmd, load))
    # the batch path of the library, same inputs held K steps each: equal to rounding
    actuator = None if case == "bare" else session_from_config(cfg).actuator_params
    sim = Simulator(preset("s30"), model, DT, actuator=actuator, initial_load_n=LOAD_N)  # the FMU starts loaded
    if case != "bare":
        sim.state = sim.model.set_mode(sim.state, "velocity")
    traj = sim.run(np.repeat(cmd, K), np.repeat(load, K))
    for name in ("nut_position_m", "nut_velocity_m_s", "nut_force_n", "screw_angle_rad", "screw_speed_rad_s"):
        col = traj[name][K - 1::K]
        np.testing.assert_allclose([r[name] for r in got], col, rtol=1e-12, atol=1e-12 * np.abs(col).max())


def test_fmi2_fu2018_bare_equals_the_library(fmus):
    check_fmu(fmus, 2, "fu2018", "bare")


@pytest.mark.slow
def test_fmi3_elastic_velocity_actuator_equals_the_library(fmus):
    check_fmu(fmus, 3, "elastic", "velocity")


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
@pytest.mark.parametrize("model", ["fu2018", "elastic"])
@pytest.mark.parametrize("case", ["bare", "velocity"])
def test_fmu_matrix_equals_the_library(fmus, fmi, model, case):
    check_fmu(fmus, fmi, model, case)


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_fmu_state_get_set_serialise_continue_bit_for_bit(fmus, fmi):
    path, cfg = fmus(fmi, "fu2018", "bare")
    cmd, load = commands("effort"), loads()
    with FmuDriver(path) as a, FmuDriver(path) as b:
        fmu_run(a, "effort", cmd[:15], load[:15])
        state = a.get_state()
        data = a.serialize(state)
        want = fmu_run(a, "effort", cmd[15:], load[15:], t0=15)
        a.set_state(state)  # back in the same instance
        assert_rows_equal(fmu_run(a, "effort", cmd[15:], load[15:], t0=15), want)
        a.free_state(state)
        b.set_state(b.deserialize(data))  # into another instance, from bytes
        assert_rows_equal(fmu_run(b, "effort", cmd[15:], load[15:], t0=15), want)
    assert_rows_equal(want, session_loop(cfg, cmd, load)[15:])


@pytest.mark.parametrize("fmi", [2, 3])
def test_fmu_refuses_nan_and_bad_parameters_with_a_status_and_a_message(fmus, fmi):
    path, cfg = fmus(fmi, "fu2018", "bare")
    failed = FMI_ERROR if fmi == 3 else FMI_DISCARD  # pythonfmu 0.7: a failed doStep is fmi2Discard
    with FmuDriver(path) as drv:
        torque, load_ref, effort = drv.refs(["screw_torque_nm", "load_force_n", "max_effort_nm"])
        drv.set([torque], [math.nan])
        assert any("screw_torque_nm = nan" in m for _, m in drv.messages), drv.messages
        assert drv.do_step(0.0, DT) == failed
        drv.set([effort], [-2.0])
        assert any("max_effort_nm = -2.0" in m and "max_effort_nm" in m for _, m in drv.messages)
        assert drv.do_step(0.0, DT) == failed
        assert drv.do_step(0.0, 1.5 * DT) == failed
        drv.set([torque, load_ref, effort], [1.0, LOAD_N, 50.0])
        assert drv.do_step(0.0, DT) == OK  # nothing refused reached the session
        assert drv.get(drv.refs(["nut_position_m"])) == [session_loop(cfg, np.array([1.0]), np.array([LOAD_N]), k=1)[0]
                                                        ["nut_position_m"]]
        drv.reset()  # a new session: back at rest
        assert drv.get(drv.refs(["nut_position_m", "screw_speed_rad_s"])) == [0.0, 0.0]
        assert drv.do_step(0.0, DT) == OK


def test_an_fmu_of_another_prsm_version_is_refused_at_instantiation(fmus, tmp_path):
    path, _ = fmus(2, "fu2018", "bare")
    other = tmp_path / "old.fmu"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(other, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == f"resources/{CONFIG_NAME}":
                data = json.dumps(dict(json.loads(data), prsm_version="0.0.1")).encode()
            dst.writestr(item, data)
    messages = []
    md = read_model_description(str(other))
    with pytest.raises(Exception, match="instantiate"):
        instantiate_fmu(extract(str(other)), md, debug_logging=True,
                        logger=lambda *a: messages.append(a[-1].decode()))
    assert any("built by prsm 0.0.1" in m and f"has prsm {__version__}" in m for m in messages), messages


@pytest.mark.slow
def test_cli_builds_an_fmu_that_validates(tmp_path):
    out = tmp_path / "cli.fmu"
    r = subprocess.run([sys.executable, "-m", "prsm_ros.fmu.cli", "build", "--fmi", "3", "--preset", "s30",
                        "--model", "jones2016", "--command-interface", "position", "--actuator", "{motor: {}}",
                        "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert validate_fmu(str(out)) == []
    with FmuDriver(out) as drv:
        assert "nut_position_command_m" in drv.vr and "screw_torque_nm" not in drv.vr
        config = json.loads(zipfile.ZipFile(out).read(f"resources/{CONFIG_NAME}"))
        assert config["model"] == "jones2016" and config["session"]["interface"] == "position"
        assert config["prsm_version"] == __version__ == drv.description.version


@pytest.mark.slow
def test_fmi2_fmu_runs_in_a_host_without_python_given_libpython_home_and_path(fmus, tmp_path):
    """A 60-line C importer (tests/fmu_c_host.c) with no Python of its own: the FMU needs libpython
    preloaded (its binary takes the C API from the process), PYTHONHOME and a PYTHONPATH reaching prsm."""
    gcc = shutil.which("gcc")
    if gcc is None:
        pytest.skip("no C compiler to build the test importer")
    host = tmp_path / "host"
    subprocess.run([gcc, "-o", str(host), str(Path(__file__).with_name("fmu_c_host.c")),
                    "-I", str(Path(fmpy.__file__).parent / "c-code"), "-ldl"], check=True, timeout=120)
    path, cfg = fmus(2, "fu2018", "bare")
    unzipped = Path(extract(str(path)))
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    libpython = Path(sysconfig.get_config_var("LIBDIR")) / sysconfig.get_config_var("LDLIBRARY")
    env = {"PATH": "/usr/bin:/bin", "LD_PRELOAD": str(libpython), "PYTHONHOME": sys.base_prefix,
           "PYTHONPATH": ":".join([str(Path(prsm_sim.__file__).parents[1])]
                                  + [p for p in sys.path if "site-packages" in p])}
    r = subprocess.run([str(host), str(unzipped / "binaries" / "linux64" / "PrsmActuator.so"),
                        (unzipped / "resources").as_uri(), md.guid, str(vr["screw_torque_nm"]),
                        str(vr["nut_position_m"]), "100", "1.0"], capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    got = float(r.stdout.strip().splitlines()[-1].split()[-1])
    want = session_loop(cfg, np.array([1.0]), np.array([LOAD_N]), k=100)[0]["nut_position_m"]
    assert got == want


def test_flags_and_actuator_outputs_follow_the_actuator(tmp_path):
    """Stops at +0.5 mm and a friction surge over [10, 20) ms: the 0/1 flags say when (the actuator's
    own quantities are the oracle), and ideal sensors measure the true values exactly."""
    a = ActuatorParams(motor=MotorParams(), stops=StopParams(max_position_m=5e-4),
                       faults=(Fault("friction_surge", start_s=0.01, duration_s=0.01, value=3.0),))
    cfg = make_config(preset("s30"), "jones2016", DT, a, interface="velocity", fmi=2)
    core, logs = make_core(tmp_path, cfg)
    core.set("screw_speed_command_rad_s", 40.0)
    seen = {"fault": [], "stop": []}
    for k in range(60):
        assert core.do_step(k * DT, DT) is None
        t = core.session.time_s
        seen["fault"].append((t, core.get("fault_active")))
        seen["stop"].append((core.get("at_stop"), core.get("stop_force_n"), core.get("nut_position_m")))
        assert core.get("measured_nut_position_m") == core.get("nut_position_m")
        assert core.get("measured_screw_speed_rad_s") == core.get("screw_speed_rad_s")
        assert core.get("brake_engaged") == 0.0
    assert all(flag == (1.0 if 0.01 <= t - DT < 0.02 else 0.0) for t, flag in seen["fault"]), seen["fault"]
    assert any(flag == 1.0 for flag, _, _ in seen["stop"]) and seen["stop"][0][0] == 0.0
    assert all((flag == 1.0) == (x > 5e-4) for flag, _, x in seen["stop"])  # penetration: past the stop
    assert all(force < 0.0 for flag, force, _ in seen["stop"] if flag == 1.0)  # the upper stop pushes back: −x
    assert logs == []


# -- misuse through fmpy: out-of-order calls, huge steps, damaged states ---------------------------------
DAMAGED_SCRIPT = r"""
import json, sys
from prsm_ros.fmu.driver import FmuDriver
drv = FmuDriver(sys.argv[1])
good = drv.serialize(drv.get_state())
marker = "SECRET" * 200
damaged = [good[: len(good) // 2], b"\xff" * 64 + good[64:], b"{}", b"[" * 100000, b"\x00" * 10,
           json.dumps({"format": "prsm-fmu-state/1", "x": marker}).encode(), good.replace(b'"inputs"', b'"inpots"'),
           good.replace(b"prsm-fmu-state/1", b"prsm-fmu-state/9")]
statuses = []
for blob in damaged * 2:  # the third damaged blob into one instance used to crash the host
    drv.set_state(drv.deserialize(blob))
    statuses.append(drv.do_step(0.0, 1e-3))
drv.set_state(drv.deserialize(good))  # a good state is taken again and the instance steps on
statuses.append(drv.do_step(0.0, 1e-3))
print(json.dumps({"statuses": statuses, "messages": drv.messages}))
drv.close()
"""


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_damaged_states_give_an_error_never_a_crash_and_never_print_the_blob(fmus, fmi):
    """Damaged blobs (cut, not UTF-8, not JSON, nested 1e5 deep, another format, a wrong key) set
    into one instance, twice each: every one refused with an error, the host alive (it segfaulted at
    the third), the next doStep failed, and a good state then taken. In a child process, so a crash is
    an exit status, not the end of the test run."""
    from prsm_ros.fmu.core import MAX_LOG_CHARS
    path, _ = fmus(fmi, "fu2018", "bare")
    r = subprocess.run([sys.executable, "-c", DAMAGED_SCRIPT, str(path)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.returncode, r.stderr[-2000:])
    out = json.loads(r.stdout.strip().splitlines()[-1])
    failed = FMI_ERROR if fmi == 3 else FMI_DISCARD
    assert out["statuses"] == [failed] * 16 + [OK]
    refused = [s for s, m in out["messages"] if m.startswith("FMU state refused") and "the step was not taken" not in m]
    assert refused == [FMI_ERROR] * 16
    assert all(s < 4 for s, _ in out["messages"]), "no fatal status"
    assert all("SECRET" * 3 not in m and len(m) <= MAX_LOG_CHARS + 60 for _, m in out["messages"])


EXIT_SCRIPT = r"""
import sys
from prsm_ros.fmu import core
from prsm_ros.fmu.driver import FmuDriver
if sys.argv[2] == "kept":  # the binary's static reference left as pythonfmu has it
    core.release_static_interpreter_handle = lambda resources: None
with FmuDriver(sys.argv[1]) as drv:
    assert drv.do_step(0.0, float(sys.argv[3])) == 0, drv.messages
"""


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("valgrind") is None, reason="needs valgrind's memcheck")
@pytest.mark.parametrize(("fmi", "handle", "reads_freed"), [(2, "released", False), (3, "released", False),
                                                            (3, "kept", True)])
def test_a_python_importer_exits_without_the_binary_reading_freed_memory(fmus, fmi, handle, reads_freed):
    """Under valgrind's memcheck, a Python importer instantiates the FMU, steps it, frees it and exits. The
    binary's unload function (`finalizePythonInterpreter`, run after the C++ exit handlers) reads no freed
    memory; with the slave's release of the static reference undone ("kept") the same run shows the read
    that made glibc abort importers at exit now and then (so the check sees the defect it guards)."""
    path, _ = fmus(fmi, "ideal", "bare")
    r = subprocess.run(["valgrind", "--trace-children=yes", "--error-limit=no", "--num-callers=40", sys.executable,
                        "-c", EXIT_SCRIPT, str(path), handle, repr(DT)], capture_output=True, text=True, timeout=1200,
                       env={**os.environ, "PYTHONMALLOC": "malloc"})
    assert r.returncode == 0, r.stderr[-2000:]
    # valgrind names a function only in the stack of an error it reports
    assert ("finalizePythonInterpreter" in r.stderr) == reads_freed, r.stderr[-3000:]


@pytest.mark.parametrize("fmi", [2, 3])
def test_calls_out_of_order_and_huge_steps_give_an_error(fmus, fmi):
    """doStep before initialisation, at a time behind or ahead of the instance, with 1e9 model steps
    (the library's runs stop at MAX_RUN_STEPS = 1e7) or after terminate: an error, nothing stepped."""
    from prsm_ros.limits import MAX_RUN_STEPS
    path, _ = fmus(fmi, "fu2018", "bare")
    failed = FMI_ERROR if fmi == 3 else FMI_DISCARD
    md = read_model_description(str(path))
    unzipped = extract(str(path))
    messages: list[str] = []
    fmu = instantiate_fmu(unzipped, md, debug_logging=True, logger=lambda *a: messages.append(a[-1].decode()))
    try:
        with pytest.raises(Exception, match=f"status {failed}"):
            fmu.doStep(0.0, DT)  # before initialisation
        assert "before initialisation" in messages[-1]
    finally:
        fmu.freeInstance()
        shutil.rmtree(unzipped, ignore_errors=True)
    with FmuDriver(path) as drv:
        pos = drv.refs(["nut_position_m"])
        drv.set(drv.refs(["screw_torque_nm"]), [1.0])
        t0 = time_ns()
        assert drv.do_step(0.0, 1e6) == failed  # 1e9 steps refused at once, not run for minutes
        assert (time_ns() - t0) < 5e9 and f"at most {MAX_RUN_STEPS}" in drv.messages[-1][1]
        assert drv.do_step(0.0, 2 * DT) == OK
        at = drv.get(pos)
        assert drv.do_step(0.0, DT) == failed and "back in time" in drv.messages[-1][1]
        assert drv.do_step(5 * DT, DT) == failed and "a gap" in drv.messages[-1][1]
        assert drv.get(pos) == at  # nothing stepped
        assert drv.do_step(2 * DT, DT) == OK
        drv.fmu.terminate()
        assert drv.do_step(3 * DT, DT) == failed and "after terminate" in drv.messages[-1][1]


def test_a_refused_state_changes_nothing(tmp_path):
    """A state whose tunable parameter is good but whose session part is not: the tunable is not
    taken either (all or nothing), and the instance steps on as before once a good state is set."""
    cfg = config_for("fu2018", "velocity")
    core, logs = make_core(tmp_path, cfg)
    good = core.get_state()
    bad = json.loads(json.dumps(good))
    bad["tunables"]["drive_speed_kp_nm_s_rad"] = 2 * good["tunables"]["drive_speed_kp_nm_s_rad"]
    bad["session"] = {"not": "a session"}
    assert core.set_state(bad) is False
    assert core.tunables == good["tunables"] and core.get_state() == good
    assert core.do_step(0.0, DT) is not None
    assert core.set_state(good) is True and core.do_step(0.0, DT) is None


def test_a_drive_loop_tuned_past_its_bound_is_said_through_the_fmu_logger(tmp_path):
    """Oracle: the sampled speed loop's pole z = 1 − a (a = kp h/J) leaves the unit circle at a > 2
    (docs/actuator.md): a kp of 3 J/h, J the inertia the defaults were tuned on (kp = J · 2π · 30 Hz), rings by
    itself, and the FMU's logger says so with status "warning"; the defaults at 1 kHz say nothing."""
    core, logs = make_core(tmp_path, config_for("jones2016", "velocity"))
    assert not [m for status, m in logs if status == "warning"]
    j = core.get("drive_speed_kp_nm_s_rad") / (2 * math.pi * 30.0)
    core.set("drive_speed_kp_nm_s_rad", 3.0 * j / DT)
    said = [m for status, m in logs if status == "warning"]
    assert len(said) == 1 and said[0].startswith("DriveLoopWarning: drive: the velocity loop updated at 1000 Hz")
    assert core.do_step(0.0, DT) is None  # said, not refused
