"""The demo's nut-position controller law and its reference, pure (no ROS, no I/O).

The ROS demo controller (`prsm_ros.cli.demo_controller`) runs this law in its own process over
DDS; studies and gain tuning (`prsm-sweep`) run the same law offline against a `Simulator` with
`run_position_loop`, so a gain tuned here is the gain the demo would use.

Control law (nut coordinates x, lead per radian p, reflected inertia J about the screw):
    τ = (J/p)·(a_ref + 2ζω ė + ω² e + (ω³/κ) ∫e) + p·F_load
with e = x_ref − x: critically damped (ζ = 1) error dynamics at `bandwidth_hz`, a slow integral
(κ = 10) for friction, and the load's static torque fed forward. The inertia is the `ideal`
model's reflected inertia of the nominal preset (`prsm_sim.models.ideal.reflected_inertia`),
i.e. model-based tuning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


from prsm_sim.errors import InputError
from prsm_sim.stepping.trajectory import Trajectory, trajectory_from_rows

# The demo's defaults (prsm-demo and `python -m prsm_ros.cli.demo_controller`)
DEFAULT_GAINS = {"bandwidth_hz": 8.0, "damping": 1.0, "integral_ratio": 10.0}
DEFAULT_AMPLITUDE_M = 0.02
DEFAULT_FREQUENCY_HZ = 0.5
DEFAULT_MAX_TORQUE_NM = 50.0


def reference(t_s: float, amplitude_m: float, frequency_hz: float) -> tuple[float, float, float]:
    """x_ref = A/2 (1 − cos 2πft): starts at rest at 0, smooth; returns position, velocity, acceleration."""
    w = 2 * math.pi * frequency_hz
    return (0.5 * amplitude_m * (1 - math.cos(w * t_s)), 0.5 * amplitude_m * w * math.sin(w * t_s),
            0.5 * amplitude_m * w * w * math.cos(w * t_s))


@dataclass
class PositionController:
    """Nut-position PID with acceleration and load feed-forward; output clamped to ±max_torque_nm."""

    inertia_kgm2: float
    lead_per_rad_m: float
    bandwidth_hz: float = DEFAULT_GAINS["bandwidth_hz"]
    damping: float = DEFAULT_GAINS["damping"]
    integral_ratio: float = DEFAULT_GAINS["integral_ratio"]
    load_n: float = 0.0
    max_torque_nm: float = DEFAULT_MAX_TORQUE_NM
    integral_ms: float = 0.0  # ∫e dt, m·s

    def torque(self, e_m: float, de_m_s: float, a_ref_m_s2: float, dt_s: float) -> float:
        w = 2 * math.pi * self.bandwidth_hz
        self.integral_ms += e_m * dt_s
        accel = a_ref_m_s2 + 2 * self.damping * w * de_m_s + w * w * e_m + w ** 3 / self.integral_ratio * self.integral_ms
        tau = self.inertia_kgm2 / self.lead_per_rad_m * accel + self.lead_per_rad_m * self.load_n
        return max(-self.max_torque_nm, min(self.max_torque_nm, tau))


@dataclass
class Tracking:
    """Running tracking statistics."""

    n: int = 0
    sum_sq_m2: float = 0.0
    max_abs_m: float = 0.0

    def add(self, e_m: float) -> None:
        self.n += 1
        self.sum_sq_m2 += e_m * e_m
        self.max_abs_m = max(self.max_abs_m, abs(e_m))

    @property
    def rms_m(self) -> float:
        return math.sqrt(self.sum_sq_m2 / self.n) if self.n else math.nan


def run_position_loop(sim, ctl: PositionController, duration_s: float, load_n: float,
                      amplitude_m: float = DEFAULT_AMPLITUDE_M,
                      frequency_hz: float = DEFAULT_FREQUENCY_HZ) -> tuple[Trajectory, Tracking]:
    """Close the demo's loop offline: one controller update per simulator step (1 kHz at dt = 1 ms).

    As in the demo, the controller reads the state at the end of each step (nut position
    x = p θ_S and velocity p ω_S, docs/model.md §2), scores the tracking error there, and
    holds its torque over the next step. `load_n` is the plant's load; the controller feeds
    forward its own `ctl.load_n` (the nominal one), so a load spread is a disturbance.
    """
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"duration_s = {duration_s!r}: must be a finite number > 0")
    n = int(round(duration_s / sim.dt_s))
    if n < 1:
        raise InputError(f"duration_s = {duration_s} is shorter than one step ({sim.dt_s} s)")
    p = sim.params.geometry.lead_per_rad_m
    track = Tracking()
    rows = []
    for _ in range(n):
        s = sim.state
        t = s.time_s
        x_ref, v_ref, a_ref = reference(t, amplitude_m, frequency_hz)
        e = x_ref - p * s.screw_angle_rad
        if sim.nstep:
            track.add(e)
        tau = ctl.torque(e, v_ref - p * s.screw_speed_rad_s, a_ref, sim.dt_s if sim.nstep else 0.0)
        rows.append(sim.step(tau, load_n))
    s = sim.state
    track.add(reference(s.time_s, amplitude_m, frequency_hz)[0] - p * s.screw_angle_rad)
    return trajectory_from_rows(rows, sim.layout, sim.state), track

