"""What changed between two groups of bags (`prsm-bag compare A_DIR B_DIR`), e.g. two controller versions.

Both groups are reported bag by bag (`fleet.report_many`, on Ray when it is installed); then,
per metric present in both: median, mean and spread of each group, the relative change of the
median B vs A, and the Mann-Whitney U test's two-sided p-value (a rank test: no normality
assumed, robust to the odd outlier bag). A metric whose better direction is known (tracking
errors and peak loads: lower; efficiency and life: higher) is flagged a regression when its
median moves the wrong way by more than `threshold` (relative) and the rank test agrees
(p < `alpha`), so one noisy bag does not raise a flag.

With n_a and n_b bags the rank test cannot give a p-value below 2 / C(n_a + n_b, n_a) (every
bag of one group beyond every bag of the other). When that floor is not below `alpha` no
comparison can be significant: the verdict is "too few bags", with the smallest group size that
could reach significance (`smallest_group`, equal groups), never "0 regressions". Only metrics
are compared: figures of the run (errors, efficiencies, peaks, life, travel), not where or when a
peak happened, sample counts, energies or the rating used.
"""

from __future__ import annotations

import math

import numpy as np

from prsm_ros.bag.fleet import expand, report_many
from prsm_ros.bag.reader import BagError

# better direction by metric name: −1 lower is better, +1 higher is better (first match wins)
DIRECTIONS = (("error", -1), ("peak", -1), ("slip", -1), ("efficiency", +1), ("life.l10", +1))
SKIP = ("duration_s", "samples", "complete", "dt_s", "wall_time_s", "life.dynamic_load_rating_n",
        "life.cycle_duration_s", "life.cycle_revolutions", "tracking.pairs", "tracking.reference_span_m")
# parts of a flattened name that mark where or when a figure happened, or the bookkeeping behind it
NOT_METRIC = (".time_s", ".at.", "_segments", "_energy_j", "_energy_change_j", "_energy_released_j")


def is_metric(name: str) -> bool:
    """A figure of the run worth comparing (not a peak's time or element, a count, or an energy sum)."""
    return name not in SKIP and name not in ("bag", "status", "error") and not any(p in name for p in NOT_METRIC)


def min_p_value(n_a: int, n_b: int) -> float:
    """The smallest two-sided Mann-Whitney p-value two groups of these sizes can give (no ties)."""
    if n_a < 1 or n_b < 1:
        return 1.0
    return min(1.0, 2.0 / math.comb(n_a + n_b, n_a))


def smallest_group(alpha: float) -> int:
    """The fewest bags per group (equal groups) with which the rank test can reach p < alpha."""
    n = 1
    while min_p_value(n, n) >= alpha:
        n += 1
    return n


def direction(metric: str) -> int:
    for key, d in DIRECTIONS:
        if key in metric:
            return d
    return 0


def _check(threshold: float, alpha: float) -> None:
    if not (math.isfinite(threshold) and threshold >= 0):
        raise BagError(f"--threshold {threshold!r}: must be a relative change >= 0 (e.g. 0.05 for 5 %)")
    if not (0 < alpha < 1):
        raise BagError(f"--alpha {alpha!r}: must lie in (0, 1)")


def _finite_values(ok_a: list[dict], ok_b: list[dict], name: str) -> tuple[np.ndarray, np.ndarray] | None:
    """The finite values of `name` in each group; None when a value is no float or a group has none."""
    va = np.array([r.get(name, math.nan) for r in ok_a], dtype=object)
    vb = np.array([r.get(name, math.nan) for r in ok_b], dtype=object)
    if not all(isinstance(v, float) for v in (*va, *vb)):
        return None
    va = va.astype(float)[np.isfinite(va.astype(float))]
    vb = vb.astype(float)[np.isfinite(vb.astype(float))]
    if not va.size or not vb.size:
        return None
    return va, vb


def _relative_change(ma: float, mb: float) -> float:
    """(mb − ma) / |ma|; from a zero median A: 0 when unchanged, else ±inf in the direction of the move."""
    if ma != 0:
        return (mb - ma) / abs(ma)
    return 0.0 if mb == ma else math.copysign(math.inf, mb - ma)


def _rank_p_value(va: np.ndarray, vb: np.ndarray) -> float:
    """Mann-Whitney U two-sided p-value; NaN with fewer than two values in a group or all values equal."""
    from scipy.stats import mannwhitneyu
    if va.size > 1 and vb.size > 1 and np.ptp(np.concatenate([va, vb])) > 0:
        return float(mannwhitneyu(va, vb, alternative="two-sided").pvalue)
    return math.nan


def _summary(v: np.ndarray) -> dict:
    return {"n": int(v.size), "median": float(np.median(v)), "mean": float(v.mean()), "std": float(v.std())}


def _metric(name: str, va: np.ndarray, vb: np.ndarray, threshold: float, alpha: float, enough: bool) -> dict:
    """One metric's statistics in both groups and whether B is a regression on A."""
    sa, sb = _summary(va), _summary(vb)
    change = _relative_change(sa["median"], sb["median"])
    p = _rank_p_value(va, vb)
    d = direction(name)
    worse = enough and d != 0 and change * d < -threshold and (not math.isnan(p) and p < alpha)
    return {"a": sa, "b": sb, "relative_change": change, "p_value": p,
            "better": {-1: "lower", 1: "higher", 0: None}[d], "regression": bool(worse)}


def compare_rows(a: list[dict], b: list[dict], threshold: float = 0.05, alpha: float = 0.05) -> dict:
    """Statistics per metric and regression flags for rows of group A (before) and B (after)."""
    _check(threshold, alpha)
    ok_a = [r for r in a if r["status"] == "ok"]
    ok_b = [r for r in b if r["status"] == "ok"]
    names = sorted({k for r in ok_a for k in r} & {k for r in ok_b for k in r})
    floor = min_p_value(len(ok_a), len(ok_b))
    enough = floor < alpha
    metrics = {}
    for n in filter(is_metric, names):
        values = _finite_values(ok_a, ok_b, n)
        if values is not None:
            metrics[n] = _metric(n, *values, threshold, alpha, enough)
    regressions = [n for n, m in metrics.items() if m["regression"]]
    return {"a_bags": len(a), "b_bags": len(b), "a_failed": len(a) - len(ok_a), "b_failed": len(b) - len(ok_b),
            "threshold": threshold, "alpha": alpha, "min_p_value": floor, "smallest_group": smallest_group(alpha),
            "verdict": "compared" if enough else "too few bags", "metrics": metrics, "regressions": regressions}


def compare(a_dir: str, b_dir: str, options: dict, *, threshold: float = 0.05, alpha: float = 0.05,
            address: str | None = None, use_ray: bool | None = None, progress: bool = True) -> dict:
    _check(threshold, alpha)  # before any bag is read
    a_paths, b_paths = expand(a_dir), expand(b_dir)
    rows = report_many(a_paths + b_paths, options, address=address, use_ray=use_ray, progress=progress)
    out = compare_rows(rows[:len(a_paths)], rows[len(a_paths):], threshold, alpha)
    out.update({"a": str(a_dir), "b": str(b_dir)})
    return out


def text(c: dict) -> str:
    lines = [f"A = {c['a']} ({c['a_bags']} bags, {c['a_failed']} unreadable), "
             f"B = {c['b']} ({c['b_bags']} bags, {c['b_failed']} unreadable); "
             f"regression: median worse by > {c['threshold']:.0%} with p < {c['alpha']}"]
    width = max((len(n) for n in c["metrics"]), default=6)
    lines.append(f"{'metric':<{width}}  {'median A':>12}  {'median B':>12}  {'change':>9}  {'p':>7}")
    for n, m in c["metrics"].items():
        flag = "  REGRESSION" if m["regression"] else ""
        p = "-" if math.isnan(m["p_value"]) else f"{m['p_value']:.3g}"
        lines.append(f"{n:<{width}}  {m['a']['median']:>12.6g}  {m['b']['median']:>12.6g}  "
                     f"{m['relative_change']:>+9.1%}  {p:>7}{flag}")
    if c["verdict"] == "too few bags":
        lines.append(f"too few bags: with {c['a_bags'] - c['a_failed']} and {c['b_bags'] - c['b_failed']} readable bags "
                     f"the rank test cannot go below p = {c['min_p_value']:.3g} (alpha {c['alpha']}); "
                     f"record at least {c['smallest_group']} bags per group for a verdict")
    else:
        lines.append(f"{len(c['regressions'])} regression(s)" + (": " + ", ".join(c["regressions"]) if c["regressions"] else ""))
    return "\n".join(lines)
