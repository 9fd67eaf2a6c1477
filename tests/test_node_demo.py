"""`prsm-demo` end to end: node and controller as separate processes over DDS, summary printed, bag closed.

Run through the installed console script with no ROS environment sourced (only the pip wheels),
in lockstep so the tracking figures are the same on a loaded machine.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from prsm_ros.cli.demo_controller import PositionController, reference  # noqa: E402
from ros_procs import ros_test_env  # noqa: E402

ENV = ros_test_env("test_node_demo")


def test_prsm_demo_tracks_the_profile_and_records_a_bag(tmp_path):
    bag = tmp_path / "demo.mcap"
    exe = Path(sys.executable).parent / "prsm-demo"
    res = subprocess.run([str(exe), "--time-mode", "lockstep", "--duration", "1.0", "--record", str(bag)],
                         env=ENV, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    out = res.stdout
    assert f"ROS_DOMAIN_ID={ENV['ROS_DOMAIN_ID']}" in out  # the user's (here: the test's) domain is kept
    rms_mm = float(re.search(r"RMS error\s+([-\d.]+) mm", out).group(1))
    max_mm = float(re.search(r"max error\s+([-\d.]+) mm", out).group(1))
    steps = int(re.search(r"steps\s+(\d+)", out).group(1))
    assert steps == 1000
    assert 0 < rms_mm <= max_mm < 1.0  # 20 mm stroke tracked to well under a millimetre
    from mcap.reader import make_reader
    with open(bag, "rb") as f:
        summary = make_reader(f).get_summary()
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    assert counts["/clock"] == 1000 and counts["/prsm_actuator/nut_position_reference"] >= 999
    assert counts["/prsm_actuator/screw_torque"] >= 1000


def test_controller_law_feeds_forward_and_saturates():
    """Zero error on the reference: the torque is the inertia × reference acceleration plus the load term."""
    c = PositionController(inertia_kgm2=2e-4, lead_per_rad_m=1e-3, load_n=100.0, max_torque_nm=5.0)
    x, v, a = reference(0.0, 0.02, 0.5)
    assert (x, v) == (0.0, 0.0)
    assert c.torque(0.0, 0.0, a, 1e-3) == pytest.approx(2e-4 / 1e-3 * a + 1e-3 * 100.0)
    assert c.torque(1.0, 0.0, 0.0, 1e-3) == 5.0 and c.torque(-1.0, 0.0, 0.0, 1e-3) == -5.0
