"""Pure-Python parts of the realtime loop (issue 15), without DDS: command ownership, the command
echo and its latency statistics, and bag paths that never overwrite a file."""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np
import pytest

from prsm_ros.node.command_echo import CommandEcho, stamp_of
from prsm_ros.node.ownership import CommandOwnership, participant_name, participant_of
from prsm_ros.node.record_path import RecordPathError, claim_record_path, default_name

A = bytes(range(12))
B = bytes(range(1, 13))


def _info(prefix: bytes, entity: bytes = b"\x00\x00\x14\x03") -> dict:
    return {"source_timestamp": 5, "publisher_gid": {"implementation_identifier": "rmw_fastrtps_cpp",
                                                     "data": prefix + entity}}


def test_participant_is_the_guid_prefix_so_one_controller_may_use_several_topics():
    assert participant_of(_info(A, b"\x00\x00\x14\x03")) == participant_of(_info(A, b"\x00\x00\x15\x03")) == A
    assert participant_of({}) is None and participant_of(None) is None
    assert participant_name(A) == A.hex()


def test_first_valid_command_owns_others_refused_and_counted_until_release():
    clock = [0.0]
    own = CommandOwnership(timeout_s=1.0, clock=lambda: clock[0])
    assert own.admit(A) is None
    own.accepted(A)
    reason = own.admit(B)
    assert reason is not None and B.hex() in reason and A.hex() in reason
    own.admit(B)
    assert own.counters.refused == 2 and own.counters.refused_by == {B.hex(): 2}
    assert own.admit(A) is None  # the owner stays admitted
    assert own.release() == f"released by {A.hex()}"
    assert own.admit(B) is None
    own.accepted(B)
    assert own.owner == B
    d = own.diagnostics()
    assert d["command_owner"] == B.hex() and d["commands_refused_not_owner"] == 2 and B.hex() in d["refused_participants"]


def test_an_invalid_command_does_not_take_ownership_and_silence_lets_it_lapse():
    clock = [0.0]
    own = CommandOwnership(timeout_s=0.5, clock=lambda: clock[0])
    assert own.admit(B) is None  # B's command then fails validation: no accepted() call
    own.admit(A)
    own.accepted(A)
    clock[0] = 0.4
    assert own.admit(B) is not None
    clock[0] = 0.91  # more than 0.5 s since A's last valid command (at 0.0)
    assert own.admit(B) is None and own.owner is None and own.counters.lapses == 1


def test_ownership_disabled_admits_everyone():
    own = CommandOwnership(enabled=False)
    own.accepted(A)
    assert own.admit(B) is None and own.owner is None


def test_echo_once_per_command_with_the_newest_stamp_and_latency_report():
    echo = CommandEcho()
    assert stamp_of(0, 123) == 123 and stamp_of(456, 123) == 456 and stamp_of(0, 0) is None
    echo.offer(1_000, "a")
    echo.offer(2_000, "b")  # a newer command before the step: the step applies this one
    assert echo.take() == (2_000, "b")
    assert echo.take() is None  # the next step applies no new command
    for k in range(100):
        echo.record_latency(0, 1_000_000 * (k + 1))  # 1..100 ms
    r = echo.report()
    assert float(r["command_latency_max_ms"]) == 100.0
    assert 50.0 <= float(r["command_latency_p50_ms"]) <= 51.0 and r["commands_echoed"] == "1"
    assert echo.report()["command_latency_p50_ms"] == "n/a"  # a new window


def test_record_paths_are_claimed_and_never_overwritten(tmp_path):
    now = datetime(2026, 11, 23, 17, 0, 0, tzinfo=timezone.utc)
    assert default_name("/arm1/prsm_actuator", now) == "prsm_arm1_prsm_actuator_20261123_170000.mcap"
    p1 = claim_record_path("", "/prsm_actuator", directory=tmp_path, now=now)
    p2 = claim_record_path("", "/prsm_actuator", directory=tmp_path, now=now)  # same second, same name
    assert p1 != p2 and p1.exists() and p2.name.endswith("_2.mcap")
    given = tmp_path / "mine.mcap"
    given.write_bytes(b"precious")
    with pytest.raises(RecordPathError, match="never overwrites"):
        claim_record_path(str(given), "/prsm_actuator")
    assert given.read_bytes() == b"precious"
    with pytest.raises(RecordPathError):
        claim_record_path(str(tmp_path / "no_such_dir" / "x.mcap"), "/prsm_actuator")


def test_the_controllers_read_cdr_as_rclpy_writes_it():
    """The controllers' raw CDR readers (prsm_ros.cdr_read) against rclpy's own serializer; odd frame
    and name lengths move every later field off its alignment."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState, TimeReference

    from prsm_ros.cdr_read import joint_state_at, joint_state_names, joint_state_stamp_effort0, time_reference_stamps
    for frame, names, effort in (("", ["screw_joint", "nut_joint"], [0.25, -3.0]), ("nut_link", ["a"], []),
                                 ("x" * 7, ["screw_joint", "nut_joint", "c"], [1e-300, 2.0, 3.0])):
        m = JointState(name=names, position=[1.0] * len(names), velocity=[], effort=effort)
        m.header.frame_id = frame
        m.header.stamp.sec, m.header.stamp.nanosec = 12, 345
        assert joint_state_stamp_effort0(serialize_message(m)) == (12_000_000_345, effort[0] if effort else None)
        assert joint_state_names(serialize_message(m)) == names
        with pytest.raises(IndexError):  # no velocities in these states
            joint_state_at(serialize_message(m), 0)
    m = JointState(name=["screw_joint", "nut_joint"], position=[3.5, -0.0125], velocity=[-7.25, 1e-3], effort=[])
    m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec = "abcde", 2, 999_999_999
    raw = serialize_message(m)
    assert joint_state_at(raw, 1) == (2_999_999_999, -0.0125, 1e-3)
    assert joint_state_at(raw, 0) == (2_999_999_999, 3.5, -7.25)
    with pytest.raises(IndexError):
        joint_state_at(raw, 2)
    with pytest.raises(ValueError, match="little-endian"):
        joint_state_at(raw[:1] + b"\x00" + raw[2:], 1)  # big-endian CDR is refused, not misread
    t = TimeReference(source="/prsm_actuator/screw_torque")
    t.header.stamp.sec, t.header.stamp.nanosec = 3, 4
    t.header.frame_id = "abc"
    t.time_ref.sec, t.time_ref.nanosec = 1_795_000_000, 999_999_999
    assert time_reference_stamps(serialize_message(t)) == (3_000_000_004, 1_795_000_000_999_999_999)


def test_float64_commands_read_from_cdr_as_rclpy_writes_them():
    """The node's polled Float64 commands (raw CDR): the value rclpy's deserialiser gives, for
    little-endian bytes (read in place) and big-endian ones (another encapsulation: deserialised);
    bytes too short for a Float64 raise, and the node refuses them as malformed."""
    import math
    import struct

    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64

    from prsm_ros.cdr_read import float64_data
    from prsm_ros.node.ros_node import _float64
    for x in (0.0, -0.0, 0.25, -3.5e-300, 1e308, math.inf, -math.inf):
        got = float64_data(serialize_message(Float64(data=x)))
        assert got == x and math.copysign(1, got) == math.copysign(1, x)
    assert math.isnan(float64_data(serialize_message(Float64(data=math.nan))))
    big = b"\x00\x00\x00\x00" + struct.pack(">d", -1.75)  # CDR_BE encapsulation
    with pytest.raises(ValueError, match="little-endian"):
        float64_data(big)
    assert deserialize_message(big, Float64).data == -1.75 == _float64(big)
    with pytest.raises(struct.error):
        _float64(b"\x00\x01\x00\x00\x01")


@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018"])
def test_step_encoder_bytes_decode_to_the_mapper_messages(model):
    """The node's CDR templates, decoded by rclpy's own deserialiser, equal MessageMapper's messages."""
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState, TimeReference
    from std_msgs.msg import Float64MultiArray

    from prsm_ros.messages import MessageMapper, stamp, time_ns
    from prsm_ros.cdr_write import StepEncoder
    from prsm_sim import Simulator, preset
    sim = Simulator(preset("s30"), model, 1e-3)
    mapper = MessageMapper(sim.layout, model)
    enc = mapper.encoder()
    for k in range(3):
        out = sim.step(0.01 * (k + 1), 20.0)
        ns, st = time_ns(out.time_s), stamp(out.time_s)
        assert deserialize_message(enc.joint_state(out, ns), JointState) == mapper.joint_state(out, st)
        assert deserialize_message(enc.wrench(out, ns), WrenchStamped) == mapper.wrench(out, st)
        assert deserialize_message(enc.clock(ns), Clock) == mapper.clock(out.time_s)
        got, want = deserialize_message(enc.internal_loads(out), Float64MultiArray), mapper.internal_loads(out)
        assert got.layout == want.layout
        np.testing.assert_array_equal(np.asarray(got.data), np.asarray(want.data))  # NaN where the record has NaN
    ref = TimeReference(source="/prsm_actuator/screw_torque")
    ref.header.stamp = stamp(2.5)
    ref.time_ref.sec, ref.time_ref.nanosec = 1_795_000_000, 123
    assert deserialize_message(StepEncoder.time_reference(2_500_000_000, 1_795_000_000_000_000_123,
                                                          "/prsm_actuator/screw_torque"), TimeReference) == ref


def test_rest_outputs_is_a_complete_record_of_the_reset_state():
    """What `~/reset` publishes while paused: every output field, the state at rest, nothing flowing."""
    from prsm_sim import OUTPUT_FIELDS, Session, preset
    st = Session(preset("s30"), "jones2016", 1e-3, nut_position_m=0.01, load_n=30.0)
    st.step()
    st.reset()
    out = st.rest_outputs()
    assert out.time_s == 0.0 and out.nut_position_m == pytest.approx(0.01) and out.nut_velocity_m_s == 0.0
    assert out.nut_force_n == out.load_force_n == 30.0 and out.power_in_w == 0.0 and out.energy_fault == 0.0
    assert set(out.scalars()) == {f for f, _ in OUTPUT_FIELDS} and out.internal.shape == (st.layout.size,)
