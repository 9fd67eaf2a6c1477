"""A corpus of hostile MCAP files, built from bytes in the test (nothing downloaded, nothing stored).

Each builder writes one file and returns its path. The damaged ones start from a good bag of our
own (`base`, written offline) and change a few bytes where the MCAP spec puts a field; the foreign
ones are written with the mcap library's Writer so that their summary is consistent and only the
content is wrong (a wrong or unparseable schema, an undeclared channel, malformed CDR).
"""

from __future__ import annotations

import struct
from pathlib import Path

from mcap.opcode import Opcode

from prsm_ros.interface import TOPIC_DEFS

SCREW_TORQUE = TOPIC_DEFS["screw_torque"].resolved()
FLOAT64_CDR = b"\x00\x01\x00\x00" + struct.pack("<d", 1.5)  # encapsulation header + one little-endian float64
EVIL_MARKER = "evil_ran.txt"


def records(data: bytes):
    """(offset, opcode, length) of each top-level record after the magic, up to the footer."""
    pos = 8
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        yield pos, opcode, length
        if opcode == Opcode.FOOTER:
            return
        pos += 9 + length


def _writer(path: Path):
    from mcap.writer import CompressionType, Writer
    f = open(path, "wb")
    w = Writer(f, compression=CompressionType.ZSTD)
    w.start(profile="ros2", library="hostile corpus")
    return f, w


def _float64_channel(w, topic: str) -> int:
    sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
    return w.register_channel(topic, "cdr", sid, {})


def truncated(base: Path, out: Path) -> Path:
    data = base.read_bytes()
    out.write_bytes(data[: len(data) // 2])
    return out


def bad_crc(base: Path, out: Path) -> Path:
    """The first chunk's uncompressed CRC changed: the data decompresses but does not match it."""
    data = bytearray(base.read_bytes())
    pos = next(p for p, op, _ in records(bytes(data)) if op == Opcode.CHUNK)
    crc_at = pos + 9 + 24  # start time, end time, uncompressed size, then the CRC
    (crc,) = struct.unpack_from("<I", data, crc_at)
    struct.pack_into("<I", data, crc_at, (crc ^ 0x5A5A5A5A) or 1)
    out.write_bytes(bytes(data))
    return out


def bad_footer(base: Path, out: Path) -> Path:
    """The footer's summary offsets point far past the end of the file."""
    data = bytearray(base.read_bytes())
    footer = len(data) - 8 - 29  # footer record (1 + 8 + 20 bytes) then the closing magic
    assert data[footer] == Opcode.FOOTER
    struct.pack_into("<QQ", data, footer + 9, (1 << 62) + 12345, (1 << 61) + 7)
    out.write_bytes(bytes(data))
    return out


def huge_lengths(base: Path, out: Path) -> Path:
    """The second chunk declares 2^40 uncompressed bytes; a record after the chunks declares 2^62 bytes."""
    data = bytearray(base.read_bytes())
    chunks = [p for p, op, _ in records(bytes(data)) if op == Opcode.CHUNK]
    struct.pack_into("<Q", data, chunks[min(1, len(chunks) - 1)] + 9 + 16, 1 << 40)
    last = chunks[-1]
    (length,) = struct.unpack_from("<Q", data, last + 1)
    end = last + 9 + length
    out.write_bytes(bytes(data[:end]) + struct.pack("<BQ", Opcode.MESSAGE, 1 << 62) + b"\x00" * 64)
    return out


def beside_screw_torque(out: Path, topic: str, schema_name: str, definition: bytes, n: int = 20) -> Path:
    """`topic` with schema `schema_name` / `definition` and Float64 bytes, beside a good ~/screw_torque (n each)."""
    f, w = _writer(out)
    sid = w.register_schema(schema_name, "ros2msg", definition)
    cid = w.register_channel(topic, "cdr", sid, {})
    tq = _float64_channel(w, SCREW_TORQUE)
    for k in range(n):
        w.add_message(cid, k * 10_000_000, FLOAT64_CDR, k * 10_000_000)
        w.add_message(tq, k * 10_000_000, FLOAT64_CDR, k * 10_000_000)
    w.finish()
    f.close()
    return out


def foreign_joint_states(out: Path, definition: bytes) -> Path:
    """/joint_states whose schema says sensor_msgs/msg/JointState but whose definition is `definition`."""
    return beside_screw_torque(out, "/joint_states", "sensor_msgs/msg/JointState", definition)


def wrong_schema(out: Path) -> Path:
    return foreign_joint_states(out, b"float64 data")


def unparseable_schema(out: Path) -> Path:
    return foreign_joint_states(out, b"this is {not a definition\nfloat64[[ x\n")


def foreign_encoding(out: Path) -> Path:
    """/joint_states as protobuf: a schema and message encoding the tools do not read."""
    f, w = _writer(out)
    sid = w.register_schema("sensor_msgs.JointState", "protobuf", b"\x0a\x03abc")
    cid = w.register_channel("/joint_states", "protobuf", sid, {})
    for k in range(5):
        w.add_message(cid, k, b"\x08\x01", k)
    w.finish()
    f.close()
    return out


def undeclared_channel(base_topic_bytes: bytes, out: Path) -> Path:
    """Good Float64 messages on ~/screw_torque, and messages on channel 99 that no Channel record declares."""
    f, w = _writer(out)
    tq = _float64_channel(w, SCREW_TORQUE)
    for k in range(10):
        w.add_message(tq, k * 1000, base_topic_bytes, k * 1000)
        w.add_message(99, k * 1000 + 1, base_topic_bytes, k * 1000 + 1)
    w.finish()
    f.close()
    return out


def malformed_messages(out: Path) -> Path:
    """A good bag of JointState and ~/screw_torque, with malformed messages among the good ones.

    ~/screw_torque: one 4-byte message (only the CDR header). /joint_states: one cut in half, one
    whose `name` sequence declares 2^31 - 1 strings.
    """
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    f, w = _writer(out)
    js_def = ts.generate_msgdef("sensor_msgs/msg/JointState", ros_version=2)[0]
    sid = w.register_schema("sensor_msgs/msg/JointState", "ros2msg", js_def.encode())
    js = w.register_channel("/joint_states", "cdr", sid, {})
    tq = _float64_channel(w, SCREW_TORQUE)
    name_count_at = 4 + 8 + 4 + ((len(b"base") + 1 + 3) // 4) * 4  # header: stamp, frame_id "base"
    for k in range(20):
        t = k * 10_000_000
        body = joint_state_cdr(t)
        if k == 5:
            body = body[: len(body) // 2]
        elif k == 6:
            huge = bytearray(body)
            struct.pack_into("<I", huge, name_count_at, 2**31 - 1)
            body = bytes(huge)
        w.add_message(js, t, body, t)
        w.add_message(tq, t, FLOAT64_CDR[:4] if k == 7 else FLOAT64_CDR, t)
    w.finish()
    f.close()
    return out


def evil_schema(out: Path) -> Path:
    """A topic whose schema names the package `evilmod` (play used to import `evilmod.msg`)."""
    return beside_screw_torque(out, "/evil", "evilmod/msg/Evil", b"float64 data", n=5)


def evil_module(folder: Path) -> Path:
    """`evilmod.py` in `folder`: importing it writes EVIL_MARKER there."""
    marker = folder / EVIL_MARKER
    (folder / "evilmod.py").write_text(f"open({str(marker)!r}, 'w').write('imported')\n")
    return marker


def joint_state_cdr(t_ns: int) -> bytes:
    """One JointState stamped `t_ns` (frame "base", screw and nut joints) as CDR, from the rosbags typestore."""
    import numpy as np
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id="base")
    msg = T["sensor_msgs/msg/JointState"](header=hdr, name=["screw_joint", "nut_joint"],
                                         position=np.array([10.0 * t_ns * 1e-9, 0.002 * t_ns * 1e-9]), velocity=np.array([10.0, 0.002]),
                                         effort=np.array([0.5, 2000.0]))
    return bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def string_cdr(text: str) -> bytes:
    """A std_msgs/String as CDR: encapsulation header, length with the NUL, the bytes, the NUL."""
    raw = text.encode()
    return b"\x00\x01\x00\x00" + struct.pack("<I", len(raw) + 1) + raw + b"\x00"


def joint_states_bag(out: Path, n: int = 20, *, times_ns=None, position=None, strings=None, compression=None,
                     finish: bool = True) -> Path:
    """/joint_states (screw and nut joints, `joint_state_cdr`) at `times_ns` (default 10 ms apart), the
    nut position replaced by `position` where given; `strings`: {topic: [text, ...]} as std_msgs/String."""
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    f = open(out, "wb")
    w = Writer(f, compression=compression or CompressionType.ZSTD)
    w.start(profile="ros2", library="hostile corpus")
    sid = w.register_schema("sensor_msgs/msg/JointState", "ros2msg",
                            ts.generate_msgdef("sensor_msgs/msg/JointState", ros_version=2)[0].encode())
    js = w.register_channel("/joint_states", "cdr", sid, {})
    times = list(times_ns) if times_ns is not None else [k * 10_000_000 for k in range(n)]
    for k, t in enumerate(times):
        body = joint_state_cdr(max(t, 0))
        if position is not None:
            T = ts.types
            msg = ts.deserialize_cdr(body, "sensor_msgs/msg/JointState")
            msg = T["sensor_msgs/msg/JointState"](header=msg.header, name=msg.name,
                                                 position=msg.position * 0 + position[k % len(position)],
                                                 velocity=msg.velocity, effort=msg.effort)
            body = bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/JointState"))
        w.add_message(js, t, body, t)
    ssid = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
    for topic, texts in (strings or {}).items():
        cid = w.register_channel(topic, "cdr", ssid, {})
        for k, text in enumerate(texts):
            w.add_message(cid, k, string_cdr(text), k)
    if finish:
        w.finish()
    f.close()
    return out


def recursive_schema(out: Path) -> Path:
    """/tree whose custom type contains a sequence of itself, beside a good ~/screw_torque."""
    definition = b"Node[] children\nfloat64 x\n" + b"=" * 80 + b"\nMSG: treepkg/Node\nNode[] children\nfloat64 x\n"
    return beside_screw_torque(out, "/tree", "treepkg/msg/Node", definition, n=5)


def two_types(out: Path) -> Path:
    """/joint_states recorded on two channels: one JointState, one Float64."""
    f, w = _writer(out)
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    sid = w.register_schema("sensor_msgs/msg/JointState", "ros2msg",
                            ts.generate_msgdef("sensor_msgs/msg/JointState", ros_version=2)[0].encode())
    js = w.register_channel("/joint_states", "cdr", sid, {})
    fl = _float64_channel(w, "/joint_states")
    for k in range(10):
        w.add_message(js, k * 10_000_000, joint_state_cdr(k * 10_000_000), k * 10_000_000)
        w.add_message(fl, k * 10_000_000 + 1, FLOAT64_CDR, k * 10_000_000 + 1)
    w.finish()
    f.close()
    return out
