"""Node benchmark (issue 4 item 7): realtime pacing and CPU, and lockstep round trips over DDS.

    python -m prsm_ros.bench.node [--quick]      # or: prsm-bench --only node

- Realtime at 1 kHz (60 s; quick: 3 s) with the fu2018 model (jones2016 when fu2018 is missing),
  recording to MCAP as a default run does. The node runs in this process, exactly as `prsm-node`
  builds it (PrsmNode + a single-threaded executor), so its own pacer gives every step's start time:
  long-run rate error = steps / (last start − first start) against update_rate; period jitter =
  p99 of |period − 1 ms| over consecutive step starts; CPU = process CPU time / wall time (all
  threads: step loop, executor, recorder).
- Lockstep round trips: `prsm-node` (lockstep, 1 step per command, recording) and the demo
  controller (`prsm_ros.cli.demo_controller`) as two processes over DDS; the controller answers each
  state with a command, so states received / wall time is command→state round trips per second.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from prsm_sim import MODELS

from prsm_ros.bench.common import area_main, figure
from prsm_ros.ros_env import isolated_env, ros_args, start_module


def bench_model() -> tuple[str, str]:
    """fu2018 when it exists, else jones2016 (and a note saying so)."""
    if "fu2018" in MODELS:
        return "fu2018", ""
    return "jones2016", "fu2018 not available: measured with jones2016"


def realtime_run(model: str, seconds: float, *, record: bool = True, preset: str = "s30") -> dict:
    """Run PrsmNode in this process in realtime mode for `seconds`; return pacing and CPU figures."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from prsm_ros.node.ros_node import PrsmNode

    env = isolated_env(respect_user=False)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    # the node raises this thread to SCHED_FIFO and shortens the GIL switch interval: undo after
    policy, sched_param, switch = os.sched_getscheduler(0), os.sched_getparam(0), sys.getswitchinterval()
    with tempfile.TemporaryDirectory(prefix="prsm_bench_node_") as tmp:
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=int(env["ROS_DOMAIN_ID"]),
                   signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        overrides = [Parameter("model", value=model), Parameter("preset", value=preset),
                     Parameter("time_mode", value="realtime"), Parameter("record", value=record),
                     Parameter("record_path", value=str(Path(tmp) / "bench.mcap"))]
        node = PrsmNode(context=ctx, parameter_overrides=overrides)
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        try:
            cpu0, wall0 = time.process_time(), time.perf_counter()
            end = wall0 + seconds
            while time.perf_counter() < end:
                executor.spin_once(timeout_sec=0.1)
            cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
            stats = node.pacer.stats
            late = np.array(stats.lateness_s)
            steps, overruns, skipped = stats.steps, stats.overruns, stats.skipped_periods
            period = node.pacer.period_s
            rec_dropped = node.recorder.messages_dropped if node.recorder else 0
            scheduling = dict(node.scheduling)
        finally:
            node.close()
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)
            os.sched_setscheduler(0, policy, sched_param)
            sys.setswitchinterval(switch)
    # step k started at t0 + (k+1)·period + late[k]; drop the first second's start-up transients
    skip = min(len(late) // 4, int(round(1.0 / period)))
    late = late[skip:]
    starts = (np.arange(len(late)) + 1) * period + late
    rate = (len(late) - 1) / (starts[-1] - starts[0])
    periods = np.diff(starts)
    return {"steps": steps, "rate_hz": rate, "rate_error_pct": 100 * (rate * period - 1),
            "jitter_p99_us": 1e6 * float(np.percentile(np.abs(periods - period), 99)),
            "jitter_max_us": 1e6 * float(np.max(np.abs(periods - period))),
            "late_p99_us": 1e6 * float(np.percentile(late, 99)),
            "cpu_pct": 100 * cpu / wall, "overruns": overruns, "skipped": skipped, "record_dropped": rec_dropped,
            "scheduling": scheduling}


def lockstep_round_trips(model: str, sim_seconds: float, *, record: bool = True, preset: str = "s30") -> dict:
    """prsm-node (lockstep) and the demo controller as two processes: round trips per wall second."""
    env = isolated_env(respect_user=False, RERUN="off")
    with tempfile.TemporaryDirectory(prefix="prsm_bench_node_") as tmp:
        params = {"model": model, "preset": preset, "time_mode": "lockstep", "record": record,
                  "record_path": str(Path(tmp) / "lockstep.mcap"), "cmd_timeout": 0.0}
        with open(Path(tmp) / "node.log", "wb") as log:
            node = start_module("prsm_ros.node.ros_node", ros_args(params), env, stdout=log, stderr=subprocess.STDOUT)
            try:
                ctl = start_module("prsm_ros.cli.demo_controller", ["--duration", repr(sim_seconds), "--preset", preset],
                                   env, stdout=subprocess.PIPE)
                out, _ = ctl.communicate(timeout=120 + 10 * sim_seconds)
            finally:
                node.send_signal(2)
                node.wait(timeout=30)
    summary = json.loads(out.decode().strip().splitlines()[-1])
    return {"round_trips_per_s": summary["states_received"] / summary["wall_time_s"], **summary}


def measure(quick: bool = False) -> list[dict]:
    model, note = bench_model()
    seconds = 3.0 if quick else 60.0
    rt = realtime_run(model, seconds)
    ls = lockstep_round_trips(model, 1.0 if quick else 10.0)
    base = f"{model}, s30, recording on, {seconds:g} s" + (f"; {note}" if note else "")
    return [
        figure("node realtime 1 kHz long-run rate error", abs(rt["rate_error_pct"]), "%", "< 0.1",
               abs(rt["rate_error_pct"]) < 0.1, None, f"{base}; {rt['rate_hz']:.3f} Hz over {rt['steps']} steps"),
        figure("node realtime period jitter p99", rt["jitter_p99_us"], "µs", "≤ 100", rt["jitter_p99_us"] <= 100, None,
               f"max {rt['jitter_max_us']:.0f} µs; start lateness p99 {rt['late_p99_us']:.0f} µs; "
               f"overruns {rt['overruns']}, skipped periods {rt['skipped']}; step thread "
               f"{rt['scheduling']['step_thread']}, others {rt['scheduling']['other_threads']}"),
        figure("node realtime CPU share of one core", rt["cpu_pct"], "%", "≤ 30", rt["cpu_pct"] <= 30, None,
               f"all threads of the node process (step loop, executor, recorder); dropped records {rt['record_dropped']}"),
        figure("node lockstep command→state round trips", ls["round_trips_per_s"], "1/s", "≥ 2000",
               ls["round_trips_per_s"] >= 2000, None,
               f"{model}, 1 step per command, recording on; rclpy controller process over DDS; "
               f"{ls['states_received']} round trips in {ls['wall_time_s']:.2f} s"),
    ]


def main(argv: list[str] | None = None) -> int:
    return area_main("node", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
