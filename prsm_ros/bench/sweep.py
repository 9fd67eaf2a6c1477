"""Benchmarks of studies on Ray (`prsm-bench --only sweep`): scaling over workers and the cost of a task.

All figures run in one embedded Ray (2 CPUs, its own temp dir, stopped at the end) through the
study runner itself (`prsm_ros.sweep.runner.run_study`), side by side and repeated:

- throughput with 2 workers over 1 worker on the same study (target ≥ 1.7 on 2 cores);
- runs per second for short runs (10 ms simulated) with one run per task and with many, and for
  long runs (1 s simulated), each beside the in-process rate of the same runs without Ray, so the
  per-task overhead shows (and whether batching several runs into a task pays).

Nothing here asserts a timing; on a shared machine the figures are noisy.
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
import time
from pathlib import Path

from prsm_ros.bench.common import area_main, figure
from prsm_ros.sweep import execute, runner, study

TARGET_SCALING = 1.7


def _study(duration_s: float, n: int) -> dict:
    return study.normalise({"preset": "s30", "model": "fu2018", "scenario": "heavy", "duration_s": duration_s,
                            "vary": {"friction.mu_screw_roller": {"uniform": [0.02, 0.12]}}, "samples": n,
                            "seed": 1, "metrics": ["efficiency"]})


def _ray_rate(norm: dict, workers: int, per_task: int, tmp: Path) -> float:
    out = Path(tempfile.mkdtemp(dir=tmp))
    s = runner.run_study(norm, out, workers=workers, runs_per_task=per_task, progress=False)
    shutil.rmtree(out, ignore_errors=True)
    assert s["failed"] == 0 and s["ran"] == s["runs"]
    return s["ran"] / s["wall_time_s"]


def _serial_rate(norm: dict) -> float:
    specs = study.run_specs(norm)
    t0 = time.perf_counter()
    for spec in specs:
        execute.run_one(norm, spec)
    return len(specs) / (time.perf_counter() - t0)


def _median_spread(values: list[float]) -> tuple[float, float]:
    med = statistics.median(values)
    return med, (max(values) - min(values)) / med if med > 0 else 0.0


def measure(quick: bool = False) -> list[dict]:
    repeats = 1 if quick else 3
    n_scale, n_short, n_long = (24, 60, 6) if quick else (80, 200, 16)
    tmp = Path(tempfile.mkdtemp(prefix="prsmray-", dir="/tmp"))
    runner.start_embedded(2, str(tmp / "r"))  # as prsm-sweep does
    import ray
    try:
        mid = _study(0.3, n_scale)
        _ray_rate(mid, 2, 4, tmp)  # warm the worker processes (imports) before timing
        one, two = [], []
        for _ in range(repeats):  # alternated, so load changes hit both
            one.append(_ray_rate(mid, 1, 4, tmp))
            two.append(_ray_rate(mid, 2, 4, tmp))
        ratios = [b / a for a, b in zip(one, two)]
        ratio, spread = _median_spread(ratios)
        short, long_ = _study(0.01, n_short), _study(1.0, n_long)
        rates = {}
        for name, norm, per_task in (("short_1", short, 1), ("short_batch", short, 20), ("long_1", long_, 1)):
            rates[name] = _median_spread([_ray_rate(norm, 2, per_task, tmp) for _ in range(repeats)])
        serial_short = _serial_rate(short)
        serial_long = _serial_rate(long_)
    finally:
        ray.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
    # with one run per task, 2 workers spend 2/rate per run; the in-process run itself takes 1/serial
    overhead_ms = max(0.0, 2.0 / rates["short_1"][0] - 1.0 / serial_short) * 1e3
    return [
        figure("sweep: throughput 2 workers / 1 worker (fu2018 heavy, 0.3 s runs, 4 per task)", ratio, "×",
               f">= {TARGET_SCALING}", None if quick else ratio >= TARGET_SCALING, spread,
               f"{statistics.median(one):.1f} vs {statistics.median(two):.1f} runs/s; Ray start not included"),
        figure("sweep: short runs (10 ms simulated), 1 run per task, 2 workers", rates["short_1"][0], "runs/s", "", None,
               rates["short_1"][1], f"in-process without Ray {serial_short:.0f} runs/s on 1 core; "
                                    f"≈ {overhead_ms:.0f} ms of task overhead per task and worker"),
        figure("sweep: short runs (10 ms simulated), 20 runs per task, 2 workers", rates["short_batch"][0], "runs/s", "",
               None, rates["short_batch"][1],
               f"{rates['short_batch'][0] / rates['short_1'][0]:.1f}× the one-run-per-task rate"),
        figure("sweep: long runs (1 s simulated), 1 run per task, 2 workers", rates["long_1"][0], "runs/s", "", None,
               rates["long_1"][1], f"in-process without Ray {serial_long:.1f} runs/s on 1 core "
                                   f"({rates['long_1'][0] / serial_long:.2f}× with 2 workers)"),
    ]


def main(argv: list[str] | None = None) -> int:
    return area_main("sweep", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
