"""Sensors around the screw: motor encoder, nut linear encoder, nut load cell.

Pure functions of (true values, sensor parameters, step index). Noise and dropout draw from
a counter-based generator: each draw is a hash of (seed, step, stream), so a step needs no
generator object in the state, stays a pure function of (state, inputs) and repeats bit for
bit for a seed in lockstep, whatever order the steps are evaluated in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

_M64 = (1 << 64) - 1


def _splitmix64(x: int) -> int:
    """One round of SplitMix64 (Steele, Lea, Flood 2014): a bijective 64-bit mixer."""
    x = (x + 0x9E3779B97F4A7C15) & _M64
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _M64
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _M64
    return x ^ (x >> 31)


def uniform(seed: int, step: int, stream: int) -> float:
    """A uniform draw in (0, 1] keyed by (seed, step, stream)."""
    z = _splitmix64(_splitmix64(_splitmix64(seed & _M64) ^ (step & _M64)) ^ (stream & _M64))
    return ((z >> 11) + 1) * (1.0 / (1 << 53))


def normal(seed: int, step: int, stream: int) -> float:
    """A standard normal draw keyed by (seed, step, stream) (Box–Muller on two keyed uniforms)."""
    u1 = uniform(seed, step, 2 * stream)
    u2 = uniform(seed, step, 2 * stream + 1)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


def quantise(value: float, resolution: float) -> float:
    """Round `value` down to a whole number of `resolution` steps (0: unchanged), as an incremental encoder counts."""
    if resolution <= 0.0:
        return value
    return math.floor(value / resolution) * resolution


def first_order(previous: float, target: float, bandwidth_hz: float | None, dt_s: float) -> float:
    """Exact zero-order-hold step of a first-order low-pass y' = 2π f (x − y); None: no filter."""
    if bandwidth_hz is None:
        return target
    a = math.exp(-2.0 * math.pi * bandwidth_hz * dt_s)
    return target + (previous - target) * a


class TrueSample(NamedTuple):
    """The true values the sensors see at one step (what their latency delays), by name.

    Motor angle on the motor shaft (rad), screw angle (rad) and speed (rad/s: the rotor's with a
    compliant coupling, where the motor encoder sits), the nut's own position (m), velocity (m/s)
    and axial force (N)."""

    motor_angle_rad: float
    screw_angle_rad: float
    screw_speed_rad_s: float
    nut_position_m: float
    nut_velocity_m_s: float
    nut_force_n: float


@dataclass(frozen=True)
class SensorChannel:
    """One sensor: the quantities it reports (name, unit), the one its bias and noise faults act on,
    and the stream numbers of its noise and dropout draws (one per sensor and purpose).

    Each reports a freshness flag besides (``<name>_fresh``: 0 while dropped or stuck)."""

    name: str
    quantities: tuple[tuple[str, str], ...]
    primary: str
    stream: int
    dropout_stream: int

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(q for q, _ in self.quantities)


SENSORS = (
    SensorChannel("motor_encoder", (("motor_angle_rad", "rad"), ("screw_angle_rad", "rad"),
                                    ("screw_speed_rad_s", "rad/s")), "screw_angle_rad", 1, 11),
    SensorChannel("linear_encoder", (("nut_position_m", "m"), ("nut_velocity_m_s", "m/s")), "nut_position_m", 2, 12),
    SensorChannel("load_cell", (("nut_force_n", "N"),), "nut_force_n", 3, 13),
)
# the readings, then the freshness flags, in the order of the `measured` block
MEASURED_QUANTITIES = tuple(q for s in SENSORS for q in s.quantities) + tuple((f"{s.name}_fresh", "1") for s in SENSORS)
STREAM = {s.name: s.stream for s in SENSORS}
DROPOUT_STREAM = {s.name: s.dropout_stream for s in SENSORS}
