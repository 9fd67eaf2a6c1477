"""`fit`: bounded least squares from several starts, the delay by scan, intervals from the Jacobian.

Steps (docs/fit.md "How the fit works"):

1. Every free parameter is searched in the unit box between its bounds (log-scaled where it spans
   decades) by `scipy.optimize.least_squares` (trust-region reflective, bounds), from the base
   values and from `starts − 1` Latin-hypercube points of the box; the lowest cost wins, so a local
   minimum of one start is not taken for the answer. The starts are independent tasks handed to
   `map_fn` (serial by default; `prsm-fit` runs them on Ray).
2. The command-path delay is a whole number of steps: each delay up to `MAX_DELAY_STEPS` is tried at
   the fitted parameters; another delay than zero is refitted.
3. Intervals: with J the Jacobian of the residuals scaled by the sensors' resolutions σ_s, the
   covariance is C = (JᵀJ)⁻¹ [Σ_h J_hᵀ r_h r_hᵀ J_h] (JᵀJ)⁻¹ + (JᵀJ)⁻¹: the first term is the sandwich
   clustered by horizon (the errors within a horizon are correlated: a wrong start speed shifts the
   whole horizon), the second the covariance of residuals of exactly one resolution, the floor that
   keeps a noise-free recording from giving intervals of zero width. ci95 = value ± 1.96 √C_ii in
   the search coordinate (log(value) for log-scaled parameters), clipped to the bounds.
4. A parameter is not identifiable when its 95 % interval spans more than half its bound box, when
   it weighs in a near-null direction of J (singular value below `NULL_RATIO` of the largest, columns
   normalised), or when it correlates at ≥ `MAX_CORRELATION` with another. Those are held at the
   base value, the rest fitted again, and the report says which and why.
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


@dataclass(frozen=True)
class StartResult:
    """One start's outcome: where it began and ended in the unit box, its cost (½ Σ r²)."""

    u0: tuple[float, ...]
    u: tuple[float, ...]
    cost: float
    nfev: int


def solve_start(problem: FitProblem, u0) -> StartResult:
    """One bounded least-squares run from `u0` (a task of its own: `map_fn` runs several)."""
    from scipy.optimize import least_squares  # type: ignore[import-untyped]  # here: `import prsm_sim` stays quick
    res = least_squares(problem.residuals, np.asarray(u0, float), bounds=(0.0, 1.0), method="trf",
                        diff_step=DIFF_STEP, x_scale="jac", max_nfev=MAX_NFEV)
    return StartResult(u0=tuple(map(float, u0)), u=tuple(map(float, res.x)), cost=float(res.cost), nfev=int(res.nfev))


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


def unidentifiable(J: np.ndarray, C: np.ndarray, names: list[str]) -> dict[str, str]:
    """The free parameters the data cannot tell (module docstring, step 4) → why."""
    why: dict[str, str] = {}
    sd = np.sqrt(np.clip(np.diag(C), 0.0, None))
    for i, n in enumerate(names):
        if not np.isfinite(sd[i]) or Z95 * sd[i] > 0.5:
            why[n] = "its 95 % interval spans more than half its bounds: the data hardly move it"
    norms = np.linalg.norm(J, axis=0)
    for i, n in enumerate(names):
        if norms[i] <= 1e-12 * max(norms.max(), 1e-300):
            why[n] = "the recordings do not depend on it"
    ok = norms > 0
    if ok.sum() >= 2:
        _, s, vt = np.linalg.svd(J[:, ok] / norms[ok], full_matrices=False)
        for k in np.flatnonzero(s < NULL_RATIO * s[0]):
            for j, i in enumerate(np.flatnonzero(ok).tolist()):
                if abs(vt[k, j]) > 0.3:
                    why.setdefault(names[i], "it weighs in a near-null direction of the Jacobian")
    R = correlation_of(C)
    for i in range(len(names)):
        for j in range(len(names)):
            if i != j and abs(R[i, j]) >= MAX_CORRELATION:
                why.setdefault(names[i], f"correlated {R[i, j]:+.3f} with {names[j]}")
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
    problem: FitProblem
    base: Params  # the base as given, before the fit (`problem.base` may have a freed drag switched on)

    def to_dict(self) -> dict:
        return {"parameters": self.parameters, "correlation": self.correlation, "residual_rms": self.residual_rms,
                "base_residual_rms": self.base_residual_rms,
                "starts": [{"cost": s.cost, "evaluations": s.nfev,
                            "values": {p.name: p.from_unit(x) for p, x in zip(self.problem.free, s.u)}}
                           for s in self.starts]}


Progress = Callable[[str, int, int], None]


def serial_map(fn, problem: FitProblem, points):
    """Run the starts one after the other in this process (the default `map_fn`)."""
    for u0 in points:
        yield fn(problem, u0)


def _best(problem: FitProblem, points, map_fn, say: Progress) -> tuple[np.ndarray, list[StartResult]]:
    results: list[StartResult] = []
    for i, res in enumerate(map_fn(solve_start, problem, points)):
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

    `map_fn(solve_start, problem, points)` runs the starts and yields their `StartResult`s in order
    (default: one after the other in this process).
    """
    say = progress or (lambda stage, done, total: None)
    kw = {"actuator": actuator, "kernel": kernel} | ({"horizon_s": horizon_s} if horizon_s else {})
    given = base
    problem = FitProblem.build(recordings, prepared_base(base, [p.name for p in free]), model, free, **kw)
    fit_delay = any(p.name == DELAY_KEY for p in free)
    u, results = _best(problem, start_points(problem, starts, seed), map_fn, say) if problem.free else (
        np.zeros(0), [])
    delay, band = 0, [0]
    if fit_delay:
        delay, band = _delay_scan(problem, problem.params_at(u), say)
        if delay:
            problem = replace(problem, delay_steps=delay)
            u = np.array(solve_start(problem, u).u) if problem.free else u
    return _report(problem, u, results, fit_delay, band, say, given)


def _report(problem: FitProblem, u: np.ndarray, results, fit_delay: bool, band: list[int], say: Progress,
            given: Params) -> FitResult:
    """Identifiability, the refit of what is identifiable, intervals, the report (module doc, steps 3–4)."""
    names = [p.name for p in problem.free]
    r0 = problem.residuals(u)
    J = jacobian(problem, u, r0) if names else np.zeros((r0.size, 0))
    C = covariance(J, r0, problem.cluster_ids()) if names else np.zeros((0, 0))
    why = unidentifiable(J, C, names)
    say("intervals", 1, 2)
    keep = [i for i, n in enumerate(names) if n not in why]
    if why and names:
        fixed = problem.params_at(u).with_overrides({n: base_value(problem.base, n) for n in why})
        sub = replace(problem, base=fixed, free=tuple(problem.free[i] for i in keep))
        u_sub = np.array(solve_start(sub, u[keep]).u) if keep else np.zeros(0)
        r_sub = sub.residuals(u_sub)
        J_sub = jacobian(sub, u_sub, r_sub) if keep else np.zeros((r_sub.size, 0))
        C_sub = covariance(J_sub, r_sub, sub.cluster_ids()) if keep else np.zeros((0, 0))
        params = sub.params_at(u_sub) if keep else fixed
        point = {problem.free[i].name: (u_sub[j], C_sub[j, j]) for j, i in enumerate(keep)}
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
                     starts=tuple(results), problem=problem, base=given)


def _entry(p: FreeParameter, u: float, var: float, base: Params, why: str | None, value: float) -> dict:
    """One parameter's report: value, ci95 (search coordinate ± 1.96 σ, clipped to the bounds), unit, identifiable."""
    sd = math.sqrt(max(var, 0.0)) * p.span()
    centre = math.log(value) if p.log and value > 0 else value
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
