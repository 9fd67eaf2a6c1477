"""A ROS 2 Jazzy client (rclpy from the `ros-jazzy-*` wheels) drives the Kilted node with `prsm-ctl`.

The project's wheels are Kilted; a Humble or Jazzy stack meets the node over DDS. This runs
`prsm-ctl` under a Jazzy interpreter against a node from this install: topics both ways,
services, parameter services, a transient-local `robot_description`. Installing the Jazzy wheels
takes minutes, so the test runs only where one is installed (in its own virtual environment,
never this one), named by PRSM_JAZZY_PYTHON:

    python -m venv /tmp/jazzy && /tmp/jazzy/bin/pip install ros-jazzy-rclpy ros-jazzy-std-msgs \\
        ros-jazzy-std-srvs ros-jazzy-sensor-msgs ros-jazzy-diagnostic-msgs ros-jazzy-rmw-fastrtps-cpp numpy pyyaml scipy
    PRSM_JAZZY_PYTHON=/tmp/jazzy/bin/python python -m pytest tests/test_jazzy_client.py
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from ros_procs import CEILING_FACTOR, NodeProcess, ros_test_env

JAZZY = os.environ.get("PRSM_JAZZY_PYTHON", "")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not JAZZY, reason="no Jazzy interpreter (PRSM_JAZZY_PYTHON, see the module doc)")]
ROOT = Path(__file__).resolve().parent.parent
ENV = ros_test_env("test_jazzy_client")


def jazzy_ctl(*argv: str) -> subprocess.CompletedProcess:
    # the Kilted wheels' loader re-executes this test process with its libraries on LD_LIBRARY_PATH
    # and marks it done; a Jazzy interpreter must start without either, so it loads its own
    env = {k: v for k, v in ENV.items() if k not in ("LD_LIBRARY_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE")}
    env["PYTHONPATH"] = str(ROOT)
    return subprocess.run([JAZZY, "-m", "prsm_ros.cli.ctl", "--json", "--timeout", str(10 * CEILING_FACTOR), *argv],
                          env=env, capture_output=True, text=True, timeout=120 * CEILING_FACTOR)


def test_a_jazzy_client_drives_the_kilted_node(tmp_path):
    version = subprocess.run([JAZZY, "-c", "import importlib.metadata as m; print(m.version('ros-jazzy-rclpy'))"],
                             capture_output=True, text=True)
    assert version.returncode == 0, f"{JAZZY} has no ros-jazzy-rclpy: {version.stderr}"
    params = {"model": "ideal", "start_paused": True, "record": False, "cmd_timeout": 0.0, "ownership_timeout": 0.05,
              "actuator.motor.fitted": True, "actuator.brake.holding_torque_nm": 8.0}
    with NodeProcess(ENV, params, workdir=tmp_path / "run") as proc:
        def ok(*argv):
            r = jazzy_ctl(*argv)
            assert r.returncode == 0, (argv, r.stderr)
            return [json.loads(line) for line in r.stdout.splitlines() if line.strip()]
        assert ok("step", "5")[0]["message"].startswith("stepped 5 of 5")
        ok("param", "set", "load_force", "100.0")
        assert ok("param", "get", "load_force")[0]["value"] == 100.0
        ok("resume")
        ok("command", "torque", "0.2")
        state = ok("state")[0]
        assert state["paused"] == "False" and state["command"] == "0.2" and state["time_s"] > 0.005
        assert ok("brake", "on")[0]["message"] == "sent brake engage to /prsm_actuator/brake_command"
        ok("fault", "inject", "jam", "duration_s=0.05", "value=3")
        ok("pause")
        assert proc.stop() == 0, proc.stderr
