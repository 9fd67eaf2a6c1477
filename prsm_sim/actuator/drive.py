"""The servo drive's control law: effort, velocity (PI) and position (P → PI cascade).

Pure: `drive_update` maps the drive's memory, the command and the measured feedback to the
screw-side torque reference and the new memory. Loops run in screw coordinates.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from functools import partial
from typing import NamedTuple

import numpy as np

from prsm_sim.errors import DriveLoopWarning, InputError
from prsm_sim.actuator.params import DriveParams, SensorParams


class DriveOut(NamedTuple):
    torque_nm: float  # screw-side torque reference after the limit
    integral_nm: float  # speed-loop integrator (its torque contribution)
    limited: bool
    speed_reference_rad_s: float


def loop_schedule(loop_rate_hz: float | None, dt_s: float) -> tuple[int, int]:
    """(loop updates per step, steps per loop update) for the drive's loop rate at the step `dt_s`.

    The loops run on the step's grid: a whole number of updates per step (sub-steps) or one update
    every whole number of steps. A rate that is no whole ratio of the step rate 1/dt_s runs at the
    nearest such rate; `warnings.warn` then says which, once, where the actuator is built.
    """
    if loop_rate_hz is None:
        return 1, 1
    ratio = loop_rate_hz * dt_s
    n_sub, hold = (max(1, round(ratio)), 1) if ratio >= 1.0 else (1, max(1, round(1.0 / ratio)))
    runs_hz = n_sub / (hold * dt_s)
    if not math.isclose(runs_hz, loop_rate_hz, rel_tol=1e-9):
        warnings.warn(f"drive.loop_rate_hz = {loop_rate_hz!r} is no whole ratio of the step rate {1.0 / dt_s:g} Hz "
                      f"(dt_s = {dt_s!r}): the drive's loops run at {runs_hz:g} Hz, "
                      + (("once a step" if n_sub == 1 else f"{n_sub} updates a step") if hold == 1 else f"one update every {hold} steps"), stacklevel=4)
    return n_sub, hold


def shape_reference(r_m: float, v_m_s: float, target_m: float, target_rate_m_s: float, v_max_m_s: float,
                    a_max_m_s2: float, h_s: float) -> tuple[float, float]:
    """The drive's position reference one loop update on: it follows the command (now at `target_m`,
    moving at `target_rate_m_s`) with |v| ≤ v_max and |dv/dt| ≤ a_max, braking so as to meet it at its
    own speed, never overshooting it. Its rate is the position loop's feed-forward: a command that
    moves within those limits is followed exactly (no lag), and a command step neither asks for more
    acceleration than a_max (no torque kick) nor waits on the position error.

    Braking is planned on the loop's own grid, in the frame moving with the command: the relative
    speed u₁ at the end of this update is the largest from which the remaining distance still
    suffices, h (u₀ + u₁)/2 + u₁²/(2 a) ≤ |e| (trapezoidal position, speed changing by a h per update).
    """
    a, vt = a_max_m_s2, max(-v_max_m_s, min(v_max_m_s, target_rate_m_s))
    dv = a * h_s
    e = target_m - r_m
    vr = v_m_s - vt
    if e == 0.0 and vr == 0.0:
        return r_m + h_s * vt, vt
    s = (1.0 if e > 0.0 else -1.0) if e != 0.0 else (-1.0 if vr > 0.0 else 1.0)
    u0, dist = s * vr, abs(e)
    c = 0.5 * h_s * u0 - dist
    if c >= 0.0 and abs(vr) <= dv:
        return target_m + h_s * vt, vt  # even braking to the command's speed meets it over this update
    if math.isinf(a):
        u1 = 2.0 * dist / h_s - u0
    else:
        u1 = a * (-0.5 * h_s + math.sqrt(max(0.0, 0.25 * h_s * h_s - 2.0 * c / a)))
    v1 = max(v_m_s - dv, min(v_m_s + dv, vt + s * u1))  # the acceleration limit on the reference itself
    v1 = max(-v_max_m_s, min(v_max_m_s, v1))
    r1 = r_m + 0.5 * h_s * (v_m_s + v1)
    if (target_m + h_s * vt - r1) * s <= 0.0 and abs(v1 - vt) <= dv:
        return target_m + h_s * vt, vt
    return r1, v1


def drive_update(drive: DriveParams, mode: str, command: float, integral_nm: float, speed_meas_rad_s: float,
                 nut_meas_m: float, lead_per_rad_m: float, torque_limit_nm: float, h_s: float,
                 feedforward_rad_s: float = 0.0, feedforward_nm: float = 0.0) -> DriveOut:
    """One loop update.

    effort: the command is the screw torque (N·m). velocity: the command is the screw speed
    (rad/s); τ = kp e + ∫ ki e dt. position: the command is the nut position (m);
    ω_ref = kp_pos (x_ref − x) / (L/2π) + `feedforward_rad_s`, then the speed loop with the torque
    `feedforward_nm` (the reference's acceleration times the inertia) added. The speed reference is clamped
    to ±speed_limit; the torque to ±torque_limit, and the integrator holds while the output
    sits on the limit and the error would push it further (conditional integration). `drive` must be
    tuned (`DriveParams.tuned`: every gain a number; InputError otherwise).
    """
    if mode == "effort":
        tau = max(-torque_limit_nm, min(torque_limit_nm, command))
        return DriveOut(torque_nm=tau, integral_nm=integral_nm, limited=tau != command, speed_reference_rad_s=0.0)
    kp, ki, kx = drive.speed_kp_nm_s_rad, drive.speed_ki_nm_rad, drive.position_kp_1_s
    if kp is None or ki is None or kx is None:
        raise InputError("drive: gains left None (tune them first: DriveParams.tuned(inertia_kgm2))")
    if mode == "position":
        w_ref = kx * (command - nut_meas_m) / lead_per_rad_m + feedforward_rad_s
    else:
        w_ref = command
    lim = drive.speed_limit_rad_s
    w_ref = max(-lim, min(lim, w_ref))
    e = w_ref - speed_meas_rad_s
    integ = integral_nm + ki * e * h_s
    raw = kp * e + integ + feedforward_nm
    tau = max(-torque_limit_nm, min(torque_limit_nm, raw))
    limited = tau != raw
    if limited and raw * e > 0.0:
        # anti-windup: the integrator stops where the output meets the limit (never beyond its new value)
        edge = math.copysign(torque_limit_nm, raw) - kp * e - feedforward_nm
        integ = min(integ, max(edge, integral_nm)) if raw > 0 else max(integ, min(edge, integral_nm))
    return DriveOut(torque_nm=tau, integral_nm=integ, limited=limited, speed_reference_rad_s=w_ref)


def sampled_loop_radius(drive: DriveParams, mode: str, inertia_kgm2: float, h_s: float,
                        speed_from_angles: bool = False) -> float:
    """The spectral radius of the drive's loops closed on a rigid inertia, sampled every `h_s`: below 1
    they settle, at or above it they ring at the loop's own rate (a limit cycle once the torque saturates).

    The linear, unsaturated loop of `drive_update` (command zero, no feed-forward) on J θ̈ = τ with τ held
    over each update (exact for the inertia: θ⁺ = θ + h ω + h² τ/(2J), ω⁺ = ω + h τ/J), the speed read as ω at
    the sample or, `speed_from_angles`, as the last update's angle change over h (a quantised encoder).
    In velocity mode with ki = kp ω_b/4 (`DriveParams.tuned`) and the speed read at the sample, the loop's
    poles solve z² + (a + b − 2) z + (1 − a) = 0 with a = kp h/J, b = ki h²/J; the Jury conditions then
    hold for ω_b h < 4 (√2 − 1) ≈ 1.657: a 30 Hz speed loop needs more than 114 updates a second. The
    position loop's cascade (kp_pos = ω_b/5) leaves that bound where it is; a speed read from angles
    lowers it. Effort mode closes no loop: 0.
    """
    if mode == "effort":
        return 0.0
    kp, ki, kx = drive.speed_kp_nm_s_rad, drive.speed_ki_nm_rad, drive.position_kp_1_s
    if kp is None or ki is None or kx is None:
        raise InputError("drive: gains left None (tune them first: DriveParams.tuned(inertia_kgm2))")
    h, j = h_s, inertia_kgm2
    kx = kx if mode == "position" else 0.0
    # state z = (θ, ω, S, d): S the integrator's memory, d the last update's angle change. The loop reads
    # ω_meas = ω (or d/h) and the position error −θ; e = −kx θ − ω_meas, S⁺ = S + ki h e, τ = kp e + S⁺
    read = (0.0, 0.0, 0.0, 1.0 / h) if speed_from_angles else (0.0, 1.0, 0.0, 0.0)
    e = np.array([-kx, 0.0, 0.0, 0.0]) - np.array(read)
    s_new = np.array([0.0, 0.0, 1.0, 0.0]) + ki * h * e
    tau = kp * e + s_new
    a = np.array([
        [1.0, h, 0.0, 0.0] + 0.5 * h * h / j * tau,
        [0.0, 1.0, 0.0, 0.0] + h / j * tau,
        s_new,
        [0.0, h, 0.0, 0.0] + 0.5 * h * h / j * tau,
    ])
    # a state that does not feed back holds its value, a pole at 1 that is no ring: the angle in velocity mode
    # (and a position loop of no gain), the integrator's memory with no integral gain
    keep = [i for i, fed in enumerate((kx != 0.0, True, ki != 0.0, True)) if fed]
    return float(max(abs(np.linalg.eigvals(a[np.ix_(keep, keep)]))))


def tuned_drive(drive: DriveParams, inertia_kgm2: float, h_loop_s: float, dt_s: float,
                sensors: SensorParams) -> tuple[DriveParams, Callable[[str], float]]:
    """The drive's gains tuned on the inertia it moves (`DriveParams.tuned`), and the spectral radius of its
    loops by mode (`sampled_loop_radius` at the loop period `h_loop_s`, the speed read as `sensors` give it:
    from angles with a quantised encoder). Where the loop of the drive's own mode does not settle (radius ≥ 1)
    `warnings.warn` says so once, `DriveLoopWarning`, with the rate and bandwidth to change."""
    tuned = drive.tuned(inertia_kgm2)
    radius = partial(sampled_loop_radius, tuned, inertia_kgm2=inertia_kgm2, h_s=h_loop_s,
                     speed_from_angles=sensors.encoder_counts_per_rev != 0)
    warn_if_ringing(drive, drive.mode, radius(drive.mode), inertia_kgm2, h_loop_s, dt_s, stacklevel=6)
    return tuned, radius


def warn_if_ringing(drive: DriveParams, mode: str, radius: float, inertia_kgm2: float, h_loop_s: float, dt_s: float,
                    stacklevel: int = 5) -> None:
    """`DriveLoopWarning` where the loop of `mode` does not settle (`sampled_loop_radius` `radius` ≥ 1), with the
    rate and bandwidth to change; nothing otherwise. `stacklevel` points the warning at the user's call."""
    if radius >= 1.0:
        warnings.warn(f"drive: the {mode} loop updated at {1.0 / h_loop_s:g} Hz (drive.loop_rate_hz = "
                      f"{drive.loop_rate_hz!r}, dt_s = {dt_s!r}) with drive.speed_bandwidth_hz = "
                      f"{drive.speed_bandwidth_hz!r} does not settle on the {inertia_kgm2:.4g} kg·m² it drives "
                      f"(sampled-loop pole |z| = {radius:.3f} >= 1): it rings at the loop's rate; raise the loop rate "
                      "or lower the bandwidth", DriveLoopWarning, stacklevel=stacklevel)
