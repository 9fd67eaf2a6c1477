"""`fit`: bounded least squares from several starts, the delay by scan, intervals from the Jacobian.

Steps (docs/fit.md "How the fit works"):

1. Every free parameter is searched in the unit box between its bounds (log-scaled where it spans
   decades) by `scipy.optimize.least_squares` (trust-region reflective, bounds), from the base
   values and from `starts − 1` Latin-hypercube points of the box, each of those first moved by
   `scan_log`; the lowest cost wins, so a local minimum of one start is not taken for the answer.
   The starts are independent tasks handed to `map_fn` (serial by default; `prsm-fit` runs them on
   Ray) and run on each recording's first `SCREEN_S`; the best is polished on the whole recordings.
2. The command-path delay is a whole number of steps: each delay up to `MAX_DELAY_STEPS` is tried at
   the starts' best on the same first seconds; the polish runs at the delay found.
3. Intervals: with J the Jacobian of the residuals scaled by the sensors' resolutions σ_s, the
   covariance is C = (JᵀJ)⁻¹ [Σ_h J_hᵀ r_h r_hᵀ J_h] (JᵀJ)⁻¹ + (JᵀJ)⁻¹: the first term is the sandwich
   clustered by horizon (the errors within a horizon are correlated: a wrong start speed shifts the
   whole horizon), the second the covariance of residuals of exactly one resolution, the floor that
   keeps a noise-free recording from giving intervals of zero width. ci95 = value ± 1.96 √C_ii in
   the search coordinate (log(value) for log-scaled parameters), clipped to the bounds.
4. A parameter is not identifiable when moving it by `REACH` of its bounds changes no sample by one
   sensor resolution (out of the recordings' reach: a chain stiffness of a run that never loads the
   chain), when its 95 % interval is wider than its bounds, when it weighs in a near-null direction
   of J (singular value below `NULL_RATIO` of the largest, columns normalised), or when it
   correlates at ≥ `MAX_CORRELATION` with another. Those are held at the base value, the rest
   fitted again, and the report says which and why; where holding them raises the misfit beyond
   the 95 % band of χ² (`_shadowed`), the rest would carry their error and are held too.
5. The starts are read too (`disagreeing_starts`): a parameter is not identifiable where another start
   ended outside its 95 % interval at a point the data cannot tell from the fit's (its misfit within
   χ²₁'s 95 % band of the fit's: the profile-likelihood interval then reaches that point, so the
   Jacobian's interval is too narrow), or, where the fit's own misfit is above `LACK_OF_FIT_RMS`
   sensor resolutions, at any cost: no start then reproduced the recordings, the best is one local
   minimum among others, and where the search ended depends on where it began.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from collections.abc import Callable

import numpy as np

from prsm_sim.identify.free import DELAY_KEY, MAX_DELAY_STEPS, FreeParameter, base_value, prepared_base
from prsm_sim.identify.problem import FitProblem
from prsm_sim.params import Params

MAX_CORRELATION = 0.95
NULL_RATIO = 1e-3
Z95 = 1.959964
DIFF_STEP = 1e-3  # finite-difference step in the unit box
MAX_NFEV = 60
# A parameter is out of the recordings' reach when moving it by this fraction of its bounds (unit box) changes
# no sample's prediction by one sensor resolution: a real sensor records nothing of a change below its count,
# however many samples there are (the interval alone, which averages over samples, would call it identified).
REACH = 0.1
SCAN_FACTOR = 2.0  # the grid of `scan_log`: a factor of two between points
# the starts run on each recording's first SCREEN_S; the best is polished on the whole recordings (a start's
# least squares costs its evaluations times the data's length, and a few seconds already place the minimum)
SCREEN_S = 2.0
# A fit whose residuals' RMS exceeds this many sensor resolutions does not reproduce its recordings: the
# resolutions are the recordings' own noise and quanta (`problem.resolution`), which a model that describes
# the plant at the right parameters misses by about one (χ² per sample ≈ 1); three is far beyond what
# noise explains at any recording length the fit accepts, and leaves room for a resolution estimated low.
LACK_OF_FIT_RMS = 3.0
CHI2_1_95 = 3.841459  # the 95 % quantile of χ² with one degree of freedom


@dataclass(frozen=True)
class StartResult:
    """One least-squares run: where it began and ended in the unit box, its cost (½ Σ r²), the
    evaluations it took and the seconds of recording it ran on."""

    u0: tuple[float, ...]
    u: tuple[float, ...]
    cost: float
    nfev: int
    data_s: float = 0.0
    residuals: np.ndarray | None = None  # at `u`, with the Jacobian there, where asked for (`keep`)
    jacobian: np.ndarray | None = None

    def to_dict(self, free) -> dict:
        return {"cost": self.cost, "evaluations": self.nfev, "data_s": self.data_s,
                "values": {p.name: p.from_unit(x) for p, x in zip(free, self.u, strict=True)}}


def solve_start(problem: FitProblem, u0, scan: bool = False, keep: bool = False) -> StartResult:
    """One bounded least-squares run from `u0` (a task of its own: `map_fn` runs several), after
    `scan_log` where `scan`; with `keep`, the residuals and their Jacobian at the end point (the
    solver's own forward differences at it, as `jacobian` takes them), which the report reuses."""
    from scipy.optimize import least_squares  # type: ignore[import-untyped]  # here: `import prsm_sim` stays quick
    u = scan_log(problem, u0) if scan else np.asarray(u0, float)
    res = least_squares(problem.residuals, u, bounds=(0.0, 1.0), method="trf",
                        diff_step=DIFF_STEP, x_scale="jac", max_nfev=MAX_NFEV)
    return StartResult(u0=tuple(map(float, u0)), u=tuple(map(float, res.x)), cost=float(res.cost), nfev=int(res.nfev),
                       data_s=sum(r.duration_s for r in problem.recordings),
                       residuals=res.fun if keep else None, jacobian=res.jac if keep else None)


def start_task(problem: FitProblem, job: tuple) -> StartResult:
    """`solve_start(problem, *job)`: one start as a task of `map_fn` (job: the start point, whether to scan)."""
    return solve_start(problem, *job)


def scan_log(problem: FitProblem, u0) -> np.ndarray:
    """`u0` with each log-scaled free parameter in turn moved to the lowest-cost point of a grid over its
    bounds (`SCAN_FACTOR` apart), the others held.

    A chain stiffness far above the chain's own contact and shaft stiffness changes nothing (the
    series chain is as stiff as its softest member): its cost is a plateau there and a narrow well
    around the true value, and least squares started on the plateau sees no slope (it stops at a
    local minimum). The grid's best point lies in the valley the chain's mode frequency draws
    through (mass, stiffness), where least squares has a slope to follow.
    """
    u = np.array(u0, float)
    best = float(np.sum(problem.residuals(u) ** 2))
    widest_first = sorted((i for i, p in enumerate(problem.free) if p.log), key=lambda i: -problem.free[i].span())
    for i in widest_first:
        for x in np.linspace(0.0, 1.0, int(math.ceil(problem.free[i].span() / math.log(SCAN_FACTOR))) + 1):
            v = u.copy()
            v[i] = x
            c = float(np.sum(problem.residuals(v) ** 2))
            if c < best:
                best, u = c, v
    return u


def start_points(problem: FitProblem, starts: int, seed: int = 0) -> list[np.ndarray]:
    """The base point and `starts − 1` Latin-hypercube points of the unit box (every parameter's range
    cut in `starts − 1` strata, each stratum drawn once)."""
    u_base = problem.unit_of(problem.base)
    if starts <= 1 or not problem.free:
        return [u_base]
    from scipy.stats import qmc  # type: ignore[import-untyped]
    extra = qmc.LatinHypercube(d=len(problem.free), seed=seed).random(starts - 1)
    return [u_base] + [0.05 + 0.9 * x for x in extra]


def jacobian(problem: FitProblem, u: np.ndarray, r0: np.ndarray) -> np.ndarray:
    """Forward differences of the residuals at `u` in the unit box (backward at the upper bound)."""
    J = np.empty((r0.size, len(u)))
    for i in range(len(u)):
        h = DIFF_STEP if u[i] + DIFF_STEP <= 1.0 else -DIFF_STEP
        v = u.copy()
        v[i] += h
        J[:, i] = (problem.residuals(v) - r0) / h
    return J


def covariance(J: np.ndarray, r: np.ndarray, clusters: np.ndarray) -> np.ndarray:
    """The covariance of the unit-box point (module docstring, step 3)."""
    H = np.linalg.pinv(J.T @ J)
    meat = np.zeros_like(H)
    order = np.argsort(clusters, kind="stable")
    cs, Jo, ro = clusters[order], J[order], r[order]
    cuts = np.flatnonzero(np.diff(cs)) + 1
    for Jh, rh in zip(np.split(Jo, cuts), np.split(ro, cuts)):
        g = Jh.T @ rh
        meat += np.outer(g, g)
    return H @ meat @ H + H


def correlation_of(C: np.ndarray) -> np.ndarray:
    sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        R = C / np.outer(sd, sd)
    R = np.where(np.isfinite(R), R, 0.0)
    np.fill_diagonal(R, 1.0)
    return np.clip(R, -1.0, 1.0)


def reach_of(J: np.ndarray) -> np.ndarray:
    """Per free parameter, the largest change of any sample (sensor resolutions) that moving it by `REACH`
    of its bounds makes, to first order."""
    return REACH * np.max(np.abs(J), axis=0) if J.size else np.zeros(J.shape[1])


def secant_reach(problem: FitProblem, u: np.ndarray, r0: np.ndarray, i: int) -> float:
    """`reach_of` for parameter `i` by the change itself: `REACH` of its bounds inward from `u` (a parameter
    on a plateau, a stiffness far above the chain's own, has no slope where it is but may have one there)."""
    v = u.copy()
    v[i] += -REACH if u[i] > 0.5 else REACH
    return float(np.max(np.abs(problem.residuals(v) - r0)))


def unidentifiable(J: np.ndarray, C: np.ndarray, names: list[str], secant: dict | None = None) -> dict[str, str]:
    """The free parameters the data cannot tell (module docstring, step 4) → why.

    `J` is the Jacobian of the residuals in sensor resolutions per unit-box coordinate, `C` the
    unit-box covariance (`covariance`), `secant` the `secant_reach` of the parameters `reach_of` finds flat."""
    why: dict[str, str] = {}
    sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
    for i, n in enumerate(names):
        if not np.isfinite(sd[i]) or Z95 * sd[i] > 0.5:
            why[n] = "its 95 % interval is wider than its bounds: the data hardly move it"
    for i, n in enumerate(names):
        lin, far = reach_of(J)[i], (secant or {}).get(n, 0.0)
        if lin < 1.0 and far < 1.0:
            why[n] = (f"moving it by a tenth of its bounds changes no recorded sample by more than {max(lin, far):.2g} "
                      "of a sensor resolution: the recordings do not reach it")
        elif lin < 1.0:
            why[n] = (f"flat where the fit ended, yet a tenth of its bounds further in changes a sample by {far:.3g} "
                      "sensor resolutions: a plateau the least squares stopped on, not the data's answer "
                      "(more --starts)")
    for n, text in _null_directions(J, names).items():
        why.setdefault(n, text)
    R = correlation_of(C)
    for i in range(len(names)):
        for j in range(len(names)):
            if i != j and abs(R[i, j]) >= MAX_CORRELATION:
                why.setdefault(names[i], f"correlated {R[i, j]:+.3f} with {names[j]}")
    return why


def _null_directions(J: np.ndarray, names: list[str]) -> dict[str, str]:
    """The parameters that weigh in a near-null direction of J (columns normalised; a singular value
    below `NULL_RATIO` of the largest) → the direction, as the combination the data do not move."""
    norms = np.linalg.norm(J, axis=0) if J.size else np.zeros(len(names))
    ok = np.flatnonzero(norms > 0)
    out: dict[str, str] = {}
    if ok.size < 2:
        return out
    _, s, vt = np.linalg.svd(J[:, ok] / norms[ok], full_matrices=False)
    for k in np.flatnonzero(s < NULL_RATIO * s[0]):
        direction = " ".join(f"{vt[k, j]:+.2f}·{names[i]}" for j, i in enumerate(ok.tolist()) if abs(vt[k, j]) > 0.05)
        for j, i in enumerate(ok.tolist()):
            if abs(vt[k, j]) > 0.3:
                out.setdefault(names[i], f"it weighs in a near-null direction of the Jacobian ({direction}, "
                                         "unit-box coordinates): the data do not move that combination")
    return out


def disagreeing_starts(problem: FitProblem, u: np.ndarray, r0: np.ndarray, C: np.ndarray, ends) -> dict[str, str]:
    """The free parameters whose fitted value another start contradicts (module docstring, step 5) → why.

    `u`, `r0` and `C` are the fit's end point in the unit box, its residuals (sensor resolutions) and
    its unit-box covariance; `ends` the starts' `StartResult`s. A start's end is tested on `problem` (the
    whole recordings at the fit's delay), not on the seconds it was run on.
    """
    names = [p.name for p in problem.free]
    best = float(r0 @ r0)
    s2 = best / max(1, r0.size - len(names))
    lack = s2 > LACK_OF_FIT_RMS ** 2
    half = Z95 * np.sqrt(np.clip(np.diag(C), 0.0, None))
    why: dict[str, str] = {}
    for end in ends:
        v = np.asarray(end.u, float)
        off = [i for i in range(len(names)) if abs(v[i] - u[i]) > half[i] and names[i] not in why]
        if not off:
            continue
        rise = (float(np.sum(problem.residuals(v) ** 2)) - best) / max(1.0, s2)
        if not lack and rise > CHI2_1_95:
            continue  # the data tell that end from the fit's
        for i in off:
            p = problem.free[i]
            at, other = p.from_unit(float(u[i])), p.from_unit(float(v[i]))
            unit = "" if p.unit == "1" else f" {p.unit}"
            why[names[i]] = (
                f"another start ended at {other:.4g}{unit}, outside the interval about {at:.4g}{unit}, "
                + (f"and no start reproduced the recordings (the best misses them by {math.sqrt(s2):.3g} sensor "
                   "resolutions RMS, noise explains about 1): the answer depends on where the search began "
                   "(more --starts, or another model)" if lack else
                   f"with a misfit the data cannot tell from the fit's (Δχ² {rise:.3g} ≤ {CHI2_1_95:.3g}): "
                   "several answers"))
    return why


@dataclass(frozen=True)
class FitResult:
    """What `fit` found (`to_dict` is fit.json's `parameters`, `correlation`, `residual_rms`)."""

    params: Params
    delay_steps: int
    parameters: dict
    correlation: dict
    residual_rms: dict
    base_residual_rms: dict
    starts: tuple[StartResult, ...]
    polish: StartResult | None  # the best start's run on the whole recordings (None: the starts ran on them)
    problem: FitProblem
    base: Params  # the base as given, before the fit (`problem.base` may have a freed drag switched on)

    def to_dict(self) -> dict:
        return {"parameters": self.parameters, "correlation": self.correlation, "residual_rms": self.residual_rms,
                "base_residual_rms": self.base_residual_rms,
                "starts": [s.to_dict(self.problem.free) for s in self.starts],
                "polish": self.polish.to_dict(self.problem.free) if self.polish else None}


Progress = Callable[[str, int, int], None]


def serial_map(fn, problem: FitProblem, points):
    """Run the starts one after the other in this process (the default `map_fn`)."""
    for u0 in points:
        yield fn(problem, u0)


def _best(problem: FitProblem, points, map_fn, say: Progress) -> tuple[np.ndarray, list[StartResult]]:
    results: list[StartResult] = []
    jobs = [(u0, i > 0) for i, u0 in enumerate(points)]  # the base as given; the other starts scanned first
    for i, res in enumerate(map_fn(start_task, problem, jobs)):
        results.append(res)
        say("starts", i + 1, len(points))
    best = min(results, key=lambda s: s.cost)
    return np.array(best.u), results


def _delay_scan(problem: FitProblem, params: Params, say: Progress) -> tuple[int, list[int]]:
    """The delay of lowest cost at `params`, and the delays within the 95 % band of it (χ²₁ 3.84 on the
    cost in resolutions², scaled by the best delay's residual variance)."""
    costs = []
    for d in range(MAX_DELAY_STEPS + 1):
        costs.append(float(np.sum(problem.residuals_of(params, d) ** 2)))
        say("delay", d + 1, MAX_DELAY_STEPS + 1)
    best = int(np.argmin(costs))
    s2 = max(1.0, costs[best] / max(1, problem.size - len(problem.free) - 1))
    band = [d for d, c in enumerate(costs) if (c - costs[best]) / s2 <= 3.84]
    return best, band


def fit(recordings, base: Params, model: str, free: list[FreeParameter], *, actuator=None, starts: int = 4,
        seed: int = 0, map_fn=serial_map, progress: Progress | None = None, horizon_s: float | None = None,
        kernel: str = "compiled") -> FitResult:
    """Fit `free` (dotted names with bounds, `DELAY_KEY` for the delay) to `recordings` from `base` (module doc).

    `map_fn(start_task, problem, jobs)` runs the starts and yields their `StartResult`s in order
    (default: one after the other in this process).
    """
    say = progress or (lambda stage, done, total: None)
    kw = {"actuator": actuator, "kernel": kernel} | ({"horizon_s": horizon_s} if horizon_s else {})
    given = base
    problem = FitProblem.build(recordings, prepared_base(base, [p.name for p in free]), model, free, **kw)
    screen = problem.head(SCREEN_S)
    shortened = screen is not problem
    u, results = _best(screen, start_points(problem, starts, seed), map_fn, say) if problem.free else (
        np.zeros(0), [])
    fit_delay = any(p.name == DELAY_KEY for p in free)
    band = [0]
    if fit_delay:
        delay, band = _delay_scan(screen, screen.params_at(u), say)
        problem = replace(problem, delay_steps=delay)
    polish = None
    if problem.free and (shortened or problem.delay_steps):
        polish = solve_start(problem, u, keep=True)
        u = np.array(polish.u)
    say("polish", 1, 1)
    return _report(problem, u, results, fit_delay, band, say, given, polish)


def _report(problem: FitProblem, u: np.ndarray, results, fit_delay: bool, band: list[int], say: Progress,
            given: Params, polish: StartResult | None) -> FitResult:
    """Identifiability, the refit of what is identifiable, intervals, the report (module doc, steps 3–4)."""
    names = [p.name for p in problem.free]
    r0, J = _at_end(problem, u, polish)
    C = covariance(J, r0, problem.cluster_ids()) if names else np.zeros((0, 0))
    flat = np.flatnonzero(reach_of(J) < 1.0).tolist() if names else []
    why = unidentifiable(J, C, names, {names[i]: secant_reach(problem, u, r0, int(i)) for i in flat})
    ends = [s for s in results if polish is not None or not np.array_equal(np.asarray(s.u), u)]
    for n, text in disagreeing_starts(problem, u, r0, C, ends).items():
        why.setdefault(n, text)
    say("intervals", 1, 2)
    if why and names:
        params, point = _held(problem, u, r0, why)
    else:
        params = problem.params_at(u)
        point = {n: (u[i], C[i, i]) for i, n in enumerate(names)}
    say("intervals", 2, 2)
    parameters = {}
    for i, p in enumerate(problem.free):
        ui, var = point.get(p.name, (u[i], C[i, i]))
        parameters[p.name] = _entry(p, ui, var, problem.base, why.get(p.name), _get(params, p.name))
    if fit_delay:
        d = problem.delay_steps
        parameters[DELAY_KEY] = {"value": d, "ci95": [min(band), max(band)], "unit": "steps",
                                 "identifiable": max(band) - min(band) < MAX_DELAY_STEPS, "base": 0}
    R = correlation_of(C)
    correlation = {a: {b: float(R[i, j]) for j, b in enumerate(names)} for i, a in enumerate(names)}
    return FitResult(params=params, delay_steps=problem.delay_steps, parameters=parameters, correlation=correlation,
                     residual_rms=problem.signal_rms(params), base_residual_rms=problem.signal_rms(given, None, 0),
                     starts=tuple(results), polish=polish, problem=problem, base=given)


def _held(problem: FitProblem, u: np.ndarray, r0: np.ndarray, why: dict[str, str]) -> tuple[Params, dict]:
    """The parameters in `why` held at the base and the rest fitted again from `u` (module doc, step 4):
    the parameters, and per refitted name its unit-box value and variance. Adds to `why` the rest that
    would carry the held ones' error (`_shadowed`); then every value is the base's."""
    names = [p.name for p in problem.free]
    keep = [i for i, n in enumerate(names) if n not in why]
    fixed = problem.params_at(u).with_overrides({n: base_value(problem.base, n) for n in why})
    sub = replace(problem, base=fixed, free=tuple(problem.free[i] for i in keep))
    u_sub = np.array(solve_start(sub, u[keep]).u) if keep else np.zeros(0)
    r_sub = sub.residuals(u_sub)
    why |= _shadowed(r0, r_sub, [names[i] for i in keep], list(why))
    if len(why) == len(names):
        return problem.params_at(u).with_overrides({n: base_value(problem.base, n) for n in why}), {}
    C_sub = covariance(jacobian(sub, u_sub, r_sub), r_sub, sub.cluster_ids())
    return sub.params_at(u_sub), {problem.free[i].name: (u_sub[j], C_sub[j, j]) for j, i in enumerate(keep)}


def _shadowed(r_full: np.ndarray, r_held: np.ndarray, rest: list[str], held: list[str]) -> dict[str, str]:
    """The rest → why, where holding `held` at the base raises the misfit beyond the 95 % band of χ² with
    one degree of freedom per held parameter (the cost in resolutions², scaled by the full fit's residual
    variance): the data then contradict the base's values, and whatever the rest were fitted to carries
    that error into them."""
    from scipy.stats import chi2  # type: ignore[import-untyped]
    full = float(np.sum(r_full ** 2))
    s2 = max(1.0, full / max(1, r_full.size - len(rest) - len(held)))
    rise = (float(np.sum(r_held ** 2)) - full) / s2
    bound = float(chi2.ppf(0.95, len(held)))
    if rise <= bound or not rest:
        return {}
    text = (f"fitted only with {', '.join(held)} held at the base, which raises the misfit by {rise:.3g} "
            f"(95 % bound {bound:.3g}): its value would carry their error")
    return {n: text for n in rest}


def _at_end(problem: FitProblem, u: np.ndarray, polish: StartResult | None) -> tuple[np.ndarray, np.ndarray]:
    """The residuals at `u` and their Jacobian: the polish's own where it ended there, else computed."""
    if polish is not None and polish.residuals is not None and polish.jacobian is not None and problem.free:
        return polish.residuals, polish.jacobian
    r0 = problem.residuals(u)
    return r0, jacobian(problem, u, r0) if problem.free else np.zeros((r0.size, 0))


def _entry(p: FreeParameter, u: float, var: float, base: Params, why: str | None, value: float) -> dict:
    """One parameter's report: value, ci95 (search coordinate ± 1.96 σ, clipped to the bounds), unit, identifiable."""
    sd = math.sqrt(max(var, 0.0)) * p.span()
    clipped = min(max(value, p.lower), p.upper)  # a base outside the bounds (an infinite stiffness: rigid)
    centre = math.log(clipped) if p.log else clipped
    lo_b, hi_b = (math.log(p.lower), math.log(p.upper)) if p.log else (p.lower, p.upper)
    lo, hi = max(lo_b, centre - Z95 * sd), min(hi_b, centre + Z95 * sd)
    if p.log:
        lo, hi = math.exp(lo), math.exp(hi)
    out = {"value": value, "ci95": [lo, hi], "unit": p.unit, "identifiable": why is None,
           "base": base_value(base, p.name)}
    if why is not None:
        out["why_not"] = why
    return out


def _get(params: Params, name: str) -> float:
    return base_value(params, name)
