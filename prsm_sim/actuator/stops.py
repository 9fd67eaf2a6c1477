"""Stiff, damped end stops on the nut and the thread ends, solved implicitly on the plant's own response.

A penalty contact on the nut's own axial position x_N (not the screw's thread position (L/2π) θ_S:
with a compliant chain they differ by its deflection): penetration δ = x_N − x_max (or x_min − x_N),
force F = k δ₁ + c (δ₁ − δ₀⁺)/h on the penetration at the step's end and its mean rate over the
step (backward Euler on the contact), held over the step, never pulling. The force is solved to consistency with the step
itself: F − law(δ₁(F)) = 0 with the nut's end position from the plant's own step
under the load less F. That residual is strictly increasing in F (the harder the stop pushes, the
less the nut goes in), so its root is unique; it covers a screw that sticks (δ₁ no longer moves
with F: at rest the force is then exactly k δ, the static law) as well as one that slides. The
damper acts on the mean rate: on the end speed instead, a nut that rattles on a compliant chain
(speeds alternating from step to step) would draw energy from it.

Where the plant's step jumps with the force the residual jumps across zero and has no root: a screw
held by its static friction up to a force F_b slips at once just past it (fu2018's regularised running
friction is far below μN at small slip), so the nut moves a finite distance for F = F_b + 0. The solve
then takes the side of the jump on which the stop absorbs more work. A hold the stop presses harder than
the friction can take (k δ > F_b) gives way: the nut slides out until it is held where the force is k δ
(the stuck side would leave it resting deeper than the force it reports); a drive pressing the nut past
k δ plus the friction slides it in likewise. Sliding is refused only where the stop would give out
energy doing so (k δ past the band's edge by less than half the spring force of the one-step slip), so
at rest the force is off k δ by at most that half (of the refined step's slip: below). Where both sides give
out energy (an `elastic` nut at rest within its clearance, 1.6 µm into a thread end under 195 N: its screw
slid 36 µm in or out of the end within a 5.6 ms step for forces 1 mN apart, and both sides gave out
4.8–17 mJ), the actuator takes the step again in halves (`gives_out`): the slide on either side shrinks with
the step, so the piece holding the jump gives out less, within the halvings' budget.

The force is held over the step, but the nut may come to rest within it: the step then ends at rest while
its force still carries the motion that ended inside (the damper's c Δδ/h of a nut that stopped early; on a
jump, the stuck side's offset). At a 71 ms step, a nut pressed by 210 kN into a 1e7 N/m, 2e5 N·s/m stop
stopped early in the step 392 µm out from where it started: 1.1 kN of damping, and it rested 110 µm off the
static deflection of the force it reported. So a step that ends with the nut at rest off the law at its end,
k δ₁ + c δ̇₁, by more than k · REST_TOL_M (`off_rest`) has its last sub-step taken again by the actuator
(`Actuator._sub_step`; a bare simulator's thread-end step is not) as two halves of the same model at h/2, the
second judged likewise (down to h/2**MAX_REST_HALVINGS): the piece in which the nut
stops carries the motion, the piece after it starts and ends at rest, δ₁ = δ₀, and its force is k δ. Each
piece is a step of its own, solved and booked as any (each absorbs ½ k Δδ² + c Δδ²/h ≥ 0), so the books
close and the stop never gives out energy. (Projecting the rest onto the law instead would move the nut
with no force doing it, or report a force the step did not hold.) A step that ends moving is not refined:
its force is the contact's backward Euler, and the refinement costs a solve per halving.

Energy: the work the nut does on the stop over a step is F Δx_N; the stop stores ½ k δ²; the rest,
F Δx_N − Δ(½ k δ²) = ½ k Δδ² + c Δδ²/h (in contact over the whole step) is ≥ 0 in every case
(entering, leaving, clipped at zero; on a jump, on the side taken whenever either side's is), so the
stop only absorbs energy (a 1e8 N/m stop on a ~100 kg reflected mass rings at ~1000 rad/s, beyond an
explicit step).

The thread ends (`Geometry.thread_ends`) are the same contact at ±(screw_length_m − nut_length_m)/2, up
to half the nut's length; past it they are hard (`end_depth_m`, `_solve_hard`). The callers tell the
model its steps are the solve's trials (`Model.in_contact`), so a model that would reflect the screw's
speed off an unresolved contact reverses by an L-stable step there.
"""

from __future__ import annotations

import math
from typing import NamedTuple, TypeVar
from collections.abc import Callable

from prsm_sim.actuator.params import StopParams

MAX_ITERATIONS = 60
REL_TOL = 1e-10  # of the contact force (plus 1 mN)
BRACKET_TOL = 1e-6  # a bracket this narrow (of the force) ends the search
POSITION_TOL_M = 1e-12  # or k times this: a model's end position is not smoother in the force than its own rounding
# the energy a stop may give out over a step before the step is taken again in halves (`gives_out`): its
# force's rounding over the nut's (1e5 N over 1e-14 m)
GIVE_TOL_J = 1e-9
# a step that ends with the nut at rest (the damper at its end speed within k times this) ends on the stop's law
# there, k δ₁ + c δ̇₁, to k times this (`off_rest`): a fourth of the 2 µm the operating envelope allows
REST_TOL_M = 5e-7
MAX_REST_HALVINGS = 16  # ... refined down to h/2**16 at most (a step's last piece; each halving one more solve)


class ThreadEndEvent(NamedTuple):
    """The nut reached (pressed onto) or left a thread end, at the end of the step ending at `time_s`."""

    time_s: float
    what: str  # "reached" or "left"
    force_n: float  # the end's force on the nut then (N, along +x_nut; 0 when it left)

    @property
    def event_name(self) -> str:
        return f"thread_end_{self.what}"

    def describe(self) -> str:
        if self.what == "reached":
            return f"the nut reached a thread end (end force {self.force_n:.1f} N): the last of the threaded length"
        return "the nut left the thread end"


class Limit(NamedTuple):
    position_m: float
    sign: float  # +1: an upper limit (the nut pushes into it moving +x), −1: a lower one
    stiffness_n_m: float
    damping_n_s_m: float
    thread_end: bool
    hard_depth_m: float = math.inf  # past this penetration the limit is hard (`solve`): a thread end's last give


def limits_of(stops: StopParams | None, travel_m: float | None,
              nut_length_m: float | None = None) -> tuple[Limit, ...]:
    """The innermost limit on each side: the user's stops and the thread ends at ±travel_m/2 (None: none).

    The thread ends use the stops' contact law (their stiffness and damping; the defaults without stops)
    up to half the nut's length (`nut_length_m`); past it they are hard (`end_depth_m`). A user's stop inside
    the travel is hard where the end behind it would be (a soft stop pressed through reaches the end, which
    the innermost limit alone would not see)."""
    s = stops if stops is not None else StopParams()
    k, c = s.stiffness_n_m, s.damping_n_s_m
    hard = end_depth_m(nut_length_m)
    out = []
    for sign, user in ((1.0, s.max_position_m), (-1.0, s.min_position_m)):
        end = None if travel_m is None else sign * 0.5 * travel_m
        if user is not None and (end is None or sign * user <= sign * end):
            out.append(Limit(user, sign, k, c, False, math.inf if end is None else sign * (end - user) + hard))
        elif end is not None:
            out.append(Limit(end, sign, k, c, True, hard))
    return tuple(out)


def end_depth_m(nut_length_m: float | None) -> float:
    """How far a thread end gives before it is hard (m): half the nut's length (inf when unknown).

    A thread end is the shoulder the threaded length ends at, its penalty law the shoulder's compliance.
    A nut driven into it past half its own length would have half its teeth off the threads: a load near
    the rating back-driving the nut at ~10 m/s stores kilojoules, which the 1e8 N/m law alone took over
    more than that, carrying the nut off its threads. There the end is hard. Its force past the static
    rating C₀a (from a depth C₀a/k on: 2.8 mm on s30) is part of the load on the nut and shows as
    `over_static_rating`: an impact the screw would not survive undamaged, said where it happens.
    (Hard from C₀a/k on instead, the end's impulse within a step reversed a 3000 rad/s screw under
    5.7 MN, 20 times the rating, beyond what the friction step resolves.)"""
    return math.inf if nut_length_m is None else 0.5 * nut_length_m


def penetration(limit: Limit, x_m: float) -> float:
    """Penetration beyond `limit` (m, > 0 inside; negative outside)."""
    return limit.sign * (x_m - limit.position_m)


def engaged(limits: tuple[Limit, ...], x1_m: float) -> Limit | None:
    """The limit a step ending at x1 (its end position without a stop force) presses into, if any."""
    for lim in limits:
        if penetration(lim, x1_m) > 0.0:
            return lim
    return None


R = TypeVar("R")  # what a step gives (a model's or the simulator's result), as `solve` passes it through


def solve(limit: Limit, h_s: float, x0_m: float, free: R, advance: Callable[[float], R],
          nut_position: Callable[[R], float], compliance_m_n: float, v0_m_s: float = math.inf) -> tuple[float, R]:
    """The stop force held over the step (N, signed along +x_nut) and the step's result under it.

    `free`: the step's result without a stop force; `advance(F)`: the step with the stop force F
    (signed along +x_nut) added to what pushes the nut; `x0_m`, `v0_m_s`: the nut's position and
    velocity at the step's start (the velocity: inf when unknown); `nut_position(result)`: its end
    position; `compliance_m_n`: an estimate of −∂x₁/∂F (the first guess; exact for linear models). A
    nut that starts at rest pressed into the stop (at its start speed it would move less than REST_TOL_M
    over the step), at a step that resolves the contact's period (k · compliance = (ω h)²/2 ≤ 1), is first
    tried with the law's force there, k δ₀, which held it over the step before: a nut held against an end
    meets the law at the first trial or within a few, where the compliance's estimate took three
    (`fu2018`, whose stick band it does not see) to nine (`elastic`, whose chain the screw's inertia does
    not describe) whole model steps. Either way the force found meets the law to the solve's tolerance.
    A limit with a finite `hard_depth_m` that the law's force would let the nut pass is hard there
    (`_solve_hard`).
    """
    f, res = _solve_law(limit, h_s, x0_m, v0_m_s, free, advance, nut_position, compliance_m_n)
    if penetration(limit, nut_position(res)) > limit.hard_depth_m:
        return _solve_hard(limit, abs(f), res, advance, nut_position, compliance_m_n)
    return f, res


def _solve_hard(limit: Limit, f_lo: float, res_lo: R, advance: Callable[[float], R],
                nut_position: Callable[[R], float], compliance_m_n: float) -> tuple[float, R]:
    """The force (≥ the law's, `f_lo`, which lets the nut past `hard_depth_m`) that ends the step at that
    depth: from the compliance's estimate, bracketed by doubling, then secant steps kept inside the bracket
    (bisection where they creep), taking the side that ends at or short of it. The penetration falls strictly with the force, so the
    root is unique. Energy: moving in, F ≥ k δ₁ at the end, so the stop absorbs F Δδ − Δ(½ k δ²) ≥ 0
    (the work of crushing the shoulder; the step's ledger holds it as the stop's)."""
    sgn, target = limit.sign, limit.hard_depth_m
    lo, hi = f_lo, math.inf
    g_lo, g_hi = penetration(limit, nut_position(res_lo)) - target, -math.inf
    res_hi = res_lo
    f = f_lo + 1.1 * g_lo / compliance_m_n if compliance_m_n > 0.0 else 2.0 * f_lo + limit.stiffness_n_m * target
    for _ in range(MAX_ITERATIONS):
        res = advance(-sgn * f)
        g = penetration(limit, nut_position(res)) - target
        if g > 0.0:
            lo, g_lo = f, g
        else:
            hi, g_hi, res_hi = f, g, res
            if -g <= POSITION_TOL_M or hi - lo <= BRACKET_TOL * hi:
                break
        if not math.isfinite(hi):
            f = 2.0 * f + 1.0
            continue
        nxt = lo + (hi - lo) * g_lo / (g_lo - g_hi)
        f = nxt if lo < nxt < hi and (nxt - lo) > 0.01 * (hi - lo) and (hi - nxt) > 0.01 * (hi - lo) \
            else 0.5 * (lo + hi)
    return -sgn * hi, res_hi


def _solve_law(limit: Limit, h_s: float, x0_m: float, v0_m_s: float, free: R, advance: Callable[[float], R],
               nut_position: Callable[[R], float], compliance_m_n: float) -> tuple[float, R]:
    """`solve` by the contact law alone (module doc)."""
    k, c = limit.stiffness_n_m, limit.damping_n_s_m
    sgn = limit.sign
    d0 = max(0.0, penetration(limit, x0_m))

    def law(res) -> float:  # magnitude of the contact force the step's end asks for (pushing out)
        d1 = penetration(limit, nut_position(res))
        return max(0.0, k * d1 + c * (d1 - d0) / h_s)

    t0 = law(free)
    if t0 <= 0.0:
        return 0.0, free
    lo, hi = 0.0, math.inf
    res_lo = res_hi = free
    # at rest against it, at a step that resolves the contact's period ((ω h)²/2 = k · compliance ≤ 1): the force
    # that held it there. A longer step rings about the static balance within the solve's tolerance from there.
    if d0 > 0.0 and abs(v0_m_s) * h_s <= REST_TOL_M and k * compliance_m_n <= 1.0:
        f = k * d0
    else:
        f = t0 / (1.0 + (k + c / h_s) * max(compliance_m_n, 0.0))
    best = (math.inf, 0.0, free)
    prev = (0.0, -t0)
    last_width = math.inf
    for _ in range(MAX_ITERATIONS):
        res = advance(-sgn * f)
        r = f - law(res)
        if abs(r) < best[0]:
            best = (abs(r), f, res)
        if abs(r) <= REL_TOL * (f + 1e-3) + k * POSITION_TOL_M:
            return -sgn * f, res
        if r < 0.0:
            lo, res_lo = f, res
        else:
            hi, res_hi = f, res
        # secant through the last two points, kept inside the bracket (else bisection / doubling), and
        # bisection whenever the bracket did not halve (a root on a jump: the secant creeps up one side)
        # (the residual's slope is at least 1: f − r always lands on the root's far side)
        nxt = f - r * (f - prev[0]) / (r - prev[1]) if r != prev[1] else f - r
        prev = (f, r)
        width = hi - lo
        if not (lo < nxt < hi) or (math.isfinite(width) and width > 0.5 * last_width):
            nxt = 0.5 * (lo + hi) if math.isfinite(hi) else 2.0 * lo + t0
        if math.isfinite(width) and width <= BRACKET_TOL * (hi + 1e-3):
            # bracketed to a ppm: the root sits on a jump (stick/slip) and neither side meets the law. The
            # side on which the stop absorbs more (module doc): an over-pressed hold slides, and the stop
            # never gives out energy where either side spares it (equal: the nearer side)
            x0 = penetration(limit, x0_m)
            a_lo = absorbed_j(limit, lo, x0, penetration(limit, nut_position(res_lo)))
            a_hi = absorbed_j(limit, hi, x0, penetration(limit, nut_position(res_hi)))
            if a_lo != a_hi:
                return (-sgn * lo, res_lo) if a_lo > a_hi else (-sgn * hi, res_hi)
            break
        last_width = width
        f = nxt
    return -sgn * best[1], best[2]


def off_rest(limit: Limit, force_n: float, x1_m: float, v1_m_s: float) -> bool:
    """Whether a step that held the stop force `force_n` (N, signed along +x_nut) ends with the nut at rest
    against `limit` (the damper at its end speed `v1_m_s` within k · REST_TOL_M) off the law at its end, k δ₁ +
    c δ̇₁ (`x1_m`: its end position), by more than k · REST_TOL_M. The force held over a step carries what moved
    within it (the damper's c Δδ/h, a stick/slip jump's side), the law at its end does not: the caller then
    takes the step as two halves (module doc)."""
    k, c = limit.stiffness_n_m, limit.damping_n_s_m
    tol = k * REST_TOL_M
    if force_n == 0.0 or c * abs(v1_m_s) > tol:
        return False
    d1 = penetration(limit, x1_m)
    law = max(0.0, k * d1 + c * limit.sign * v1_m_s) if d1 > 0.0 else 0.0
    return abs(abs(force_n) - law) > tol


def gives_out(limit: Limit, force_n: float, x0_m: float, x1_m: float) -> bool:
    """Whether a stop holding `force_n` (N, signed along +x_nut) over a step in which the nut went from x0 to x1
    gave out energy, `absorbed_j` < −GIVE_TOL_J: the law's solve found the step's response jumping across the
    law (a stick/slip flipping the screw's slide within the step) with both sides giving out (the module doc).
    The caller then takes the step as two halves: a shorter step moves the nut less on either side of the
    jump, so the piece holding it gives out less (judged likewise, within the caller's budget of halvings)."""
    if force_n == 0.0:
        return False
    d0, d1 = penetration(limit, x0_m), penetration(limit, x1_m)
    return absorbed_j(limit, abs(force_n), d0, d1) < -GIVE_TOL_J


def absorbed_j(limit: Limit, force_n: float, d0_m: float, d1_m: float) -> float:
    """The work a stop pushing out with `force_n` (≥ 0) takes from the nut while its penetration goes from
    d0 to d1 (m, negative outside), less the rise of its stored ½ k δ² (J): ≥ 0 for a stop that only absorbs."""
    k = limit.stiffness_n_m
    e0, e1 = max(d0_m, 0.0), max(d1_m, 0.0)
    return force_n * (d1_m - d0_m) - 0.5 * k * (e1 * e1 - e0 * e0)


def stop_stored_j(limits: tuple[Limit, ...], x_m: float) -> float:
    """Elastic energy in the stop the nut is in, ½ k δ² (J)."""
    e = 0.0
    for lim in limits:
        d = penetration(lim, x_m)
        if d > 0.0:
            e += 0.5 * lim.stiffness_n_m * d * d
    return e


def stop_penetration(limits: tuple[Limit, ...], x_m: float) -> tuple[float, bool]:
    """(penetration beyond the limit the nut is in, m ≥ 0; whether that limit is a thread end)."""
    for lim in limits:
        d = penetration(lim, x_m)
        if d > 0.0:
            return d, lim.thread_end
    return 0.0, False
