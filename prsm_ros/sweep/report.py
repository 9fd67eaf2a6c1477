"""What a finished (or partial) study shows: statistics, sensitivities, failures, and plots.

Sensitivity is Spearman's rank correlation ρ between each varied input and each metric over
the successful runs: it measures a monotonic influence whatever its shape, so an input that
moves a metric through a nonlinear law still ranks by how much of the metric's order it
explains. The tornado plot shows ρ per input, largest |ρ| on top.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from prsm_ros.sweep.execute import undefined, undefined_text
from prsm_ros.sweep.runner import read_study_dir, recorded_rows
from prsm_ros.sweep.study import StudyError

PERCENTILES = (5, 50, 95)
MIN_PLOTTED = 2  # a metric with values in fewer runs gets no plots (one point shows no spread or trend)


def load_runs(out: Path):
    """The study's runs as a pandas DataFrame (runs.parquet plus any unfolded parts)."""
    import pandas as pd
    norm, h = read_study_dir(out)
    rows = recorded_rows(out)
    if not rows:
        raise StudyError(f"{out}: no runs recorded yet (run `prsm-sweep run` first)")
    return norm, h, pd.DataFrame(rows)


def statistics(df, metrics: list[str]) -> dict:
    ok = df[df["status"] == "ok"]
    out = {}
    for m in metrics:
        v = ok[m].to_numpy(dtype=float)
        v = v[np.isfinite(v)]
        if not v.size:
            out[m] = {"count": 0}
            continue
        out[m] = {"count": int(v.size), "mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
                  "min": float(v.min()), "max": float(v.max()),
                  **{f"p{p}": float(np.percentile(v, p)) for p in PERCENTILES}}
    return out


def sensitivities(df, inputs: list[str], metrics: list[str]) -> dict:
    """{metric: [{"input", "spearman_rho"}, ...] sorted by |ρ| (largest first)}; constant inputs left out."""
    from scipy.stats import spearmanr
    ok = df[df["status"] == "ok"]
    out = {}
    for m in metrics:
        ranked = []
        y = ok[m].to_numpy(dtype=float)
        for k in inputs:
            x = ok[k]
            if x.dtype == object or x.nunique() < 2:
                continue
            x = x.to_numpy(dtype=float)
            good = np.isfinite(x) & np.isfinite(y)
            if good.sum() < 3 or np.ptp(y[good]) == 0:
                continue
            rho = float(spearmanr(x[good], y[good]).statistic)
            ranked.append({"input": k, "spearman_rho": rho})
        ranked.sort(key=lambda r: -abs(r["spearman_rho"]) if math.isfinite(r["spearman_rho"]) else 0.0)
        out[m] = ranked
    return out


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in name)


def plots(df, inputs: list[str], metrics: list[str], sens: dict, out: Path) -> list[str]:
    """Histogram per metric, scatter per (input, metric), tornado per metric → PNG paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ok = df[df["status"] == "ok"]
    d = out / "plots"
    d.mkdir(exist_ok=True)
    written = []

    def save(fig, name):
        path = d / f"{_safe(name)}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=80)
        plt.close(fig)
        written.append(str(path))

    for m in metrics:
        v = ok[m].to_numpy(dtype=float)
        v = v[np.isfinite(v)]
        if v.size < MIN_PLOTTED:  # the report's text says how many runs have a value, and why the rest do not
            continue
        if v.size:
            fig, ax = plt.subplots(figsize=(5, 3.5))
            ax.hist(v, bins=min(30, max(5, v.size // 5)))
            ax.set_xlabel(m)
            ax.set_ylabel("runs")
            save(fig, f"hist_{m}")
        for k in inputs:
            if ok[k].dtype == object:
                continue
            fig, ax = plt.subplots(figsize=(5, 3.5))
            ax.scatter(ok[k].to_numpy(dtype=float), ok[m].to_numpy(dtype=float), s=8)
            ax.set_xlabel(k)
            ax.set_ylabel(m)
            save(fig, f"scatter_{k}__{m}")
        if sens.get(m):
            rows = sens[m][::-1]
            fig, ax = plt.subplots(figsize=(5, 0.5 + 0.4 * len(rows)))
            ax.barh([r["input"] for r in rows], [r["spearman_rho"] for r in rows])
            ax.set_xlim(-1, 1)
            ax.axvline(0, color="k", lw=0.5)
            ax.set_xlabel(f"Spearman ρ with {m}")
            save(fig, f"tornado_{m}")
    return written


def build(out: Path, make_plots: bool = True) -> dict:
    """The report of study directory `out` (also what `--json` prints)."""
    norm, h, df = load_runs(out)
    inputs = list(norm["vary"]) + (["scenario"] if len(norm["scenarios"]) > 1 else [])
    metrics = norm["metrics"]
    failed = df[df["status"] != "ok"]
    sens = sensitivities(df, [k for k in inputs if k != "scenario"], metrics)
    report = {"study": h, "dir": str(out), "runs_planned": None, "runs_recorded": int(len(df)),
              "runs_ok": int((df["status"] == "ok").sum()), "runs_failed": int(len(failed)),
              "failures": [{"run_id": int(r["run_id"]), "error": r["error"]} for _, r in failed.head(20).iterrows()],
              "statistics": statistics(df, metrics), "sensitivities": sens,
              "undefined": undefined(df.to_dict("records"), metrics),
              "wall_time_s_per_run": float(df["wall_time_s"].mean())}
    from prsm_ros.sweep.study import run_specs
    report["runs_planned"] = len(run_specs(norm))
    if len(norm["scenarios"]) > 1:
        report["by_scenario"] = {s: statistics(g, metrics) for s, g in df.groupby("scenario")}
    report["plots"] = plots(df, [k for k in inputs if k != "scenario"], metrics, sens, out) if make_plots else []
    return report


def text(report: dict) -> str:
    lines = [f"study {report['study']} in {report['dir']}: {report['runs_recorded']} of {report['runs_planned']} runs "
             f"recorded, {report['runs_ok']} ok, {report['runs_failed']} failed "
             f"(mean {report['wall_time_s_per_run'] * 1e3:.1f} ms per run)"]
    for m, s in report["statistics"].items():
        if not s.get("count"):
            lines.append(f"  {m}: no value")
            continue
        lines.append(f"  {m}: mean {s['mean']:.6g}  sd {s['std']:.3g}  min {s['min']:.6g}  p5 {s['p5']:.6g}  "
                     f"p50 {s['p50']:.6g}  p95 {s['p95']:.6g}  max {s['max']:.6g}  (n={s['count']})")
        for r in report["sensitivities"].get(m, []):
            lines.append(f"      ρ = {r['spearman_rho']:+.3f}  {r['input']}")
    lines += [f"  {line}" for line in undefined_text(report["undefined"])]
    unplotted = [m for m, s in report["statistics"].items() if s.get("count", 0) < MIN_PLOTTED]
    if report["plots"] and unplotted:
        lines.append(f"  no plots of {', '.join(unplotted)}: fewer than {MIN_PLOTTED} runs with a value")
    for f in report["failures"]:
        lines.append(f"  failed run {f['run_id']}: {f['error']}")
    if report["plots"]:
        lines.append(f"  {len(report['plots'])} plots in {Path(report['plots'][0]).parent}")
    return "\n".join(lines)
