"""A lockstep run is a golden file: the same run twice gives the same bytes, and its report agrees with the
controller's own figures.

Two `prsm-demo --time-mode lockstep` runs (prsm-node and the demo controller, two processes over DDS)
with the same parameters and record path; oracles: the first bag's SHA-256, and the tracking RMS
the controller computed itself from the states it received (`prsm-demo --json`).
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import pytest

from ros_domains import domain_id

# the slow tier (.ci/run runs it after the README's test command): many node or Ray start-ups
pytestmark = pytest.mark.slow

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

DURATION_S = "1.0"


def _demo(tmp_path, name: str) -> tuple[dict, bytes]:
    record = tmp_path / "run.mcap"  # the same path both times: it is part of the recorded node parameters
    env = {**os.environ, "RERUN": "off", "PYTHONUNBUFFERED": "1"}
    p = subprocess.run([sys.executable, "-m", "prsm_ros.cli.demo", "--time-mode", "lockstep", "--duration", DURATION_S,
                        "--model", "fu2018", "--record", str(record), "--json",
                        "--domain-id", str(domain_id(f"golden-{name}"))],  # one per run
                       env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    data = record.read_bytes()
    record.rename(tmp_path / name)
    return json.loads(p.stdout), data


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("golden")
    first = _demo(tmp, "first.mcap")
    second = _demo(tmp, "second.mcap")
    return tmp, first, second


def test_two_lockstep_runs_give_byte_identical_bags(two_runs):
    tmp, (s1, b1), (s2, b2) = two_runs
    assert s1["completed"] and s2["completed"] and s1["steps"] == s2["steps"] == 1000
    assert hashlib.sha256(b1).hexdigest() == hashlib.sha256(b2).hexdigest()
    assert s1["rms_error_m"] == s2["rms_error_m"]  # the loop itself is deterministic too


def test_lockstep_report_tracking_equals_the_controllers_own(two_runs):
    from prsm_ros.bag.reader import open_bag
    from prsm_ros.bag.report import report

    tmp, (s1, _), _ = two_runs
    r = report(open_bag(tmp / "first.mcap"), plots=False, progress=False)
    tr = r["tracking"]
    assert tr["pairing"].startswith("stamp") and tr["pairs"] >= s1["states_received"] - 1
    assert tr["rms_error_m"] == pytest.approx(s1["rms_error_m"], rel=0.01)
    assert tr["max_error_m"] == pytest.approx(s1["max_error_m"], rel=0.01)
    # wall-clock topics stay out of a lockstep bag; the run's figures are all there
    bag = open_bag(tmp / "first.mcap")
    assert "/diagnostics" not in bag.topics and "/prsm_actuator/command_echo" not in bag.topics
    assert bag.topics["/joint_states"].count == 1000


@pytest.mark.parametrize("type_name", ["sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped",
                                       "std_msgs/msg/Float64MultiArray", "sensor_msgs/msg/TimeReference",
                                       "diagnostic_msgs/msg/DiagnosticArray"])
def test_cdr_padding_is_zeroed_and_nothing_else_changes(type_name):
    """Oracle: a byte is padding when flipping it leaves the decoded message unchanged (rosbags decodes
    and encodes again); every such byte dirtied at once, the normaliser must give the clean bytes back."""
    from prsm_ros.mcap.codec import CdrNormaliser, TypestoreCodec

    ts = TypestoreCodec().typestore
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](sec=3, nanosec=7)
    header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="a")
    import numpy as np
    msgs = {
        "sensor_msgs/msg/JointState": T["sensor_msgs/msg/JointState"](
            header=header, name=["screw_joint", "nut"], position=np.array([1.0, 2.0]), velocity=np.array([3.0, 4.0]),
            effort=np.array([5.0, 6.0])),
        "geometry_msgs/msg/WrenchStamped": T["geometry_msgs/msg/WrenchStamped"](header=header, wrench=T["geometry_msgs/msg/Wrench"](
            force=T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=3.0), torque=T["geometry_msgs/msg/Vector3"](x=4.0, y=5.0, z=6.0))),
        "std_msgs/msg/Float64MultiArray": T["std_msgs/msg/Float64MultiArray"](layout=T["std_msgs/msg/MultiArrayLayout"](
            dim=[T["std_msgs/msg/MultiArrayDimension"](label="ab", size=2, stride=2)], data_offset=0), data=np.array([1.5, 2.5])),
        "sensor_msgs/msg/TimeReference": T["sensor_msgs/msg/TimeReference"](header=header, time_ref=stamp, source="x"),
        "diagnostic_msgs/msg/DiagnosticArray": T["diagnostic_msgs/msg/DiagnosticArray"](header=header, status=[
            T["diagnostic_msgs/msg/DiagnosticStatus"](level=1, name="n", message="m", hardware_id="h", values=[
                T["diagnostic_msgs/msg/KeyValue"](key="k", value="v")])]),
    }
    clean = bytes(ts.serialize_cdr(msgs[type_name], type_name))

    def decodes_as_clean(data: bytes) -> bool:
        try:
            return bytes(ts.serialize_cdr(ts.deserialize_cdr(data, type_name), type_name)) == clean
        except Exception:  # noqa: BLE001 — a flipped length: not padding
            return False

    padding = [i for i in range(4, len(clean)) if decodes_as_clean(clean[:i] + bytes([clean[i] ^ 0xA5]) + clean[i + 1:])]
    assert padding, "the message has alignment padding to dirty"
    dirty = bytearray(clean)
    for i in padding:
        dirty[i] ^= 0xA5
    assert bytes(dirty) != clean
    assert CdrNormaliser()(type_name, bytes(dirty)) == clean
