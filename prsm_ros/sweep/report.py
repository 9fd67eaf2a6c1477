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


# unit of a name by its suffix (longest first), where the name is not an output with a unit of its own
_SUFFIX_UNITS = (("_n_s_m", "N·s/m"), ("_nm_s_rad", "N·m·s/rad"), ("_m2_s", "m²/s"), ("_kg_m3", "kg/m³"),
                 ("_kgm2", "kg·m²"), ("_n_per_m", "N/m"), ("_rad_s", "rad/s"), ("_m_s", "m/s"), ("_revolutions", "rev"),
                 ("_hours", "h"), ("_deg", "°"), ("_rad", "rad"), ("_nm", "N·m"), ("_kg", "kg"), ("_pa", "Pa"),
                 ("_rel", "1"), ("_n", "N"), ("_m", "m"), ("_j", "J"), ("_w", "W"), ("_s", "s"))


def unit_of(name: str) -> str:
    """The unit of a study input (`group.field`) or metric (`output[@selector]`, a summary figure); "" unknown."""
    from prsm_sim import OUTPUT_FIELDS
    base = name.partition("@")[0]
    own = dict(OUTPUT_FIELDS)
    if base in own:
        return own[base]
    field = base.rsplit(".", 1)[-1]
    if field.startswith("mu_") or field in ("gear_ratio", "poisson_ratio", "breakaway_ratio"):
        return "1"
    return next((u for suffix, u in _SUFFIX_UNITS if field.endswith(suffix)), "")


def axis_label(name: str) -> str:
    unit = unit_of(name)
    return f"{name} [{unit}]" if unit else name


FIGSIZE_IN = (7.0, 4.6)
DPI = 110
MAX_TICKS = 6


def plots(df, inputs: list[str], metrics: list[str], sens: dict, out: Path, context: str = "") -> list[str]:
    """Histogram per metric, scatter per (input, metric), tornado per metric → PNG paths.

    Each figure is titled (what it shows, over how many runs, and `context`: model, preset, scenario)
    and its axes name their quantity with its unit; ticks are capped at MAX_TICKS so they never overlap.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator
    ok = df[df["status"] == "ok"]
    d = out / "plots"
    d.mkdir(exist_ok=True)
    written = []

    def figure(height_in: float = FIGSIZE_IN[1]):
        fig, ax = plt.subplots(figsize=(FIGSIZE_IN[0], height_in))
        ax.grid(True, alpha=0.4, linewidth=0.6)
        ax.xaxis.set_major_locator(MaxNLocator(MAX_TICKS))
        return fig, ax

    def save(fig, ax, name, title):
        ax.set_title(title + (f"\n{context}" if context else ""), fontsize="medium", loc="left")
        path = d / f"{_safe(name)}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=DPI)
        plt.close(fig)
        written.append(str(path))

    for m in metrics:
        v = ok[m].to_numpy(dtype=float)
        v = v[np.isfinite(v)]
        if v.size < MIN_PLOTTED:  # the report's text says how many runs have a value, and why the rest do not
            continue
        if v.size:
            fig, ax = figure()
            ax.hist(v, bins=min(30, max(5, v.size // 5)), color="tab:blue", edgecolor="white")
            ax.set_xlabel(axis_label(m))
            ax.set_ylabel("runs")
            ax.yaxis.set_major_locator(MaxNLocator(MAX_TICKS, integer=True))
            save(fig, ax, f"hist_{m}", f"Distribution of {m} over {v.size} runs")
        for k in inputs:
            if ok[k].dtype == object:
                continue
            fig, ax = figure()
            ax.scatter(ok[k].to_numpy(dtype=float), ok[m].to_numpy(dtype=float), s=12, color="tab:blue")
            ax.set_xlabel(axis_label(k))
            ax.set_ylabel(axis_label(m))
            ax.yaxis.set_major_locator(MaxNLocator(MAX_TICKS))
            rho = next((r["spearman_rho"] for r in sens.get(m, []) if r["input"] == k), None)
            save(fig, ax, f"scatter_{k}__{m}", f"{m} against {k} ({len(ok)} runs"
                 + (f", Spearman ρ = {rho:+.2f})" if rho is not None else ")"))
        if sens.get(m):
            rows = sens[m][::-1]
            fig, ax = figure(1.6 + 0.45 * len(rows))
            ax.barh([r["input"] for r in rows], [r["spearman_rho"] for r in rows],
                    color=["tab:red" if r["spearman_rho"] < 0 else "tab:blue" for r in rows])
            ax.set_xlim(-1, 1)
            ax.axvline(0, color="k", lw=0.5)
            ax.set_xlabel(f"Spearman ρ with {m} [1]")
            save(fig, ax, f"tornado_{m}", f"Sensitivity of {m} (rank correlation, {len(ok)} runs)")
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
    scenarios = ", ".join(map(str, norm.get("scenarios", [])))
    context = f"model {norm.get('model')}, preset {norm.get('preset')}, scenario {scenarios}"
    report["plots"] = (plots(df, [k for k in inputs if k != "scenario"], metrics, sens, out, context)
                       if make_plots else [])
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
