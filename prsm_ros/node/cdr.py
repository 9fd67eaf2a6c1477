"""The node's per-step messages written straight to CDR bytes, pure Python (no rclpy; issue 15).

At 1 kHz the node spent more on building rclpy message objects and serialising them than on the
step itself (every field assignment of an rclpy message is a checked Python setter). These
messages have a fixed shape for a run (two joints, one frame, one internal-load layout), so each
is a constant CDR template with a few numeric slots: `StepEncoder` fills the slots with
`struct.pack_into` and returns bytes that rclpy publishes as they are (`Publisher.publish(bytes)`)
and the MCAP recorder writes as they are: serialised once, for DDS and the bag.

Encoding: OMG CDR little-endian with the 4-byte encapsulation header (0x00 0x01 0x00 0x00), as
rmw_fastrtps and rosbag2 use; alignment counts from the end of that header. Field order follows
the .msg definitions (`sensor_msgs/JointState`, `geometry_msgs/WrenchStamped`,
`std_msgs/Float64MultiArray`, `rosgraph_msgs/Clock`, `sensor_msgs/TimeReference`); the tests
decode every encoder's bytes with rclpy's own deserialiser and compare them with the
`MessageMapper` messages.
"""

from __future__ import annotations

import array
import struct

from prsm_sim import OUTPUT_FIELDS, InternalLayout, Outputs

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR_LE
_STAMP = struct.Struct("<iI")
_D2 = struct.Struct("<dd")
_D1 = struct.Struct("<d")


class _Writer:
    """Builds one message's CDR bytes; `slot` reserves an aligned numeric field and returns its offset."""

    def __init__(self) -> None:
        self.buf = bytearray(_ENCAPSULATION)

    def align(self, n: int) -> None:
        self.buf += b"\x00" * ((-(len(self.buf) - 4)) % n)

    def u32(self, v: int) -> None:
        self.align(4)
        self.buf += struct.pack("<I", v)

    def string(self, s: str) -> None:
        data = s.encode() + b"\x00"
        self.u32(len(data))
        self.buf += data

    def slot(self, size: int, align: int) -> int:
        self.align(align)
        at = len(self.buf)
        self.buf += b"\x00" * size
        return at

    def header(self, frame_id: str) -> int:
        at = self.slot(8, 4)  # builtin_interfaces/Time: int32 sec, uint32 nanosec
        self.string(frame_id)
        return at


def split_ns(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a builtin_interfaces/Time for a time in ns."""
    return divmod(ns, 1_000_000_000)


class StepEncoder:
    """CDR bytes of the per-step messages for one model's layout (`MessageMapper`'s twins)."""

    def __init__(self, layout: InternalLayout, joint_names: tuple[str, str], nut_frame: str,
                 dims: list[tuple[str, int]]) -> None:
        self.layout = layout
        self._fields = tuple(n for n, _ in OUTPUT_FIELDS)
        w = _Writer()  # sensor_msgs/JointState
        self._js_stamp = w.header("")
        w.u32(len(joint_names))
        for n in joint_names:
            w.string(n)
        self._js_slots = []
        for _ in range(3):  # position, velocity, effort: 2 doubles each
            w.u32(2)
            self._js_slots.append(w.slot(16, 8))
        self._js = bytes(w.buf)
        w = _Writer()  # geometry_msgs/WrenchStamped
        self._wr_stamp = w.header(nut_frame)
        at = w.slot(48, 8)  # force x, y, z, torque x, y, z
        self._wr_force_z = at + 16
        self._wr = bytes(w.buf)
        w = _Writer()  # rosgraph_msgs/Clock
        self._clock_stamp = w.slot(8, 4)
        self._clock = bytes(w.buf)
        w = _Writer()  # std_msgs/Float64MultiArray: layout (dims, data_offset), then data
        w.u32(len(dims))
        for label, size in dims:
            w.string(label)
            w.u32(size)
            w.u32(size)  # stride = size (one segment per dimension entry; see messages.py)
        w.u32(0)  # data_offset
        self._n_values = len(self._fields) + layout.size
        w.u32(self._n_values)
        w.align(8)
        self._il_head = bytes(w.buf)

    def joint_state(self, out: Outputs, stamp_ns: int) -> bytes:
        buf = bytearray(self._js)
        _STAMP.pack_into(buf, self._js_stamp, *split_ns(stamp_ns))
        p, v, e = self._js_slots
        _D2.pack_into(buf, p, out.screw_angle_rad, out.nut_position_m)
        _D2.pack_into(buf, v, out.screw_speed_rad_s, out.nut_velocity_m_s)
        _D2.pack_into(buf, e, out.screw_torque_nm, out.nut_force_n)
        return bytes(buf)

    def wrench(self, out: Outputs, stamp_ns: int) -> bytes:
        buf = bytearray(self._wr)
        _STAMP.pack_into(buf, self._wr_stamp, *split_ns(stamp_ns))
        _D1.pack_into(buf, self._wr_force_z, out.nut_force_n)
        return bytes(buf)

    def clock(self, stamp_ns: int) -> bytes:
        buf = bytearray(self._clock)
        _STAMP.pack_into(buf, self._clock_stamp, *split_ns(stamp_ns))
        return bytes(buf)

    def internal_loads(self, out: Outputs) -> bytes:
        row = array.array("d", out.scalar_values())
        if self.layout.size:
            row.frombytes(out.internal.astype("<f8", copy=False).tobytes())
        return self._il_head + row.tobytes()

    @staticmethod
    def time_reference(stamp_ns: int, time_ref_ns: int, source: str) -> bytes:
        """sensor_msgs/TimeReference (the command echo; rare enough to build in full)."""
        w = _Writer()
        _STAMP.pack_into(w.buf, w.header(""), *split_ns(stamp_ns))
        _STAMP.pack_into(w.buf, w.slot(8, 4), *split_ns(time_ref_ns))
        w.string(source)
        return bytes(w.buf)
