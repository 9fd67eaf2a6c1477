"""Node benchmark: realtime pacing and CPU, and lockstep round trips over DDS.

    python -m prsm_ros.bench.node [--quick]      # or: prsm-bench --only node

- Realtime at 1 kHz (60 s; quick: 3 s) with the fu2018 model (jones2016 when fu2018 is missing),
  recording to MCAP as a default run does. The node runs in this process, exactly as `prsm-node`
  builds it (PrsmNode + the executor its `executor` parameter names), so its own pacer gives every step's start time:
  long-run rate error = steps / (last start − first start) against update_rate; period jitter =
  p99 of |period − 1 ms| over consecutive step starts; CPU = CPU time / wall time of the process
  (all threads: step loop, executor, the recorder's forwarding thread) and its MCAP writer process.
- Lockstep round trips: `prsm-node` (lockstep, 1 step per command, recording) and the demo
  controller (`prsm_ros.cli.demo_controller`) as two processes over DDS; the controller answers each
  state with a command, so states received / wall time is command→state round trips per second;
  then the same with `-p executor:=single` (rclpy's Python executor in the node) as its peer, and
  with `rclpy_floor --lockstep` in the node's place (a bare rclpy node answering each command with
  a state) as its floor.
- Realtime demo loop (10 s; quick: 2 s, 500 N): the same two processes with the node in realtime,
  as `prsm-demo` runs them; the controller's RMS tracking error against the same law closed
  offline with no delay (`prsm_sim.control.run_position_loop`) plus 5 ms of reference travel.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from prsm_sim import MODELS

from prsm_ros.bench.common import area_main, cpu_with_children_s, figure
from prsm_ros.ros_env import isolated_env, ros_args, start_module


def bench_model() -> tuple[str, str]:
    """fu2018 when it exists, else jones2016 (and a note saying so)."""
    if "fu2018" in MODELS:
        return "fu2018", ""
    return "jones2016", "fu2018 not available: measured with jones2016"


def realtime_run(model: str, seconds: float, *, record: bool = True, preset: str = "s30",
                 executor: str = "events") -> dict:
    """Run PrsmNode in this process in realtime mode for `seconds` with the `executor` it names; return
    pacing and CPU figures."""
    import rclpy
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
                     Parameter("record_path", value=str(Path(tmp) / "bench.mcap")),
                     Parameter("executor", value=executor)]
        node = PrsmNode(context=ctx, parameter_overrides=overrides)
        spinner = node.make_executor()
        try:
            cpu0, wall0 = cpu_with_children_s(), time.perf_counter()
            end = wall0 + seconds
            while time.perf_counter() < end:
                spinner.spin_once(timeout_sec=0.1)
            cpu, wall = cpu_with_children_s() - cpu0, time.perf_counter() - wall0
            stats = node.pacer.stats
            late = np.array(stats.lateness_s)
            steps, overruns, skipped = stats.steps, stats.overruns, stats.skipped_periods
            period = node.pacer.period_s
            rec_dropped = node.recorder.messages_dropped if node.recorder else 0
            scheduling = dict(node.scheduling)
        finally:
            node.close()
            spinner.shutdown()
            node.destroy_node()
            rclpy.try_shutdown(context=ctx)
            os.sched_setscheduler(0, policy, sched_param)
            sys.setswitchinterval(switch)
    return {"steps": steps, **pacing_figures(late, period),
            "cpu_pct": 100 * cpu / wall, "overruns": overruns, "skipped": skipped, "record_dropped": rec_dropped,
            "scheduling": scheduling}


def pacing_figures(late: np.ndarray, period: float) -> dict:
    """Rate and jitter from a `DeadlinePacer`'s lateness ring: step k started at t0 + (k+1)·period + late[k];
    the first second's start-up transients are dropped."""
    skip = min(len(late) // 4, int(round(1.0 / period)))
    late = late[skip:]
    starts = (np.arange(len(late)) + 1) * period + late
    rate = (len(late) - 1) / (starts[-1] - starts[0])
    periods = np.diff(starts)
    return {"rate_hz": rate, "rate_error_pct": 100 * (rate * period - 1),
            "jitter_p99_us": 1e6 * float(np.percentile(np.abs(periods - period), 99)),
            "jitter_max_us": 1e6 * float(np.max(np.abs(periods - period))),
            "late_p99_us": 1e6 * float(np.percentile(late, 99))}


def pacing_floor(seconds: float, period_s: float = 1e-3) -> dict:
    """The floor under the node's period jitter: the node's pacing with nothing to do.

    A thread scheduled as the node's step thread (`realtime_priority`'s default SCHED_FIFO level when
    the OS allows, timer slack 1 ns, the node's GIL switch interval) waits on a `DeadlinePacer` at the
    node's default rate, `pacing_spin` 0, and does nothing else: the jitter the OS and this machine
    give a Python thread sleeping to absolute deadlines, measured as `realtime_run` measures the node's.
    """
    import threading

    from prsm_ros.node.pacing import DeadlinePacer, reduce_timer_slack, request_realtime_priority
    from prsm_ros.node.parameters import NODE_PARAMETERS
    from prsm_ros.node.ros_node import REALTIME_SWITCH_INTERVAL_S

    priority = next(p.default for p in NODE_PARAMETERS if p.name == "realtime_priority")
    result: dict = {}

    def loop() -> None:
        reduce_timer_slack()
        result["scheduling"] = request_realtime_priority(priority)  # this thread only; it ends with the run
        pacer = DeadlinePacer(period_s)
        for _ in range(int(round(seconds / period_s))):
            pacer.wait()
        result["late"] = np.array(pacer.stats.lateness_s)

    switch = sys.getswitchinterval()
    sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)
    try:
        thread = threading.Thread(target=loop, name="prsm-bench-pacing-floor")
        thread.start()
        thread.join()
    finally:
        sys.setswitchinterval(switch)
    return {**pacing_figures(result["late"], period_s), "scheduling": result["scheduling"]}


def demo_loop(model: str, sim_seconds: float, time_mode: str, *, record: bool = True, preset: str = "s30",
              load_n: float = 0.0, executor: str = "events", floor: bool = False) -> dict:
    """prsm-node and the demo controller as two processes, as `prsm-demo` runs them: the controller's
    summary (tracking error, states received, wall time), the node started paused until it listens.
    `floor`: `rclpy_floor --lockstep` stands in for the node (the lockstep round trip's floor)."""
    env = isolated_env(respect_user=False, RERUN="off")
    priority = 10 if time_mode == "realtime" else 0
    with tempfile.TemporaryDirectory(prefix="prsm_bench_node_") as tmp:
        params = {"model": model, "preset": preset, "time_mode": time_mode, "record": record,
                  "record_path": str(Path(tmp) / f"{time_mode}.mcap"), "cmd_timeout": 0.0, "load_force": load_n,
                  "start_paused": True, "realtime_priority": priority, "executor": executor}
        module, args = ("prsm_ros.bench.rclpy_floor", ["--lockstep"]) if floor else ("prsm_ros.cli.node",
                                                                                  ros_args(params))
        with open(Path(tmp) / "node.log", "wb") as log:
            node = start_module(module, args, env, stdout=log, stderr=subprocess.STDOUT)
            try:
                ctl = start_module("prsm_ros.cli.demo_controller",
                                   ["--duration", repr(sim_seconds), "--preset", preset, "--load", repr(load_n),
                                    "--realtime-priority", str(priority)], env, stdout=subprocess.PIPE)
                out, _ = ctl.communicate(timeout=120 + 10 * sim_seconds)
            finally:
                node.send_signal(2)
                node.wait(timeout=30)
    return json.loads(out.decode().strip().splitlines()[-1])


def lockstep_round_trips(model: str, sim_seconds: float, *, record: bool = True, preset: str = "s30",
                         executor: str = "events", floor: bool = False) -> dict:
    """prsm-node (lockstep, its callbacks on `executor`; `floor`: `rclpy_floor --lockstep` instead) and the
    demo controller as two processes: round trips per wall second."""
    summary = demo_loop(model, sim_seconds, "lockstep", record=record, preset=preset, executor=executor, floor=floor)
    return {"round_trips_per_s": summary["states_received"] / summary["wall_time_s"], **summary}


def realtime_tracking(model: str, sim_seconds: float, load_n: float = 500.0, preset: str = "s30") -> dict:
    """The demo's loop in realtime over DDS against the same law closed offline with no delay.

    Bound (as in tests/test_node_demo.py): the offline RMS plus what the reference travels in a
    5 ms loop delay, v_max·5 ms with v_max = π A f (2π·8 Hz·5 ms = 0.25 rad of phase at the loop's
    bandwidth)."""
    from prsm_sim import Simulator, preset as make_preset
    from prsm_sim.control import DEFAULT_AMPLITUDE_M, DEFAULT_FREQUENCY_HZ, PositionController, run_position_loop
    from prsm_sim.models.ideal import reflected_inertia

    params = make_preset(preset)
    ctl = PositionController(reflected_inertia(params), params.geometry.lead_per_rad_m, load_n=load_n)
    _, offline = run_position_loop(Simulator(params, model, 1e-3), ctl, sim_seconds, load_n)
    summary = demo_loop(model, sim_seconds, "realtime", preset=preset, load_n=load_n)
    bound_m = offline.rms_m + math.pi * DEFAULT_AMPLITUDE_M * DEFAULT_FREQUENCY_HZ * 5e-3
    return {"offline_rms_m": offline.rms_m, "bound_m": bound_m, **summary}


def measure(quick: bool = False) -> list[dict]:
    model, note = bench_model()
    seconds = 3.0 if quick else 60.0
    rt = realtime_run(model, seconds)
    pace = pacing_floor(min(seconds, 10.0))  # the jitter's floor, right after the node (same machine state)
    ls = lockstep_round_trips(model, 1.0 if quick else 10.0)
    # the peer: the same loop with rclpy's Python executor in the node, right after (same machine)
    ls_single = lockstep_round_trips(model, 1.0 if quick else 10.0, executor="single")
    # the floor: a bare rclpy node answering each command with a state, the same controller, right after
    ls_floor = lockstep_round_trips(model, 1.0 if quick else 10.0, floor=True)
    tr = realtime_tracking(model, 2.0 if quick else 10.0)
    base = f"{model}, s30, recording on, {seconds:g} s" + (f"; {note}" if note else "")
    return [
        figure("node realtime 1 kHz long-run rate error", abs(rt["rate_error_pct"]), "%", "< 0.1",
               abs(rt["rate_error_pct"]) < 0.1, None, f"{base}; {rt['rate_hz']:.3f} Hz over {rt['steps']} steps"),
        figure("node realtime period jitter p99", rt["jitter_p99_us"], "µs", "≤ 100", rt["jitter_p99_us"] <= 100, None,
               f"max {rt['jitter_max_us']:.0f} µs; start lateness p99 {rt['late_p99_us']:.0f} µs; "
               f"overruns {rt['overruns']}, skipped periods {rt['skipped']}; step thread "
               f"{rt['scheduling']['step_thread']}, others {rt['scheduling']['other_threads']}; "
               f"{rt['jitter_p99_us'] / pace['jitter_p99_us']:.2f}× the pacing floor of this run"),
        figure("pacing floor: period jitter p99 of a bare paced thread", pace["jitter_p99_us"], "µs", "(peer)", None,
               None, f"the node's pacing (DeadlinePacer at 1 kHz, pacing_spin 0, {pace['scheduling']}, timer slack "
                     f"1 ns) with nothing to do, in this process right after the node; max {pace['jitter_max_us']:.0f} µs"),
        figure("node realtime CPU share of one core", rt["cpu_pct"], "%", "≤ 30", rt["cpu_pct"] <= 30, None,
               f"all threads of the node process (step loop, executor, recorder) and its MCAP writer process; "
               f"dropped records {rt['record_dropped']}"),
        figure("node lockstep command→state round trips", ls["round_trips_per_s"], "1/s", "≥ 2000",
               ls["round_trips_per_s"] >= 2000, None,
               f"{model}, 1 step per command, recording on, rclpy's EventsExecutor in the node; rclpy "
               f"controller process over DDS; {ls['states_received']} round trips in {ls['wall_time_s']:.2f} s; "
               f"{ls['round_trips_per_s'] / ls_single['round_trips_per_s']:.2f}× the node on rclpy's Python "
               f"SingleThreadedExecutor in the same run ({ls_single['round_trips_per_s']:.0f}/s); "
               f"{ls['round_trips_per_s'] / ls_floor['round_trips_per_s']:.2f}× the rclpy floor of the same run "
               f"(python -m prsm_ros.bench.rclpy_floor --lockstep: {ls_floor['round_trips_per_s']:.0f}/s); "
               f"load average {os.getloadavg()[0]:.1f}"),
        figure("node realtime demo loop: RMS tracking error", tr["rms_error_m"] * 1e3, "mm",
               f"≤ {tr['bound_m'] * 1e3:.3f}", tr["completed"] and tr["rms_error_m"] <= tr["bound_m"], None,
               f"{model}, s30, 500 N, {tr['sim_time_s']:.1f} s; same law offline with no delay "
               f"{tr['offline_rms_m'] * 1e3:.3f} mm (bound: that + 5 ms of reference travel); "
               f"{tr['states_received']} states received; controller {tr['scheduling']}"),
    ]


def main(argv: list[str] | None = None) -> int:
    return area_main("node", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
