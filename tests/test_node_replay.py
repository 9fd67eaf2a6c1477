"""An envelope case replays through prsm-node in lockstep to the same states (prsm_ros.node.replay).

Oracle: the case run offline through `prsm_sim.Session` (the envelope's runner) records every state;
the node, driven by the same actions over DDS (commands, load changes, brake, pause, resume, reset),
must publish the same true states bit for bit.
"""

from __future__ import annotations

import pytest
import json
import subprocess
import sys

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from prsm_sim.envelope import case_from_seed  # noqa: E402
from ros_procs import CEILING_FACTOR, ros_test_env  # noqa: E402

# the slow tier (.ci/run runs it after the README's test command): many node or Ray start-ups
pytestmark = pytest.mark.slow

ENV = ros_test_env("test_envelope_node")


def test_a_case_with_brake_pause_and_reset_replays_on_the_node_to_the_same_states(tmp_path):
    from prsm_ros.node.replay import replay_on_node
    case = case_from_seed(1624)  # actuator in effort mode driven onto a thread end, brake engage and release, a
    # pause, then a reset, at a step of 1/1676 s
    assert case["interface"] == "effort" and case["brake"] and case["pause_at_s"] and case["reset_at_s"]
    r = replay_on_node(case, tmp_path / "node", env=ENV)
    assert r["violations"] == [] and r["mismatch"] is None
    assert r["ok"] and r["compared"] == r["steps"] > 400


def test_the_command_replays_a_failure_file_through_the_node(tmp_path):
    """`prsm-sim envelope --case FILE --node`: one command, the offline verdict and the node's."""
    import yaml
    case = case_from_seed(2174)  # fu2018, position drive, paused mid-run, a constant load
    (tmp_path / "case.yaml").write_text(yaml.safe_dump({"case": case}), encoding="utf-8")
    p = subprocess.run([sys.executable, "-m", "prsm_ros.cli.sim", "envelope", "--case", str(tmp_path / "case.yaml"),
                        "--node", "--json", "-o", str(tmp_path / "out")], env=ENV, capture_output=True, text=True,
                       timeout=120 * CEILING_FACTOR)
    assert p.returncode == 0, p.stderr
    doc = json.loads(p.stdout)
    assert doc["ok"] and doc["node"]["ok"] and doc["node"]["compared"] == doc["steps"] > 200
