"""`prsm-sim` as a user runs it: real processes, exit codes, one-line errors, JSON."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

CLI = [sys.executable, "-m", "prsm_ros.cli.sim"]


def run(*args, ok=True):
    r = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120)
    if ok:
        assert r.returncode == 0, r.stderr
    return r


def test_steady_state_json_reports_the_seed_ratio():
    # the acceptance line: screw/carrier ratio 2.669 ± 0.001 (Jones 2016 eq. 42)
    d = json.loads(run("steady-state", "--preset", "jones2016", "--model", "jones2016", "--json").stdout)
    assert d["speed_ratio_screw_over_carrier"] == pytest.approx(2.669, abs=0.001)


@pytest.mark.slow
def test_presets_params_contact():
    assert "jones2016_literal" in run("presets").stdout
    d = json.loads(run("params", "--preset", "s30", "--json").stdout)
    assert d["geometry"]["screw_radius_m"] == 0.015
    c = json.loads(run("contact", "--preset", "jones2016", "--json").stdout)
    assert c["contacts"]["screw_exact"]["offset_deg"] == pytest.approx(-1.86, abs=0.01)


@pytest.mark.slow
def test_run_writes_csv_with_labelled_internal_loads(tmp_path):
    out = tmp_path / "run.csv"
    d = json.loads(run("run", "--preset", "s30", "--model", "fu2018", "--scenario", "heavy", "--duration", "0.3",
                       "--csv", str(out), "--json").stdout)
    # 0.75 since the roller tilting couple loads the pins (issue 12): pin friction grows with the load
    assert d["steps"] == 300 and d["tail_efficiency"] > 0.7 and d["energy_guard"]["fault"] is False
    rows = list(csv.reader(out.open()))
    assert rows[0][0] == "time_s [s]" and any("per_tooth[0,0].nut_normal_force_n [N]" in h for h in rows[0])
    assert len(rows) == 301


@pytest.mark.parametrize("args,expect", [
    (["run", "--set", "geometry.starts=2"], "geometry.starts = 2: must be a whole number >= 3"),
    (["run", "--set", "friction.mu=0.1"], "unknown parameter friction.mu"),
    (["run", "--duration", "nan"], "duration_s = nan"),
    (["run", "--preset", "s30", "--params", "x.yaml"], "give --preset or --params"),
    (["steady-state", "--model", "fu2018", "--torque", "1"], "--torque applies to --model jones2016 only"),
    (["params", "--params", "/nonexistent/p.yaml"], "cannot read parameter file"),
    (["run", "--actuator", "/nonexistent/a.yaml"], "cannot read actuator file"),
])
def test_errors_are_one_line_and_exit_2(args, expect):
    r = run(*args, ok=False)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and expect in lines[0], r.stderr


@pytest.mark.slow
def test_an_actuator_run_is_a_session_step_loop_bit_for_bit(tmp_path):
    """`prsm-sim run --actuator`: oracle, a hand-written `Session.step` loop (the node's path) with the same
    actuator file, command and load; the JSON summary (full precision: the last step's outputs, tail means
    and peaks over every step) is equal, the CSV equal to its 10 digits. The fault in the file acts
    (the session raises its events) and the actuator changes the run (a bare run ends elsewhere)."""
    from prsm_sim import Session, preset
    from prsm_sim.scenarios import summarise
    from prsm_sim.stepping.trajectory import trajectory_from_rows

    from prsm_ros.json_out import dumps
    from prsm_ros.param_files import load_actuator_file
    spec = tmp_path / "actuator.yaml"
    spec.write_text("motor: {}\nsensors: {latency_steps: 2}\n"
                    "faults:\n  - {kind: friction_surge, start_s: 0.05, duration_s: 0.05, value: 3.0}\n")
    csv_path = tmp_path / "run.csv"
    args = ["run", "--preset", "s30", "--model", "jones2016", "--scenario", "step", "--torque", "0.5",
            "--load", "200", "--duration", "0.2", "--json"]
    d = json.loads(run(*args, "--actuator", str(spec), "--csv", str(csv_path)).stdout)
    s = Session(preset("s30"), "jones2016", 1e-3, load_actuator_file(spec))
    rows = [s.step(0.5, 200.0) for _ in range(200)]
    assert [(e.what, e.fault.kind) for e in s.take_events()] == [("start", "friction_surge"), ("clear", "friction_surge")]
    want = json.loads(dumps(summarise(trajectory_from_rows(rows, s.layout, s.simulator.state))))
    assert {k: d[k] for k in want} == want
    table = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    expect = np.array([[*r.scalar_values(), *r.internal] for r in rows])
    assert table.shape == expect.shape
    np.testing.assert_allclose(table, expect, rtol=1e-9, atol=0.0)
    assert json.loads(run(*args).stdout)["final"] != d["final"]


@pytest.mark.slow
@pytest.mark.parametrize("text, extra, expect", [
    ("motor: {}\ndrive: {mode: velocity}\n", [], "drive.mode = 'velocity': the scenarios command the screw torque"),
    ("motor: {}\n", ["--mcap", "x.mcap"], "--mcap with --actuator"),
    ("gearbox: {}\n", [], "unknown actuator group 'gearbox'"),
    ("- motor\n", [], "expected a mapping of actuator groups"),
])
def test_actuator_file_errors_are_one_line_and_exit_2(tmp_path, text, extra, expect):
    spec = tmp_path / "actuator.yaml"
    spec.write_text(text)
    r = run("run", "--duration", "0.01", "--actuator", str(spec), *extra, ok=False)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and expect in lines[0], r.stderr
