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
from prsm_ros.cli.json_out import dumps

RERUN_BIN = pytest.importorskip("rerun_cli")
RERUN_BIN = Path(RERUN_BIN.__file__).parent / "rerun"

# The child: block ROS at import time, then run a module as `python -m` would.
_BLOCKING_RUNNER = textwrap.dedent('''
    import importlib.abc, runpy, sys

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
    module, sys.argv = sys.argv[1], sys.argv[1:]
    runpy.run_module(module, run_name="__main__", alter_sys=True)
''')


def _env() -> dict[str, str]:
    env = dict(os.environ)
    for k in ("RERUN", "AMENT_PREFIX_PATH", "ROS_DISTRO", "PYTHONPATH"):
        env.pop(k, None)  # RERUN=off would make to-rrd refuse; the others would point at a ROS install
    env["ROS_DISTRO"] = "jazzy"  # the typestore's distribution, whatever the machine has
    return env


def _run(module: str, *args, ok: bool = True) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-c", _BLOCKING_RUNNER, module, *map(str, args)],
                         capture_output=True, text=True, env=_env(), timeout=300)
    if ok:
        assert res.returncode == 0, f"{module} {args}: exit {res.returncode}\n{res.stderr}"
    return res


def test_the_blocker_refuses_ros():
    """The guard itself: importing the rclpy side must fail in the child, or the test below proves nothing."""
    res = _run("prsm_ros.messages", ok=False)
    assert res.returncode != 0 and "is blocked: this run has no ROS" in res.stderr


def test_sim_mcap_and_bag_tools_run_without_ros(tmp_path):
    bag, sim_csv = tmp_path / "run.mcap", tmp_path / "run.csv"
    res = _run("prsm_ros.cli.sim", "run", "--preset", "s30", "--model", "jones2016", "--scenario", "step",
               "--duration", "0.05", "--dt", "0.001", "--mcap", bag, "--csv", sim_csv, "--json", "--no-progress")
    summary = json.loads(res.stdout)
    steps = summary["steps"]
    assert steps == 50 and summary["mcap"] == str(bag)

    # the bag is clean for the Rerun CLI's MCAP reader (an independent implementation)
    check = subprocess.run([str(RERUN_BIN), "mcap", "check", str(bag)], capture_output=True, text=True, timeout=60)
    rows = [ln.split() for ln in check.stdout.splitlines() if ln.split() and ln.split()[0] in ("ok", "warn", "error")]
    assert check.returncode == 0 and len(rows) == 6 and all(r[0] == "ok" and r[-1] == "—" for r in rows), check.stdout

    info = json.loads(_run("prsm_ros.bag.cli", "info", bag, "--json").stdout)
    counts = {t["topic"]: t["count"] for t in info["topics"]} if isinstance(info["topics"], list) else \
        {k: v["count"] for k, v in info["topics"].items()}
    assert counts == {"/prsm_actuator/internal_loads/labels": 1, "/prsm_actuator/screw_torque": steps,
                      "/joint_states": steps, "/prsm_actuator/nut/wrench": steps,
                      "/prsm_actuator/internal_loads": steps, "/clock": steps}

    # export: the internal loads by their labels, equal to the simulator's own CSV of the same run
    out = tmp_path / "loads.csv"
    _run("prsm_ros.bag.cli", "export", bag, "-t", "/prsm_actuator/internal_loads", "-o", out)
    with open(out, newline="") as f:
        exported = list(csv.reader(f))
    with open(sim_csv, newline="") as f:
        simulated = list(csv.reader(f))
    sim_names = [h.rpartition(" [")[0] for h in simulated[0]]
    # time_s then every element, labelled like the simulator's CSV (the row's own time_s fills the time column)
    assert exported[0] == sim_names
    got = np.array(exported[1:], dtype=float)
    want = np.array(simulated[1:], dtype=float)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-300)  # the CSV keeps 10 significant digits

    # report: the same metrics as computed here, where ROS is importable
    rdir = tmp_path / "report"
    _run("prsm_ros.bag.cli", "report", bag, "--json", "--no-plots", "-o", rdir)
    child = json.loads((rdir / "report.json").read_text())
    here = json.loads(dumps(report(open_bag(bag), tmp_path / "report_here", plots=False, progress=False)))
    child.pop("bag", None), here.pop("bag", None)
    assert child == here

    # to-rrd: a recording the Rerun CLI verifies
    rrd = tmp_path / "run.rrd"
    res = _run("prsm_ros.bag.cli", "to-rrd", bag, "-o", rrd)
    verify = subprocess.run([str(RERUN_BIN), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    assert "source: internal_loads" in res.stdout and f"rows: {steps}" in res.stdout
