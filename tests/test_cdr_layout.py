"""`cdr_layout`: a message's layout learnt once per shape, and the recorder's check that skips decoding.

Oracles: rclpy's own deserializer decides whether bytes are good (the check must answer as it does
for every mutation of good bytes, including after it has learnt their shape); rclpy's serializer
gives the messages; a layout reused for a new message must zero the same bytes a fresh walk does.
"""

import random

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_msgs.msg import Bool, Float64, Float64MultiArray, MultiArrayDimension  # noqa: E402

from prsm_ros.mcap.codec import CdrNormaliser  # noqa: E402
from prsm_ros.mcap.recorder import McapFile  # noqa: E402


def _reference(k: int) -> bytes:
    return serialize_message(JointState(name=["nut_joint"], position=[1e-5 * k], velocity=[0.1 * k],
                                        effort=[float("nan")]))


def _decodes(data: bytes, cls) -> bool:
    try:
        deserialize_message(data, cls)
    except Exception:  # noqa: BLE001 - whatever rclpy raises for bytes it cannot read
        return False
    return True


def _checking_file(path, deterministic: bool) -> McapFile:
    """A file whose `check` knows layouts: a deterministic one has them, another learns them as the
    recorder does when a received topic is declared (`prepare_checks`)."""
    f = McapFile(path, deterministic=deterministic)
    if not deterministic:
        f.prepare_checks()
    return f


@pytest.mark.parametrize("deterministic", [True, False])
def test_check_answers_as_rclpy_for_mutations_of_a_learnt_shape(tmp_path, deterministic):
    """Every single-byte change of a reference (lengths, strings, numbers, padding, header) and a few
    truncations: the file's check, its shape learnt from good references, says what rclpy's
    deserializer says (a lockstep file and a realtime one alike)."""
    f = _checking_file(tmp_path / "c.mcap", deterministic)
    try:
        for k in range(3):  # learnt: numbers only changing
            assert f.check(JointState, _reference(k))
        good = _reference(7)
        rng = random.Random(1)
        cases = [good[:i] + bytes([v]) + good[i + 1:] for i in range(len(good)) for v in (0x00, 0xFF, 0x80, 0xC3)]
        cases += [good[:n] for n in (0, 3, 4, 10, len(good) - 1)] + [good + b"\x00" * 3, good + b"\x07"]
        cases += [bytes(rng.randrange(256) for _ in range(len(good))) for _ in range(50)]
        disagree = [c for c in cases if f.check(JointState, c) != _decodes(c, JointState)]
        assert not disagree, f"{len(disagree)} of {len(cases)} cases, first {disagree[0].hex()}"
        assert sum(not _decodes(c, JointState) for c in cases) > 10  # the cases do include bad bytes
    finally:
        f.abort()


@pytest.mark.parametrize("value", [2, 0xFF])
def test_a_boolean_is_decisive(tmp_path, value):
    """A Bool's byte other than 0 or 1: the check answers as rclpy does, never from a learnt shape."""
    f = McapFile(tmp_path / "b.mcap", deterministic=True)
    try:
        good = serialize_message(Bool(data=True))
        assert f.check(Bool, good) and f.check(Bool, serialize_message(Bool(data=False)))
        odd = good[:4] + bytes([value]) + good[5:]
        assert f.check(Bool, odd) == _decodes(odd, Bool)
    finally:
        f.abort()


def test_a_reused_layout_zeroes_what_a_fresh_walk_zeroes():
    """Same shape, new numbers, padding dirtied: the normaliser that has seen the shape gives the
    bytes a fresh normaliser gives (the lengths decide the layout, the numbers do not)."""
    seen = CdrNormaliser()
    dims = [MultiArrayDimension(label="rollers", size=3, stride=6), MultiArrayDimension(label="t", size=2, stride=2)]
    cases = []
    for k in range(5):
        msg = Float64MultiArray(data=[k + 0.5 * i for i in range(6)])
        msg.layout.dim = dims
        cases.append(("std_msgs/msg/Float64MultiArray", serialize_message(msg)))
    cases += [("sensor_msgs/msg/JointState", _reference(k)) for k in range(3)]
    dirtied = 0
    for type_name, clean in cases:
        lay = CdrNormaliser().layouts.layout(type_name, clean)
        dirty = bytearray(clean)
        for a, b in lay.padding:
            dirty[a:b] = b"\xa5" * (b - a)
            dirtied += b - a
        expected = CdrNormaliser()(type_name, bytes(dirty))
        assert seen(type_name, bytes(dirty)) == expected == CdrNormaliser()(type_name, clean)
    assert dirtied > 0


@pytest.mark.parametrize("deterministic", [True, False])
def test_float64_commands_check_as_rclpy(tmp_path, deterministic):
    f = _checking_file(tmp_path / "f.mcap", deterministic)
    try:
        good = [serialize_message(Float64(data=float(k))) for k in range(3)]
        assert all(f.check(Float64, g) for g in good)
        for bad in (b"", b"\x00\x01\x00\x00", good[0][:-1], b"\x00\x01\x00\x00\x01"):
            assert f.check(Float64, bad) == _decodes(bad, Float64) is False
        longer = good[0] + b"\x00" * 8
        assert f.check(Float64, longer) == _decodes(longer, Float64)
    finally:
        f.abort()


def test_realtime_commands_are_decoded_once_per_shape(tmp_path):
    """A realtime file (not deterministic) checks a stream of torque commands, each a new number, with
    rclpy's deserializer once for their shape, not once per message; bad bytes are still decoded."""
    f = _checking_file(tmp_path / "r.mcap", deterministic=False)
    decoded = []
    deserialize = f._codec.deserialize

    def counting(data, cls):
        decoded.append(data)
        return deserialize(data, cls)

    f._codec.deserialize = counting
    try:
        assert all(f.check(Float64, serialize_message(Float64(data=0.001 * k))) for k in range(100))
        assert len(decoded) == 1
        assert not f.check(Float64, b"\x00\x01\x00\x00\x01") and len(decoded) == 2
    finally:
        f.abort()
