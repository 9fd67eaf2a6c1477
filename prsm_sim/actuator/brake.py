"""Holding brake on the screw shaft: engage/release ramps and a set-valued friction torque."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar

from prsm_sim.actuator.params import BrakeParams

R = TypeVar("R", bound=tuple[Any, ...])  # a step's result, its end state first

# The work a dry friction torque held over a step may do on the shaft before the step is taken again in halves
# (`works_on_shaft`): above what a held brake's rounding leaves (|τ| ≤ 1e3 N·m over ≤ 1e-12 rad of drift), so a
# held brake is never halved; a 14 J reversal falls to a few nJ in the 16 halvings a step may take (4× per halving).
DRY_WORK_TOL_J = 1e-9
# Trials of the bracketed search (`held_torque`) past its two ends (the linear response's torque, the capacity):
# regula falsi lands in one where the screw's response is linear in the torque; where it is not (`fu2018`'s
# regimes, `elastic`'s chain), of 2,067 solves in the ten brake cases of the envelope's regression set 66 took 11
# or 12 and 13 ran out (each then keeps its nearest trial that does not push along: `held_torque`)
DRY_CORRECTIONS = 12


def brake_level(brake: BrakeParams, level: float, engaged: bool, dt_s: float) -> float:
    """Brake level in [0, 1] after `dt_s`: ramps linearly to 1 over engage_time_s, to 0 over release_time_s."""
    if engaged:
        return 1.0 if brake.engage_time_s == 0.0 else min(1.0, level + dt_s / brake.engage_time_s)
    return 0.0 if brake.release_time_s == 0.0 else max(0.0, level - dt_s / brake.release_time_s)


def stiction_torque(capacity_nm: float, w_free_rad_s: float, inertia_kgm2: float, h_s: float) -> float:
    """The torque (|τ| ≤ capacity) that stops the screw within the step, or the capacity against its motion.

    A dry friction (brake pads, a jam) is set-valued: it holds when the torque needed to stop
    the shaft, −J ω_free / h, is within the capacity, else slips at the capacity. Solved on the
    screw's linear response; `held_torque` corrects it on the model's end speed where that lands on the
    torque's side (`pushes_along`).
    """
    if capacity_nm <= 0.0:
        return 0.0
    need = -inertia_kgm2 * w_free_rad_s / h_s
    return max(-capacity_nm, min(capacity_nm, need))


def held_torque(capacity_nm: float, w_free_rad_s: float, slope_rad_s_nm: float, h_s: float,
                trial: Callable[[float], R]) -> R:
    """The step `trial(τ)` (its result's first item the end state) with the dry friction torque τ solved on the
    screw's linear response ω₁ = ω_free + s τ (`stiction_torque`, J = h/s), then corrected where the step's end
    speed lands on the torque's side (`pushes_along`): the linear response mispredicted it (the load across
    `elastic`'s chain, `fu2018`'s regimes).

    The correction solves ω₁(τ) = 0 on the model's own end speed, bracketed: one end the torque that pushed
    along, the other the capacity against that motion (if the shaft still runs on under the full capacity, it
    slips there: the law). Between them, regula falsi with the Illinois halving of the kept end's weight (Dowell
    & Jarratt 1971), which keeps the root bracketed where a Newton step on the linear slope crawls (`fu2018`'s
    stiction kinks the response near rest: envelope seed 1059's end speed went 31 → 1.8 → 0.27 rad/s in
    three), to a torque that holds the shaft (|τ ω₁| h within DRY_WORK_TOL_J), within DRY_CORRECTIONS trials.
    """
    inertia = h_s / slope_rad_s_nm
    t_a = stiction_torque(capacity_nm, w_free_rad_s, inertia, h_s)
    res_a = trial(t_a)
    w_a = res_a[0].screw_speed_rad_s
    if not pushes_along(t_a, w_a, h_s):
        return res_a
    t_b = -math.copysign(capacity_nm, w_a)
    res_b = trial(t_b)
    w_b = res_b[0].screw_speed_rad_s
    if w_b * w_a >= 0.0:
        return res_b  # slips at the capacity, against the motion
    # the capacity turns the shaft round within the step: the root lies between. The search ends where the
    # torque holds the shaft (|τ ω₁| h within DRY_WORK_TOL_J); exhausted, it gives the trial nearest that of
    # those not pushing along (the brake reversing a creep: it only takes energy out), else the nearest
    fa, fb = w_a, w_b  # Illinois: the ends' weights, halved when the same end is kept twice
    side = 0
    best, best_key = res_b, (True, abs(t_b * w_b))
    for _ in range(DRY_CORRECTIONS):
        t = (t_a * fb - t_b * fa) / (fb - fa)
        res = trial(t)
        w1 = res[0].screw_speed_rad_s
        if abs(t * w1) * h_s <= DRY_WORK_TOL_J:
            return res
        key = (pushes_along(t, w1, h_s), abs(t * w1))
        if key < best_key:
            best, best_key = res, key
        if w1 * w_b < 0.0:  # on a's side: the root lies between t and t_b
            t_a, w_a, fa = t, w1, w1
            if side == -1:
                fb *= 0.5
            side = -1
        else:
            t_b, w_b, fb = t, w1, w1
            if side == 1:
                fa *= 0.5
            side = 1
    return best


def pushes_along(torque_nm: float, end_speed_rad_s: float, h_s: float) -> bool:
    """Whether a dry friction torque held over a step pushes the shaft the way it turns at the step's end, by
    more than DRY_WORK_TOL_J of power over the step: against the law (the friction opposes the motion, or holds
    it at rest). The torque was solved on a linear response of the screw (`stiction_torque`); where the model's
    step departs from it (a load acting across `elastic`'s chain, `fu2018`'s friction regimes), the end
    speed can come out on the torque's side, and the brake then drives the screw (a 9.8 N·m brake gave out 4 J
    a 4 ms step under 183 kN pressing the nut into a stop). The caller then corrects the torque on the speed
    the model gave."""
    return torque_nm * end_speed_rad_s * h_s > DRY_WORK_TOL_J


def works_on_shaft(torque_nm: float, angle_change_rad: float) -> bool:
    """Whether a dry friction torque held over a step did work on the shaft, τ Δθ > DRY_WORK_TOL_J.

    Dry friction only takes energy out, −τ Δθ ≥ 0 over any motion. A torque held over a step is set by the
    end speed (`stiction_torque`, corrected on the model's end speed where the linear response missed it:
    `pushes_along`); when the shaft reverses or stops inside the step, the motion before ran along that
    torque, and over a whole step it can outweigh the rest (a brake engaging on a screw that turns back from
    −421 to +14 rad/s in a 26 ms step gave 14 J). The caller takes such a step as two halves, the half
    holding the reversal likewise, which locates it: the work of the piece that holds it falls as the
    piece's length squared. A shaft the solve held (|τ ω₁| h within the tolerance) leaves τ Δθ within it too,
    bar the motion before it came to rest; one a search that ran out left creeping along the torque trips it
    on every piece, which the caller's budget of one piece per level bounds.
    """
    return torque_nm * angle_change_rad > DRY_WORK_TOL_J
