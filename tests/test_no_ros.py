"""Offline MCAP writing and bag analysis run without ROS (`pip install 'prsm[bag]'`), and stay so.

Each command runs in a child interpreter whose import system refuses rclpy, every rosidl / rmw /
ament module and every ROS message package (a meta-path finder installed before the command's
module is loaded), as on an install without the `ros` extra. Oracles: the offline bag's labels and
internal loads are the simulator's own CSV (`prsm-sim run --csv`, same run); `prsm-bag report`
gives the same JSON as in this process, where ROS is importable; `rerun mcap check` and
`rerun rrd verify` (the Rerun CLI, an independent reader) accept the bag and the .rrd.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from prsm_ros.bag.reader import open_bag
from prsm_ros.bag.report import report
from prsm_ros.json_out import dumps

RERUN_BIN = pytest.importorskip("rerun_cli")
RERUN_BIN = Path(RERUN_BIN.__file__).parent / "rerun"

# The child: block ROS at import time, then run each command as `python -m MODULE ARGS` would, in
# one interpreter (one import of numpy/scipy for all), and print each one's exit code and output.
_BLOCKING_RUNNER = textwrap.dedent('''
    import contextlib, importlib.abc, io, json, runpy, sys

    EXACT = {"rclpy", "rpyutils", "builtin_interfaces", "std_msgs", "sensor_msgs", "geometry_msgs",
             "diagnostic_msgs", "rosgraph_msgs", "std_srvs", "rcl_interfaces", "rosidl_runtime_py"}
    PREFIXES = ("rosidl", "rmw", "rcl_", "rcutils", "ament_", "type_description", "service_msgs")
    SUFFIXES = ("_msgs", "_srvs", "_interfaces")

    def blocked(name):
        top = name.partition(".")[0]
        return top in EXACT or top.startswith(PREFIXES) or top.endswith(SUFFIXES)

    class RefuseRos(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if blocked(name):
                raise ModuleNotFoundError(f"{name} is blocked: this run has no ROS", name=name)
            return None

    already = sorted(m for m in sys.modules if blocked(m))
    if already:
        sys.exit(f"ROS modules imported before the blocker: {already}")
    sys.meta_path.insert(0, RefuseRos())
    results = []
    for module, *args in json.loads(sys.argv[1]):
        out, err, code = io.StringIO(), io.StringIO(), 0
        sys.argv = [module, *args]
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                runpy.run_module(module, run_name="__main__", alter_sys=True)
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            except BaseException as e:
                code, _ = 1, err.write(f"{type(e).__name__}: {e}")
        results.append({"command": [module, *args], "code": code, "stdout": out.getvalue(), "stderr": err.getvalue()})
    print(json.dumps(results))
''')


def _env() -> dict[str, str]:
    env = dict(os.environ)
    for k in ("RERUN", "AMENT_PREFIX_PATH", "ROS_DISTRO", "PYTHONPATH"):
        env.pop(k, None)  # RERUN=off would make to-rrd refuse; the others would point at a ROS install
    env["ROS_DISTRO"] = "jazzy"  # the typestore's distribution, whatever the machine has
    return env


def _run(*commands: list, codes: tuple[int, ...] | None = None) -> list[dict]:
    """Run the commands (module, args…) in one ROS-blocked child; each must exit 0, or with its entry of `codes`."""
    res = subprocess.run([sys.executable, "-c", _BLOCKING_RUNNER, json.dumps([[str(a) for a in c] for c in commands])],
                         capture_output=True, text=True, env=_env(), timeout=300)
    assert res.returncode == 0, res.stderr
    results = json.loads(res.stdout)
    for r, code in zip(results, codes or (0,) * len(results)):
        assert r["code"] == code, f"{r['command']}: exit {r['code']}\n{r['stderr']}"
    return results


def test_the_blocker_refuses_ros():
    """The guard itself: importing the rclpy side must fail in the child, or the test below proves nothing."""
    res = subprocess.run([sys.executable, "-c", _BLOCKING_RUNNER, json.dumps([["prsm_ros.messages"]])],
                         capture_output=True, text=True, env=_env(), timeout=120)
    [r] = json.loads(res.stdout)
    assert r["code"] == 1 and "builtin_interfaces is blocked: this run has no ROS" in r["stderr"]


def test_sim_mcap_and_bag_tools_run_without_ros(tmp_path):
    bag, sim_csv, loads, rdir, rrd = (tmp_path / n for n in ("run.mcap", "run.csv", "loads.csv", "report", "run.rrd"))
    sim, info, export, rep, to_rrd, play = _run(
        ["prsm_ros.cli.sim", "run", "--preset", "s30", "--model", "jones2016", "--scenario", "step",
         "--duration", "0.05", "--dt", "0.001", "--mcap", bag, "--csv", sim_csv, "--json", "--no-progress"],
        ["prsm_ros.cli.bag", "info", bag, "--json"],
        ["prsm_ros.cli.bag", "export", bag, "-t", "/prsm_actuator/internal_loads", "-o", loads],
        ["prsm_ros.cli.bag", "report", bag, "--json", "--no-plots", "-o", rdir],
        ["prsm_ros.cli.bag", "to-rrd", bag, "-o", rrd],
        ["prsm_ros.cli.bag", "play", bag],  # the one bag command that needs ROS: it says so and exits 2
        codes=(0, 0, 0, 0, 0, 2))
    summary = json.loads(sim["stdout"])
    steps = summary["steps"]
    assert steps == 50 and summary["mcap"] == str(bag)

    # the bag is clean for the Rerun CLI's MCAP reader (an independent implementation)
    check = subprocess.run([str(RERUN_BIN), "mcap", "check", str(bag)], capture_output=True, text=True, timeout=60)
    rows = [ln.split() for ln in check.stdout.splitlines() if ln.split() and ln.split()[0] in ("ok", "warn", "error")]
    assert check.returncode == 0 and len(rows) == 6 and all(r[0] == "ok" and r[-1] == "—" for r in rows), check.stdout

    counts = {t["topic"]: t["count"] for t in json.loads(info["stdout"])["topics"]}
    assert counts == {"/prsm_actuator/internal_loads/labels": 1, "/prsm_actuator/screw_torque": steps,
                      "/joint_states": steps, "/prsm_actuator/nut/wrench": steps,
                      "/prsm_actuator/internal_loads": steps, "/clock": steps}

    # export: the internal loads by their labels, equal to the simulator's own CSV of the same run
    with open(loads, newline="") as f:
        exported = list(csv.reader(f))
    with open(sim_csv, newline="") as f:
        simulated = list(csv.reader(f))
    # time_s then every element, labelled like the simulator's CSV (the row's own time_s fills the time column)
    assert exported[0] == [h.rpartition(" [")[0] for h in simulated[0]]
    got = np.array(exported[1:], dtype=float)
    want = np.array(simulated[1:], dtype=float)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-300)  # the simulator's CSV keeps 10 significant digits

    # report: the same metrics as computed here, where ROS is importable
    child = json.loads((rdir / "report.json").read_text())
    here = json.loads(dumps(report(open_bag(bag), tmp_path / "report_here", plots=False, progress=False)))
    assert json.loads(rep["stdout"]) == child and child == here and "efficiency" in child

    # to-rrd: a recording the Rerun CLI verifies
    verify = subprocess.run([str(RERUN_BIN), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    assert "source: internal_loads" in to_rrd["stdout"] and f"rows: {steps}" in to_rrd["stdout"]
    assert play["stderr"].strip().splitlines() == [
        "prsm-bag play: error: play publishes on ROS topics and needs rclpy and the ROS message packages "
        "(rclpy is not installed): pip install 'prsm[ros]'"]
