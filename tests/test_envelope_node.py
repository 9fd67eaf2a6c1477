"""A widened envelope case (a datasheet-built screw, the drive's loops at half the step rate, a step of
1/570 s) reproduces through prsm-node from its seed with one command: the same states, step for step."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from prsm_sim.envelope import case_from_seed
from ros_procs import CEILING_FACTOR, ros_test_env

pytestmark = pytest.mark.slow  # a node start-up

ENV = ros_test_env("test_envelope_widened_node")


def test_a_datasheet_screw_with_a_slow_drive_loop_replays_on_the_node(tmp_path):
    case = case_from_seed(42)
    assert case["datasheet"] and case["loop_rate_hz"] * case["dt_s"] == pytest.approx(0.5)
    p = subprocess.run([sys.executable, "-m", "prsm_ros.cli.sim", "envelope", "--seed", "42", "--node", "--json",
                        "-o", str(tmp_path / "out")], env=ENV, capture_output=True, text=True,
                       timeout=120 * CEILING_FACTOR)
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["ok"] and doc["node"]["ok"] and doc["node"]["compared"] == doc["steps"] > 200
