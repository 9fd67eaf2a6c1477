"""The per-step messages as CDR bytes from templates serialised by rclpy (what the node publishes each step).

At 1 kHz the node spent more on building rclpy message objects and serialising them than on the
step itself (every field assignment of an rclpy message is a checked Python setter). These
messages have a fixed shape for a run (two joints, one frame, one internal-load layout), so each
is a constant template with a few numeric slots: `StepEncoder` fills the slots with
`struct.pack_into` and returns bytes that rclpy publishes as they are (`Publisher.publish(bytes)`)
and the MCAP recorder writes as they are: serialised once, for DDS and the bag.

The CDR itself comes from rclpy's encoder (`rclpy.serialization.serialize_message`); this module
knows no CDR layout. Each template is serialised once with every slot at zero, then twice per slot
with that slot at two distinctive probe values: the one offset where each probe's bytes appear is
the slot, and the byte order they appear in is the encoding's. Strings and sequences whose lengths are
fixed for the run (joint names, frame id, layout labels, the internal-load count) stay as the
library wrote them. The tests decode every encoder's bytes with rclpy's deserialiser and compare
them with the `MessageMapper` messages.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable, Sequence

import numpy as np

from builtin_interfaces.msg import Time
from geometry_msgs.msg import WrenchStamped
from rclpy.serialization import serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from prsm_sim import OUTPUT_FIELDS, InputError, InternalLayout, Outputs

# Two probe values per struct code, packed bytes all non-zero and unlike each other, so that a slot
# is the one place where each probe's bytes appear in its own serialisation.
_PROBES = {"i": (0x11223344, 0x5A6B7C0D), "I": (0x11223344, 0x5A6B7C0D),
           "d": tuple(struct.unpack("<d", bytes(range(k, k + 8)))[0] for k in (0x11, 0x31))}


def split_ns(ns: int) -> tuple[int, int]:
    """(sec, nanosec) of a builtin_interfaces/Time for a time in ns."""
    return divmod(ns, 1_000_000_000)


def _time(sec: int, nanosec: int) -> Time:
    return Time(sec=sec, nanosec=nanosec)


def _find_slot(probed: tuple[bytes, bytes], kind: str) -> tuple[int, str]:
    """Offset and byte order ("<" or ">") of the slot holding `_PROBES[kind]` in the two serialisations.

    Both probes are looked for at the same offset, rather than diffing against a zero serialisation,
    because the serialiser does not zero its alignment padding: those bytes can differ between calls.
    """
    hits = []
    for order in "<>":
        a, b = (struct.pack(order + kind, v) for v in _PROBES[kind])
        at = probed[0].find(a)
        while at >= 0:
            if probed[1][at:at + len(b)] == b:
                hits.append((at, order))
            at = probed[0].find(a, at + 1)
    if len(hits) != 1:
        raise InputError(f"expected one {kind!r} slot in the serialised probes, found {hits}")
    return hits[0]


class _Template:
    """One message's serialised bytes and its numeric slots, found from rclpy's output.

    `build(values)` returns the message with the slot values in the given order; `kinds` are their
    struct codes. Slots that lie back to back in the bytes are packed with one `Struct` (a run).
    """

    def __init__(self, build: Callable[[Sequence], object], kinds: str) -> None:
        zeros = [0] * len(kinds)
        self.bytes = serialize_message(build(zeros))
        found = []
        for i, kind in enumerate(kinds):
            probed = []
            for value in _PROBES[kind]:
                probe = list(zeros)
                probe[i] = value
                probed.append(serialize_message(build(probe)))
            if len(probed[0]) != len(self.bytes) or len(probed[1]) != len(self.bytes):
                raise InputError("a numeric slot changed the serialised length; it cannot be a template slot")
            found.append(_find_slot(tuple(probed), kind))
        if len({order for _, order in found}) > 1:
            raise InputError("slots of one message serialised in different byte orders")
        self.order = found[0][1] if found else "<"
        runs: list[list] = []  # [offset, codes, first index, end index]
        for i, ((at, _), kind) in enumerate(zip(found, kinds)):
            last = runs[-1] if runs else None
            if last is not None and last[0] + struct.calcsize(self.order + last[1]) == at:
                last[1] += kind
                last[3] = i + 1
            else:
                runs.append([at, kind, i, i + 1])
        self._runs = [(struct.Struct(self.order + codes).pack_into, at, b - a) for at, codes, a, b in runs]

    def runs(self, sizes: tuple[int, ...]) -> list[tuple[Callable, int]]:
        """(pack_into, offset) of each run, checked to hold `sizes` values each, in slot order.

        The caller writes its runs with direct `pack_into` calls: at 1 kHz a generic loop over the
        runs with slicing cost about as much again as the packing (measured with timeit).
        """
        if tuple(n for _, _, n in self._runs) != sizes:
            raise InputError(f"slot runs of {[n for _, _, n in self._runs]} values, expected {list(sizes)}")
        return [(pack, at) for pack, at, _ in self._runs]

    def fill(self, *values) -> bytes:
        """The template with every slot filled, `values` in slot order (for the rarer messages)."""
        buf = bytearray(self.bytes)
        i = 0
        for pack, at, n in self._runs:
            pack(buf, at, *values[i:i + n])
            i += n
        return bytes(buf)


class StepEncoder:
    """CDR bytes of the per-step messages for one model's layout (`MessageMapper`'s twins)."""

    def __init__(self, layout: InternalLayout, joint_names: tuple[str, str], nut_frame: str,
                 dims: list[tuple[str, int]]) -> None:
        self.layout = layout
        self._fields = tuple(n for n, _ in OUTPUT_FIELDS)
        names = list(joint_names)

        def joint_state(v):
            m = JointState(name=names, position=[float(x) for x in v[2:4]],
                           velocity=[float(x) for x in v[4:6]], effort=[float(x) for x in v[6:8]])
            m.header.stamp = _time(v[0], v[1])
            return m

        def wrench(v):
            m = WrenchStamped()
            m.header.stamp, m.header.frame_id = _time(v[0], v[1]), nut_frame
            m.wrench.force.z = float(v[2])
            return m

        self._js = _Template(joint_state, "iIdddddd")
        (self._js_stamp, self._js_p, self._js_v, self._js_e) = self._js.runs((2, 2, 2, 2))
        self._wr = _Template(wrench, "iId")
        (self._wr_stamp, self._wr_force_z) = self._wr.runs((2, 1))
        self._clock = _Template(lambda v: Clock(clock=_time(v[0], v[1])), "iI")
        (self._clock_stamp,) = self._clock.runs((2,))
        # std_msgs/Float64MultiArray: everything before the data values is constant for the run
        # (labels, sizes, the value count); the data are the serialisation's last bytes.
        self._n_values = len(self._fields) + layout.size
        dim = [MultiArrayDimension(label=label, size=size, stride=size) for label, size in dims]
        msg = Float64MultiArray(data=[0.0] * self._n_values)
        msg.layout.dim = dim
        base = serialize_message(msg)
        head_len = len(base) - 8 * self._n_values
        probed = []
        for value in _PROBES["d"]:
            msg.data = [0.0] * (self._n_values - 1) + [value]
            probed.append(serialize_message(msg))
        at, order = _find_slot(tuple(probed), "d")
        if at != len(base) - 8 or base[head_len:] != bytes(8 * self._n_values):
            raise InputError("Float64MultiArray data are not the serialisation's last bytes")
        self._il_head = base[:head_len]
        # the scalars packed by one Struct, the internal loads as the array's bytes in the same order;
        # the layout's size is read once (a property summing numpy products: 7 µs per call)
        self._il_scalars = struct.Struct(f"{order}{len(self._fields)}d").pack
        self._il_dtype = np.dtype(f"{order}f8")
        self._n_internal = layout.size

    def joint_state(self, out: Outputs, stamp_ns: int) -> bytes:
        buf = bytearray(self._js.bytes)
        (stamp, at_s), (p, at_p), (v, at_v), (e, at_e) = self._js_stamp, self._js_p, self._js_v, self._js_e
        stamp(buf, at_s, *split_ns(stamp_ns))
        p(buf, at_p, out.screw_angle_rad, out.nut_position_m)
        v(buf, at_v, out.screw_speed_rad_s, out.nut_velocity_m_s)
        e(buf, at_e, out.screw_torque_nm, out.nut_force_n)
        return bytes(buf)

    def wrench(self, out: Outputs, stamp_ns: int) -> bytes:
        buf = bytearray(self._wr.bytes)
        (stamp, at_s), (f, at_f) = self._wr_stamp, self._wr_force_z
        stamp(buf, at_s, *split_ns(stamp_ns))
        f(buf, at_f, out.nut_force_n)
        return bytes(buf)

    def clock(self, stamp_ns: int) -> bytes:
        buf = bytearray(self._clock.bytes)
        stamp, at = self._clock_stamp
        stamp(buf, at, *split_ns(stamp_ns))
        return bytes(buf)

    def internal_loads(self, out: Outputs) -> bytes:
        data = self._il_head + self._il_scalars(*out.scalar_values())
        if self._n_internal:
            data += out.internal.astype(self._il_dtype, copy=False).tobytes()
        return data

    @staticmethod
    def time_reference(stamp_ns: int, time_ref_ns: int, source: str) -> bytes:
        """sensor_msgs/TimeReference (the command echo), from a template per source topic."""
        return _time_reference_template(source).fill(*split_ns(stamp_ns), *split_ns(time_ref_ns))


@functools.lru_cache(maxsize=16)  # one source per command topic; lru_cache is thread-safe
def _time_reference_template(source: str) -> _Template:
    def build(v):
        m = TimeReference(source=source, time_ref=_time(v[2], v[3]))
        m.header.stamp = _time(v[0], v[1])
        return m
    return _Template(build, "iIiI")
