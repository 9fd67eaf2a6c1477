"""`prsm-sim` as a user runs it: real processes, exit codes, one-line errors, JSON."""

import csv
import json
import subprocess
import sys

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


def test_presets_params_contact():
    assert "jones2016_literal" in run("presets").stdout
    d = json.loads(run("params", "--preset", "s30", "--json").stdout)
    assert d["geometry"]["screw_radius_m"] == 0.015
    c = json.loads(run("contact", "--preset", "jones2016", "--json").stdout)
    assert c["contacts"]["screw_exact"]["offset_deg"] == pytest.approx(-1.86, abs=0.01)


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
])
def test_errors_are_one_line_and_exit_2(args, expect):
    r = run(*args, ok=False)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and expect in lines[0], r.stderr
