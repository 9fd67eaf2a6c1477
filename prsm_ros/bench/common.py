"""What every benchmark area shares: the figure record, the paced 1 kHz loop and the runner.

An area is a module with `measure(quick) -> list[figure]`; `prsm-bench` (`bench.cli`) names the
areas it runs, and each area's `python -m prsm_ros.bench.<area>` runs itself through `area_main`,
so no area imports the command back.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Mapping

import numpy as np

from prsm_sim import PrsmError, __version__

from prsm_ros.json_out import dumps
from prsm_ros.interrupts import interrupt_handled

Measure = Callable[..., list]


# glibc's malloc hands an array above its mmap threshold (128 KB at a process's start) fresh pages from the OS,
# and gives them back at its free: a batch run's column arithmetic (`Simulator.run`, 40,000 rows at `fu2018`'s
# 0.125 ms) then pays a page fault for every page of every temporary, each run (measured with `perf stat`: 88,000
# faults against 35,000 for the same 20 runs; 200× against 260× simulated s per wall s, and `jones2016`'s batch
# 2,144× against 5,310×). glibc raises the threshold on its own once the process frees a larger mapped block, whoever
# allocated it: building MuJoCo's model did, so a figure moved with the areas run before it. The bench sets both
# thresholds at its start (`steady_allocator`), as a long-running process ends up, so every figure sees one allocator.
MMAP_THRESHOLD_BYTES = 32 << 20  # glibc's own ceiling for the threshold it raises by itself (64-bit)
TRIM_THRESHOLD_BYTES = 64 << 20  # free memory at the heap's top kept, not given back (twice the above, as glibc does)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (glibc's malloc.h)


def steady_allocator() -> str:
    """Fix glibc malloc's mmap and trim thresholds for this process (see MMAP_THRESHOLD_BYTES); what was done, in
    words (the run's metadata). Elsewhere (another C library) nothing is changed."""
    import ctypes
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return "left as it is (no mallopt: not glibc)"
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    if mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES) != 1 or mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES) != 1:
        return "left as it is (mallopt refused the thresholds)"
    return f"glibc malloc: mmap threshold {MMAP_THRESHOLD_BYTES >> 20} MB, trim threshold {TRIM_THRESHOLD_BYTES >> 20} MB"


class BenchError(PrsmError, RuntimeError):
    """A benchmark run failed (a process exited early, messages were lost, no summary came back)."""


def figure(name, value, unit, target, ok, spread=None, notes=""):
    """One benchmark figure; `ok` None means not judged (an indicative smoke figure)."""
    return {"figure": name, "value": value, "unit": unit, "target": target, "ok": None if ok is None else bool(ok),
            "spread": spread, "notes": notes}


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a live process and all its threads (Linux /proc)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def descendants(pid: int) -> list[int]:
    """The live processes below `pid` (children, their children, ...), from /proc."""
    parent: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parent[int(entry)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue  # ended meanwhile
    out, frontier = [], [pid]
    while frontier:
        frontier = [p for p, pp in parent.items() if pp in frontier]
        out += frontier
    return out


def descendants_cpu_s(pid: int) -> float:
    """CPU seconds of `pid`'s live descendants: the node's MCAP writer process is part of the node's cost."""
    total = 0.0
    for child in descendants(pid):
        try:
            total += proc_cpu_s(child)
        except (OSError, ValueError, IndexError):
            continue
    return total


def cpu_with_children_s() -> float:
    """CPU seconds of this process (all threads) and its children, live (/proc) or ended and reaped."""
    import resource
    done = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + done.ru_utime + done.ru_stime + descendants_cpu_s(os.getpid())


def tree_cpu_s(pid: int) -> float:
    """CPU seconds of process `pid` with all its threads and live descendants."""
    return proc_cpu_s(pid) + descendants_cpu_s(pid)


def paced_loop(steps: int, work, period_s: float = 1e-3) -> dict:
    """Call `work(k)` on absolute deadlines k·period (the node's pacing) and measure the loop.

    Returns CPU seconds per wall second of this process and its children (all threads: a writer
    thread, or a writer process, counts too) and the lateness of the wake-ups against their
    deadlines (p50, p99, max in ms).
    """
    late = np.empty(steps)
    cpu0, t0 = cpu_with_children_s(), time.perf_counter()
    for k in range(steps):
        due = t0 + (k + 1) * period_s
        now = time.perf_counter()
        if due > now:
            time.sleep(due - now)
        late[k] = time.perf_counter() - due
        work(k)
    wall = time.perf_counter() - t0
    cpu = cpu_with_children_s() - cpu0
    return {"cpu_per_wall": cpu / wall, "late_p50_ms": float(np.percentile(late, 50) * 1e3),
            "late_p99_ms": float(np.percentile(late, 99) * 1e3), "late_max_ms": float(np.max(late) * 1e3)}


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "n/a"
    if abs(v) >= 1000:
        return f"{v:,.0f}"
    if abs(v) >= 10:
        return f"{v:.1f}"
    return f"{v:.3g}"


def run(areas: Mapping[str, Measure], quick: bool, figures: list[dict] | None = None) -> list[dict]:
    """Every area's figures in turn, each tagged with its area, appended to `figures` as each area ends
    (so that a caller interrupted by Ctrl-C still holds the areas that finished)."""
    figures = [] if figures is None else figures
    for i, (area, measure) in enumerate(areas.items()):
        print(f"[{area}: measuring, area {i + 1} of {len(areas)}]", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        try:
            figs = measure(quick=quick)
        except Exception as e:  # one broken area must not hide the others' figures; its error is the figure
            figs = [{"figure": f"{area}: could not be measured", "value": math.nan, "unit": "", "target": "",
                     "ok": False, "spread": None, "notes": f"{type(e).__name__}: {e}"}]
        for f in figs:
            f["area"] = area
        figures.extend(figs)
        print(f"[{area}: {time.perf_counter() - t0:.1f} s]", file=sys.stderr)
    return figures


def _spread(spread: float | None) -> str:
    """(max − min) / median of the repeats as ± half of it in %, up to ±50 %; beyond, as a multiple of the
    median (a first repeat that compiles, a quick run of two repeats on a busy machine): "±13100 %" says nothing."""
    if not spread:
        return ""
    return f"±{spread * 50:.0f} %" if spread <= 1.0 else f"max − min {spread:.3g}× median"


def table(figures: list[dict]) -> str:
    rows = [("area", "figure", "value", "target", "", "spread", "notes")]
    for f in figures:
        spread = f.get("spread")
        rows.append((f["area"], f["figure"], f"{_fmt(f['value'])} {f['unit']}".strip(), f["target"],
                     "not judged" if f["ok"] is None else "ok" if f["ok"] else "MISSED", _spread(spread), f.get("notes", "")))
    widths = [max(len(r[i]) for r in rows) for i in range(6)]
    lines = []
    for r in rows:
        lines.append("  ".join(c.ljust(w) for c, w in zip(r[:6], widths)) + "  " + r[6])
    return "\n".join(lines)


def main(areas: Mapping[str, Measure], argv: list[str] | None = None, *, prog: str = "prsm-bench",
         description: str = "") -> int:
    """The command line over `areas`: --quick, --json, --only AREA (repeatable)."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    ap.add_argument("--quick", action="store_true", help="smoke run, under a minute; figures indicative only")
    ap.add_argument("--json", action="store_true", help="machine-readable figures")
    ap.add_argument("--only", action="append", choices=list(areas), help="measure only these areas (repeatable)")
    a = ap.parse_args(argv)
    chosen = {k: areas[k] for k in (a.only or areas)}
    allocator = steady_allocator()
    figures: list[dict] = []
    interrupted = False
    try:
        run(chosen, a.quick, figures)
    except KeyboardInterrupt:
        interrupt_handled()
        interrupted = True
    meta = {"machine": platform.machine(), "python": platform.python_version(), "quick": a.quick,
            "cpus": os.cpu_count(), "allocator": allocator}
    if interrupted:
        done = list(dict.fromkeys(f["area"] for f in figures))
        meta["interrupted"] = True
        print(f"{prog}: interrupted: {len(done)} of {len(chosen)} areas measured"
              + (f" ({', '.join(done)}), their figures below" if done else ", no figures"), file=sys.stderr)
    if a.json:
        print(dumps({"meta": meta, "figures": figures}))
    else:
        print(f"prsm-bench on {meta['machine']}, {meta['cpus']} CPUs, Python {meta['python']}"
              f"{' (quick: indicative only)' if a.quick else ''}")
        print(table(figures))
    return 130 if interrupted else 0


def area_main(area: str, measure: Measure, argv: list[str] | None = None) -> int:
    """`python -m prsm_ros.bench.<module>`: the same as `prsm-bench --only <area>` (same options)."""
    return main({area: measure}, sys.argv[1:] if argv is None else argv, prog=f"prsm-bench ({area})")
