"""Holding brake on the screw shaft: engage/release ramps and a set-valued friction torque."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from prsm_sim.actuator.params import BrakeParams

R = TypeVar("R", bound=tuple[Any, ...])  # a step's result, its end state first

# The work a dry friction torque held over a step may do on the shaft before the step is taken again in halves
# (`works_on_shaft`): above what a held brake's rounding leaves (|τ| ≤ 1e3 N·m over ≤ 1e-12 rad of drift), so a
# held brake is never halved; a 14 J reversal falls to a few nJ in the 16 halvings a step may take (4× per halving).
DRY_WORK_TOL_J = 1e-9
# Newton steps on the model's end speed when the linear response put the held torque on the wrong side of it
# (`pushes_along`): one lands on the law where the screw's own slope holds (the linear models: never needed)
DRY_CORRECTIONS = 3


def brake_level(brake: BrakeParams, level: float, engaged: bool, dt_s: float) -> float:
    """Brake level in [0, 1] after `dt_s`: ramps linearly to 1 over engage_time_s, to 0 over release_time_s."""
    if engaged:
        return 1.0 if brake.engage_time_s == 0.0 else min(1.0, level + dt_s / brake.engage_time_s)
    return 0.0 if brake.release_time_s == 0.0 else max(0.0, level - dt_s / brake.release_time_s)


def stiction_torque(capacity_nm: float, w_free_rad_s: float, inertia_kgm2: float, h_s: float) -> float:
    """The torque (|τ| ≤ capacity) that stops the screw within the step, or the capacity against its motion.

    A dry friction (brake pads, a jam) is set-valued: it holds when the torque needed to stop
    the shaft, −J ω_free / h, is within the capacity, else slips at the capacity. Solved on the
    screw's linear response; `Actuator` corrects it on the model's end speed where that lands on the
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
    `elastic`'s chain, `fu2018`'s regimes), and a Newton step on the speed the model gave, on the screw's own
    slope s, puts the torque back on the law (up to DRY_CORRECTIONS)."""
    inertia = h_s / slope_rad_s_nm
    t_st = stiction_torque(capacity_nm, w_free_rad_s, inertia, h_s)
    res = trial(t_st)
    for _ in range(DRY_CORRECTIONS):
        w1 = res[0].screw_speed_rad_s
        if not pushes_along(t_st, w1, h_s):
            break
        t_st = stiction_torque(capacity_nm, w1 - slope_rad_s_nm * t_st, inertia, h_s)
        res = trial(t_st)
    return res


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
    piece's length squared. A held shaft whose end speed the correction put back on the law leaves τ Δθ within
    the tolerance; one the correction left creeping along the torque (its DRY_CORRECTIONS Newton steps converge
    only linearly where `fu2018`'s own stiction kinks the response near rest) trips it on every piece, which the
    caller's budget of one piece per level bounds.
    """
    return torque_nm * angle_change_rad > DRY_WORK_TOL_J
