"""`prsm-bench`: every performance figure of the system beside its target, on this machine.

Each area measures itself in its own module (`bench_core`, `bench_node`, `bench_recorder`,
`bench_rerun`, `bench_soak`), each with `measure(quick) -> list[figure]`; this command runs
them in turn and prints one table (or `--json`). Ratios are measured side by side in one run,
repeated, and reported as median with spread. `--quick` is a smoke run of under a minute: its
figures are indicative only, and nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import importlib
import math
import platform
import sys
import time

from prsm_ros.cli.json_out import dumps

AREAS = {
    "core": "prsm_ros.bench.core",
    "node": "prsm_ros.bench.node",
    "recorder": "prsm_ros.bench.recorder",
    "rerun": "prsm_ros.bench.viz",
    "soak": "prsm_ros.bench.soak",
    "realtime": "prsm_ros.bench.realtime",
}


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if abs(v) >= 1000:
        return f"{v:,.0f}"
    if abs(v) >= 10:
        return f"{v:.1f}"
    return f"{v:.3g}"


def run(areas: list[str], quick: bool) -> list[dict]:
    figures = []
    for area in areas:
        t0 = time.perf_counter()
        try:
            mod = importlib.import_module(AREAS[area])
            figs = mod.measure(quick=quick)
        except Exception as e:  # one broken area must not hide the others' figures
            figs = [{"figure": f"{area}: could not be measured", "value": math.nan, "unit": "", "target": "",
                     "ok": False, "spread": None, "notes": f"{type(e).__name__}: {e}"}]
        for f in figs:
            f["area"] = area
        figures.extend(figs)
        print(f"[{area}: {time.perf_counter() - t0:.1f} s]", file=sys.stderr)
    return figures


def table(figures: list[dict]) -> str:
    rows = [("area", "figure", "value", "target", "", "spread", "notes")]
    for f in figures:
        spread = f.get("spread")
        rows.append((f["area"], f["figure"], f"{_fmt(f['value'])} {f['unit']}".strip(), f["target"],
                     "not judged" if f["ok"] is None else "ok" if f["ok"] else "MISSED", f"±{spread * 50:.0f} %" if spread else "", f.get("notes", "")))
    widths = [max(len(r[i]) for r in rows) for i in range(6)]
    lines = []
    for r in rows:
        lines.append("  ".join(c.ljust(w) for c, w in zip(r[:6], widths)) + "  " + r[6])
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="prsm-bench", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smoke run, under a minute; figures indicative only")
    ap.add_argument("--json", action="store_true", help="machine-readable figures")
    ap.add_argument("--only", action="append", choices=list(AREAS), help="measure only these areas (repeatable)")
    a = ap.parse_args(argv)
    figures = run(a.only or list(AREAS), a.quick)
    meta = {"machine": platform.machine(), "python": platform.python_version(), "quick": a.quick,
            "cpus": __import__("os").cpu_count()}
    if a.json:
        print(dumps({"meta": meta, "figures": figures}))
    else:
        print(f"prsm-bench on {meta['machine']}, {meta['cpus']} CPUs, Python {meta['python']}"
              f"{' (quick: indicative only)' if a.quick else ''}")
        print(table(figures))
    return 0


def area_main(area: str, argv: list[str] | None = None) -> int:
    """`python -m prsm_ros.bench_<area>`: the same as `prsm-bench --only <area>` (same options)."""
    return main(["--only", area, *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
