"""Read the few fields a controller needs straight from CDR bytes (raw subscriptions).

A 1 kHz controller in Python spends more on building an rclpy message object per sample (every
field goes through a checked setter) than on its own law, and a reader that falls behind acts on
stale states. So the controllers of this project (`prsm_ros.cli.demo_controller`,
`prsm_ros.bench.rt_controller`) subscribe with `raw=True` and read only what they use from the bytes.
The writing side is `prsm_ros.cdr_write` (templates serialised by rclpy); this is the reading side,
for little-endian plain CDR (what Fast DDS writes on x86 and ARM), used by the node too for its
`std_msgs/Float64` commands (`float64_data`). The tests check every reader against rclpy's own
serialiser.

CDR layout rules used here: after the 4-byte encapsulation header, each primitive is aligned to
its size counted from the end of that header; a string is a uint32 length (terminating NUL
included) and the bytes; a sequence is a uint32 count and the elements.
"""

from __future__ import annotations

import struct

from prsm_sim.errors import InputError

_HEADER = 4  # encapsulation header: representation id (2 bytes) and options (2 bytes)
_LITTLE_ENDIAN_CDR = 1  # second byte of the representation id: CDR_LE


def _align(o: int, n: int) -> int:
    """Offset `o` rounded up to a multiple of `n`, counted from the end of the encapsulation header."""
    return _HEADER + (o - _HEADER + n - 1) // n * n


def _check(b: bytes) -> None:
    if b[1] != _LITTLE_ENDIAN_CDR:
        raise InputError(f"encapsulation {b[:2].hex()}: only little-endian plain CDR (0001) is read")


def _string_at(b: bytes, o: int) -> tuple[str, int]:
    """(string, offset after it) of the CDR string at `o`."""
    o = _align(o, 4)
    (n,) = struct.unpack_from("<I", b, o)
    return b[o + 4:o + 3 + n].decode(), o + 4 + n  # n counts the terminating NUL


def _skip_string(b: bytes, o: int) -> int:
    o = _align(o, 4)
    return o + 4 + struct.unpack_from("<I", b, o)[0]


def _stamp_ns(b: bytes) -> int:
    """A std_msgs/Header's stamp (the message's first field), ns."""
    sec, nsec = struct.unpack_from("<iI", b, _HEADER)
    return sec * 1_000_000_000 + nsec


def _joint_state_arrays(b: bytes) -> tuple[int, list[tuple[int, int]]]:
    """Offset of `name` and (offset of the first double, count) of position, velocity and effort
    of a sensor_msgs/JointState (header: stamp, frame_id; then name, position, velocity, effort)."""
    _check(b)
    names_at = o = _align(_skip_string(b, _HEADER + 8), 4)  # after stamp and header.frame_id
    (count,) = struct.unpack_from("<I", b, o)
    o += 4
    for _ in range(count):
        o = _skip_string(b, o)
    arrays = []
    for _ in range(3):
        o = _align(o, 4)
        (count,) = struct.unpack_from("<I", b, o)
        o += 4
        if count:
            o = _align(o, 8)
        arrays.append((o, count))
        o += 8 * count
    return names_at, arrays


def joint_state_names(b: bytes) -> list[str]:
    """The joint names of a CDR sensor_msgs/JointState."""
    o, _ = _joint_state_arrays(b)
    (count,) = struct.unpack_from("<I", b, o)
    o += 4
    names = []
    for _ in range(count):
        name, o = _string_at(b, o)
        names.append(name)
    return names


def joint_state_stamp_effort0(b: bytes) -> tuple[int, float | None]:
    """(header stamp ns, effort[0] or None) of a CDR sensor_msgs/JointState."""
    _, arrays = _joint_state_arrays(b)
    at, count = arrays[2]
    return _stamp_ns(b), (struct.unpack_from("<d", b, at)[0] if count else None)


def joint_state_position(b: bytes, name: str) -> tuple[int, float]:
    """(header stamp ns, position of joint `name`, else of the first joint) of a CDR sensor_msgs/JointState.

    Raises IndexError when it carries no position."""
    names = joint_state_names(b)
    k = names.index(name) if name in names else 0
    _, ((p_at, p_n), _, _) = _joint_state_arrays(b)
    if k >= p_n:
        raise IndexError(f"no position for joint {k} in a state of {p_n} positions")
    return _stamp_ns(b), struct.unpack_from("<d", b, p_at + 8 * k)[0]


def joint_state_at(b: bytes, index: int) -> tuple[int, float, float]:
    """(header stamp ns, position[index], velocity[index]) of a CDR sensor_msgs/JointState.

    Raises IndexError when either array is shorter than `index` + 1."""
    _, ((p_at, p_n), (v_at, v_n), _) = _joint_state_arrays(b)
    if not (0 <= index < p_n and index < v_n):
        raise IndexError(f"joint {index} not in a state of {p_n} positions and {v_n} velocities")
    (x,) = struct.unpack_from("<d", b, p_at + 8 * index)
    (v,) = struct.unpack_from("<d", b, v_at + 8 * index)
    return _stamp_ns(b), x, v


def time_reference_stamps(b: bytes) -> tuple[int, int]:
    """(header stamp ns, time_ref ns) of a CDR sensor_msgs/TimeReference."""
    _check(b)
    o = _align(_skip_string(b, _HEADER + 8), 4)
    rsec, rnsec = struct.unpack_from("<iI", b, o)
    return _stamp_ns(b), rsec * 1_000_000_000 + rnsec


def float64_data(b: bytes) -> float:
    """`data` of a CDR std_msgs/Float64 (the node's commands, taken raw by its step thread).

    Raises ValueError for another encapsulation (the caller deserialises those), struct.error
    when the bytes are too short."""
    _check(b)
    return struct.unpack_from("<d", b, _HEADER)[0]
