"""The servo drive's control law: effort, velocity (PI) and position (P → PI cascade) (issue 14).

Pure: `drive_update` maps the drive's memory, the command and the measured feedback to the
screw-side torque reference and the new memory. Loops run in screw coordinates.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from prsm_sim.actuator.params import DriveParams


class DriveOut(NamedTuple):
    torque_nm: float  # screw-side torque reference after the limit
    integral_nm: float  # speed-loop integrator (its torque contribution)
    limited: bool
    speed_reference_rad_s: float


def drive_update(drive: DriveParams, mode: str, command: float, integral_nm: float, speed_meas_rad_s: float,
                 nut_meas_m: float, lead_per_rad_m: float, torque_limit_nm: float, h_s: float,
                 feedforward_rad_s: float = 0.0) -> DriveOut:
    """One loop update.

    effort: the command is the screw torque (N·m). velocity: the command is the screw speed
    (rad/s); τ = kp e + ∫ ki e dt. position: the command is the nut position (m);
    ω_ref = kp_pos (x_ref − x) / (L/2π) + `feedforward_rad_s`, then the speed loop. The speed reference is clamped
    to ±speed_limit; the torque to ±torque_limit, and the integrator holds while the output
    sits on the limit and the error would push it further (conditional integration).
    """
    if mode == "effort":
        tau = max(-torque_limit_nm, min(torque_limit_nm, command))
        return DriveOut(tau, integral_nm, tau != command, 0.0)
    if mode == "position":
        w_ref = drive.position_kp_1_s * (command - nut_meas_m) / lead_per_rad_m + feedforward_rad_s
    else:
        w_ref = command
    lim = drive.speed_limit_rad_s
    w_ref = max(-lim, min(lim, w_ref))
    e = w_ref - speed_meas_rad_s
    integ = integral_nm + drive.speed_ki_nm_rad * e * h_s
    raw = drive.speed_kp_nm_s_rad * e + integ
    tau = max(-torque_limit_nm, min(torque_limit_nm, raw))
    limited = tau != raw
    if limited and raw * e > 0.0:
        # anti-windup: the integrator stops where the output meets the limit (never beyond its new value)
        edge = math.copysign(torque_limit_nm, raw) - drive.speed_kp_nm_s_rad * e
        integ = min(integ, max(edge, integral_nm)) if raw > 0 else max(integ, min(edge, integral_nm))
    return DriveOut(tau, integ, limited, w_ref)
