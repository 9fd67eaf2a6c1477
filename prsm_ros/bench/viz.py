"""Benchmarks of the Rerun output: its cost beside a 1 kHz step loop, and how fast batches and bags convert.

- CPU at 1 kHz: a loop paced on absolute 1 ms deadlines steps the simulator (fu2018, s30, a
  sinusoidal torque) and hands every step to a `RerunSink` in save mode, against the same loop
  with the sink off; the difference in process CPU time (all threads) per wall second is the cost
  of live logging, in % of one core (target ≤ 5 %) with the sink's defaults (scalar outputs
  every 0.2 s; internal loads sampled at 120 Hz and the scene at 30 Hz of simulation time, every
  1 s). The same runs give the cost of one `submit()` call (what the step loop itself pays) and
  the loop's lateness percentiles. The loop is scheduled as the node's realtime mode schedules its
  step thread: SCHED_FIFO where the OS allows, the sink's threads one level below, and the
  interpreter lock handed over after 100 µs (`sys.setswitchinterval`), since the sink runs there.
- the floor, in the same runs: the same loop beside a thread that sends the same data at the same
  periods through the same `RecordingWriter`, its columns computed beforehand by a batch run
  (`Simulator.run`): Rerun's own cost for the data, and the numpy that shapes it, without the
  per-step records; the sink's added CPU is also given as a ratio to it.
- batch throughput: steps per second through `RecordingWriter.send` (series of every step plus the
  scene at 30 Hz) — the background thread's headroom over the 1000 steps/s it must keep up with.
- bag conversion: simulated steps per second through `bag_to_rrd` for a bag written by
  `offline_record.write_trajectory_mcap`.

Figures are printed, never asserted (`prsm-bench --only rerun` aggregates them).
"""

from __future__ import annotations

import contextlib
import math
import os
import statistics
import sys
import tempfile
import threading
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


STEP_PRIORITY = 10  # SCHED_FIFO priority of the loop, as the node's `realtime_priority` default
SWITCH_INTERVAL_S = 1e-4  # the node's interpreter-lock hand-over in realtime mode


@contextlib.contextmanager
def node_scheduling():
    """The node's realtime scheduling for the calling thread (module docstring), undone on exit.

    Yields a function that raises the calling thread to the step thread's priority; threads
    started before it is called (the sink's) keep the level below. Yields what was applied, in words.
    """
    from prsm_ros.node.pacing import request_realtime_priority

    old_interval = sys.getswitchinterval()
    old_policy, old_param = os.sched_getscheduler(0), os.sched_getparam(0)
    applied = request_realtime_priority(STEP_PRIORITY - 1)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    try:
        yield applied, lambda: request_realtime_priority(STEP_PRIORITY)
    finally:
        sys.setswitchinterval(old_interval)
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, old_policy, old_param)


def loop_cost(seconds: float, sink_mode: str, path: Path, **sink_options) -> dict:
    """One paced 1 kHz run (`common.paced_loop`): CPU per wall second, submit() cost, lateness."""
    from prsm_sim import Simulator, preset

    from prsm_ros.viz.sink import RerunSink

    params = preset(PRESET)
    sim = Simulator(params, MODEL, 1e-3)
    steps = int(seconds * 1000)
    submit_ns = np.empty(steps)
    with node_scheduling() as (applied, raise_loop):
        sink = RerunSink(sink_mode, str(path), params, sim.layout, MODEL, **sink_options)
        raise_loop()

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
            "loads_period_s": sink.loads_period_s, "loads_rate_hz": sink.loads_rate_hz, "scheduling": applied}


def floor_cost(seconds: float, path: Path) -> dict:
    """The same paced loop beside Rerun sending the same data from ready columns (module docstring).

    A thread wakes at the sink's periods and sends, through a `RecordingWriter` with the sink's
    settings, the steps the loop has made since: their scalar outputs every `flush_period_s`, the
    internal loads of the sampled steps and the scene every `loads_period_s`; the columns and the
    internal vectors come from one batch run of the same inputs made before the clock starts.
    """
    import rerun as rr

    from prsm_sim import Simulator, preset

    from prsm_ros.viz.sink import (APPLICATION_ID, FLUSH_PERIOD_S, LOADS_PERIOD_S, LOADS_RATE_HZ, SCENE_RATE_HZ,
                                   YIELD_S, RecordingWriter, loads_sample_rows)

    params = preset(PRESET)
    steps = int(seconds * 1000)
    traj = Simulator(params, MODEL, 1e-3).run([_torque(k) for k in range(steps)], 2000.0)
    columns, internal = traj.columns, traj.internal
    loads_idx, _ = loads_sample_rows(columns["time_s"], LOADS_RATE_HZ, SCENE_RATE_HZ, (-1, -1))
    sim = Simulator(params, MODEL, 1e-3)
    done = [0]  # steps the loop has made (written by the loop only)
    stop = threading.Event()
    with node_scheduling() as (applied, raise_loop):
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
        rec.save(path)
        writer = RecordingWriter(rec, params, traj.layout, MODEL, yield_s=YIELD_S)
        writer.send_blueprint()
        writer.log_static()

        def sender() -> None:
            sent = loads_sent = 0
            loads_due = time.perf_counter() + LOADS_PERIOD_S
            while not stop.wait(FLUSH_PERIOD_S):
                k = done[0]
                writer.send({name: c[sent:k] for name, c in columns.items()}, None, loads=False)
                sent = k
                if time.perf_counter() >= loads_due:
                    loads_due += LOADS_PERIOD_S
                    idx = loads_idx[(loads_idx >= loads_sent) & (loads_idx < k)]
                    writer.send({name: c[idx] for name, c in columns.items()}, internal[idx], scalars=False)
                    loads_sent = k

        thread = threading.Thread(target=sender, name="prsm-rerun-floor", daemon=True)
        thread.start()
        raise_loop()

        def work(k: int) -> None:
            sim.step(_torque(k), 2000.0)
            done[0] = k + 1

        loop = paced_loop(steps, work)
        stop.set()
        thread.join()
        rec.flush()
        rec.disconnect()
    return {**loop, "rows": writer.rows, "frames": writer.scene_frames, "scheduling": applied}


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
    runs = []
    with tempfile.TemporaryDirectory() as d:
        for r in range(repeats):  # the loop alone, with the sink and beside the floor in turn
            base = loop_cost(seconds, "off", Path(d) / f"off{r}.rrd")
            live = loop_cost(seconds, "save", Path(d) / f"live{r}.rrd")
            floor = floor_cost(seconds, Path(d) / f"floor{r}.rrd")
            runs.append((base, live, floor))
    return _live_figures(runs) + _batch_figures(quick)


def _live_figures(runs: list[tuple[dict, dict, dict]]) -> list[dict]:
    """The live sink's figures from (loop alone, with the sink, beside the floor) triples, the median's notes."""
    costs = [(live["cpu_per_wall"] - base["cpu_per_wall"]) * 100 for base, live, _ in runs]
    floors = [(floor["cpu_per_wall"] - base["cpu_per_wall"]) * 100 for base, _, floor in runs]
    mid = sorted(range(len(costs)), key=costs.__getitem__)[len(costs) // 2]
    cost, floor_pct = costs[mid], statistics.median(floors)
    base, live, floor = runs[mid]  # the notes describe the median run
    spread = (max(costs) - min(costs)) / abs(cost) if len(costs) > 1 and cost else None
    ratio = cost / floor_pct if floor_pct > 0 else math.nan
    return [
        figure(f"Rerun live logging CPU at 1 kHz ({MODEL}, save mode)", cost, "% core", f"≤ {CPU_TARGET_PCT:g}",
               cost <= CPU_TARGET_PCT, spread,
               f"loop alone {base['cpu_per_wall'] * 100:.1f} % of a core, "
               f"with Rerun {live['cpu_per_wall'] * 100:.1f} %; floor (the same data sent from ready columns, "
               f"same runs) {floor_pct:.1f} % (each run: {', '.join(f'{f:.1f}' for f in floors)}), ratio "
               f"{ratio:.2f}; {live['rows']} rows, {live['frames']} scene frames in {live['batches']} batches "
               f"(scalars every {live['flush_period_s']:g} s, loads at {live['loads_rate_hz']} Hz and scene every "
               f"{live['loads_period_s']:g} s), dropped {live['dropped']}, error {live['error']}; "
               f"scheduling {live['scheduling']}"),
        figure("Rerun live logging CPU over its floor", ratio, "×", "(info)", None, None,
               "the sink's added CPU over Rerun's own cost for the same data sent from ready columns, "
               "median runs of the same turns"),
        figure("RerunSink.submit() per step (p99)", live["submit_p99_us"], "µs", "≤ 20", live["submit_p99_us"] <= 20,
               None, f"median {live['submit_p50_us']:.2f} µs: an append to a bounded deque, no Rerun call"),
        figure("1 kHz loop lateness p99 with Rerun", live["late_p99_ms"], "ms", "≤ 1", live["late_p99_ms"] <= 1.0,
               None, f"without Rerun p99 {base['late_p99_ms']:.3f} ms, beside the floor {floor['late_p99_ms']:.3f} "
                     f"ms; p50 {live['late_p50_ms']:.3f} vs {base['late_p50_ms']:.3f} ms"),
    ]


def _batch_figures(quick: bool) -> list[dict]:
    """Batch send and bag conversion throughput."""
    figs = []
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
