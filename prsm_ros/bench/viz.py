"""Benchmarks of the Rerun output: its cost beside a 1 kHz step loop, and how fast batches and bags convert.

- CPU at 1 kHz: a loop paced on absolute 1 ms deadlines steps the simulator (fu2018, s30, a
  sinusoidal torque) and hands every step to a `RerunSink` in save mode, against the same loop
  with the sink off; the difference in process CPU time (all threads) per wall second is the cost
  of live logging, in % of one core (target ≤ 5 %) with the sink's default periods (scalar outputs
  every 0.2 s, internal loads and scene every 1 s). The same runs give the cost of one
  `submit()` call (what the step loop itself pays) and the loop's lateness percentiles.
- batch throughput: steps per second through `RecordingWriter.send` (series of every step plus the
  scene at 30 Hz) — the background thread's headroom over the 1000 steps/s it must keep up with.
- bag conversion: simulated steps per second through `bag_to_rrd` for a bag written by
  `offline_record.write_trajectory_mcap`.

Figures are printed, never asserted (`prsm-bench --only rerun` aggregates them).
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

from prsm_ros.bench.common import area_main, figure, paced_loop

CPU_TARGET_PCT = 5.0
MODEL = "fu2018"
PRESET = "s30"


def _torque(k: int) -> float:
    return 3.0 * math.sin(2 * math.pi * 0.5 * k * 1e-3)


def loop_cost(seconds: float, sink_mode: str, path: Path, **sink_options) -> dict:
    """One paced 1 kHz run (`common.paced_loop`): CPU per wall second, submit() cost, lateness."""
    from prsm_sim import Simulator, preset

    from prsm_ros.viz.sink import RerunSink

    params = preset(PRESET)
    sim = Simulator(params, MODEL, 1e-3)
    sink = RerunSink(sink_mode, str(path), params, sim.layout, MODEL, **sink_options)
    steps = int(seconds * 1000)
    submit_ns = np.empty(steps)

    def work(k: int) -> None:
        out = sim.step(_torque(k), 2000.0)
        s0 = time.perf_counter_ns()
        sink.submit(out)
        submit_ns[k] = time.perf_counter_ns() - s0

    loop = paced_loop(steps, work)
    sink.close()  # the tail's flush is not part of the steady-state cost
    st = sink.stats()
    return {**loop, "submit_p50_us": float(np.median(submit_ns) / 1e3),
            "submit_p99_us": float(np.percentile(submit_ns, 99) / 1e3), "dropped": st["dropped"],
            "rows": st["rows"], "frames": st["scene_frames"], "error": st["error"],
            "flush_s": st["flush_time_s"], "batches": st["batches"], "flush_period_s": sink.flush_period_s,
            "loads_period_s": sink.loads_period_s}


def batch_throughput(steps: int, repeats: int) -> tuple[float, float]:
    """(median steps/s, spread) through RecordingWriter.send in one batch, to a file."""
    import rerun as rr

    from prsm_sim import Simulator, preset

    from prsm_ros.viz.sink import RecordingWriter

    params = preset(PRESET)
    traj = Simulator(params, MODEL, 1e-3).run([_torque(k) for k in range(steps)], 2000.0)
    rates = []
    with tempfile.TemporaryDirectory() as d:
        for r in range(repeats):
            rec = rr.RecordingStream("prsm_bench", recording_id=uuid.uuid4())
            rec.save(Path(d) / f"b{r}.rrd")
            writer = RecordingWriter(rec, params, traj.layout, MODEL)
            writer.log_static()
            t0 = time.perf_counter()
            writer.send(traj.columns, traj.internal)
            rec.flush()
            rates.append(steps / (time.perf_counter() - t0))
            rec.disconnect()
    med = statistics.median(rates)
    return med, (max(rates) - min(rates)) / med


def bag_throughput(steps: int) -> float:
    """Steps per second through bag_to_rrd for an offline-written bag of `steps` steps."""
    from prsm_sim import Simulator, preset

    from prsm_ros.mcap.offline import write_trajectory_mcap
    from prsm_ros.viz.from_bag import bag_to_rrd

    params = preset(PRESET)
    traj = Simulator(params, MODEL, 1e-3).run([_torque(k) for k in range(steps)], 2000.0)
    with tempfile.TemporaryDirectory() as d:
        bag = write_trajectory_mcap(Path(d) / "b.mcap", traj, params, MODEL, preset_name=PRESET, progress=False)
        t0 = time.perf_counter()
        summary = bag_to_rrd(bag, Path(d) / "b.rrd", progress=False)
        wall = time.perf_counter() - t0
    return summary["rows"] / wall


def measure(quick: bool = False) -> list[dict]:
    from prsm_ros.viz.sink import rerun_forced_off
    if rerun_forced_off():
        return [figure("Rerun live logging CPU at 1 kHz", math.nan, "% core", f"≤ {CPU_TARGET_PCT:g}", False, None,
                       "not measured: RERUN=off in the environment")]
    seconds = 1.0 if quick else 10.0
    repeats = 1 if quick else 3
    costs, runs = [], []
    with tempfile.TemporaryDirectory() as d:
        for r in range(repeats):  # off and save side by side, alternating
            base = loop_cost(seconds, "off", Path(d) / f"off{r}.rrd")
            live = loop_cost(seconds, "save", Path(d) / f"live{r}.rrd")
            costs.append((live["cpu_per_wall"] - base["cpu_per_wall"]) * 100)
            runs.append((base, live))
    mid = sorted(range(len(costs)), key=costs.__getitem__)[len(costs) // 2]
    cost = costs[mid]
    base, live = runs[mid]  # the notes describe the median run
    spread = (max(costs) - min(costs)) / abs(cost) if len(costs) > 1 and cost else None
    figs = [
        figure(f"Rerun live logging CPU at 1 kHz ({MODEL}, save mode)", cost, "% core", f"≤ {CPU_TARGET_PCT:g}",
               cost <= CPU_TARGET_PCT, spread,
               f"loop alone {base['cpu_per_wall'] * 100:.1f} % of a core, "
               f"with Rerun {live['cpu_per_wall'] * 100:.1f} %; "
               f"{live['rows']} rows, {live['frames']} scene frames in {live['batches']} batches "
               f"(scalars every {live['flush_period_s']:g} s, loads and scene every {live['loads_period_s']:g} s), "
               f"dropped {live['dropped']}, error {live['error']}"),
        figure("RerunSink.submit() per step (p99)", live["submit_p99_us"], "µs", "≤ 20", live["submit_p99_us"] <= 20,
               None, f"median {live['submit_p50_us']:.2f} µs: an append to a bounded deque, no Rerun call"),
        figure("1 kHz loop lateness p99 with Rerun", live["late_p99_ms"], "ms", "≤ 1", live["late_p99_ms"] <= 1.0,
               None, f"without Rerun p99 {base['late_p99_ms']:.3f} ms; p50 {live['late_p50_ms']:.3f} vs "
                     f"{base['late_p50_ms']:.3f} ms"),
    ]
    steps = 2000 if quick else 20_000
    rate, spread = batch_throughput(steps, 1 if quick else 3)
    figs.append(figure(f"Rerun batch send ({MODEL}: series + scene at 30 Hz)", rate, "steps/s", "≥ 10000",
                       rate >= 10_000, spread, f"{steps} steps per batch; the live sink needs 1000 steps/s"))
    try:
        conv = bag_throughput(1000 if quick else 10_000)
        figs.append(figure("bag_to_rrd conversion", conv, "steps/s", "≥ 1000", conv >= 1000, None,
                           f"{MODEL} bag from write_trajectory_mcap: MCAP decode + series + scene"))
    except ImportError as e:  # the MCAP/ROS extras are not installed
        figs.append(figure("bag_to_rrd conversion", math.nan, "steps/s", "≥ 1000", False, None, f"not measured: {e}"))
    return figs


def main(argv: list[str] | None = None) -> int:
    return area_main("rerun", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
