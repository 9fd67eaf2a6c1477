"""The reference controller of `prsm-bench --only realtime`: an independent rclpy client at 1 kHz.

    python -m prsm_ros.bench.rt_controller --duration 10 [--rate 1000] [--node /prsm_actuator]

A pacing thread publishes a distinct screw torque (`std_msgs/Float64`) every period on absolute
deadlines, at normal priority; the executor thread receives `joint_states` over a reliable
keep-last reader of depth `--depth` and, when the node offers it, `~/command_echo`. At the end
it prints one JSON line with what it saw:

- `latency_value_ms`: wall time from publishing a torque to receiving the first `joint_states`
  whose screw effort equals it exactly (the node echoes the applied torque in `effort[0]`), so
  this figure needs nothing from the node but its states;
- `latency_echo_ms`: the command's own DDS source timestamp, echoed back by the node on
  `~/command_echo` (sensor_msgs/TimeReference: `time_ref` = the command's stamp, `header.stamp` =
  the simulation time of the step that first applied it), to the receipt of the `joint_states`
  of that step (system clock on both ends: one machine);
- `states_received` / `states_expected`: distinct `joint_states` stamps received, and the
  number of steps between the first and the last one;
- `rate_hz`: simulated seconds (stamps) per wall second of receipt over the run, times the
  update rate: the node's long-run rate as a reader sees it.

Tiny torques around zero (≤ 1 mN·m) keep the actuator near rest for any model.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time

import numpy as np

# The controller reads the fields it needs straight from the CDR bytes (raw subscriptions): building a
# Python message object per sample costs more than the rest of the callback, and at 2,000 samples/s
# on a busy machine a reference controller must not be what limits the loop.
from prsm_ros.cdr_read import joint_state_stamp_effort0, time_reference_stamps

WARMUP_TIMEOUT_S = 60.0  # a loaded machine can take long to discover the node


def _percentiles(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p99": None, "max": None, "n": 0}
    a = np.asarray(values)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)), "max": float(a.max()),
            "n": int(a.size)}


class _Probe:
    """What the controller saw: torques sent, states and echoes received, with their times (thread-safe)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.sent: dict[float, float] = {}  # torque → perf_counter at publish (pruned as the run goes)
        self.state_wall_ns: dict[int, int] = {}  # joint_states stamp (ns) → time.time_ns() at receipt
        self.echo_ref_ns: dict[int, int] = {}  # step stamp (ns) → the command stamp the node echoed for it
        self.lat_value: list[float] = []
        self.stamps: list[int] = []
        self.walls: list[float] = []
        self.first_state = threading.Event()
        self.measuring = threading.Event()
        self.stop = threading.Event()
        self.published = 0

    def on_state(self, raw: bytes) -> None:
        now_pc, now_ns = time.perf_counter(), time.time_ns()
        self.first_state.set()
        if not self.measuring.is_set():
            return
        st, effort0 = joint_state_stamp_effort0(raw)
        with self.lock:
            self.stamps.append(st)
            self.walls.append(now_pc)
            self.state_wall_ns[st] = now_ns
            if effort0 is not None:
                t_sent = self.sent.pop(effort0, None)
                if t_sent is not None:
                    self.lat_value.append(now_pc - t_sent)

    def on_echo(self, raw: bytes) -> None:
        st, ref = time_reference_stamps(raw)
        with self.lock:
            self.echo_ref_ns.setdefault(st, ref)

    def pace(self, publish, rate_hz: float) -> None:
        """Publish a distinct torque every period on absolute deadlines until `stop` (the pacing thread)."""
        from prsm_ros.node.pacing import DeadlinePacer, reduce_timer_slack
        reduce_timer_slack()  # precise sleeps; the thread stays at normal priority
        pacer = DeadlinePacer(1.0 / rate_hz, spin_s=0.0)
        k = 0
        while not self.stop.is_set():
            pacer.wait()
            k += 1
            # distinct values (k is unique within the prune window), all below 1 mN·m
            torque = 1e-3 * ((k % 20011) / 20011.0 - 0.5)
            with self.lock:
                self.sent[torque] = time.perf_counter()
                if len(self.sent) > 20000:  # a command never reflected (overwritten in the node's queue)
                    for old in list(self.sent)[:10000]:
                        del self.sent[old]
            publish(torque)
            self.published += 1

    def summary(self, n_pub: int) -> dict:
        """The JSON line's figures (see the module doc)."""
        with self.lock:
            stamps, walls = self.stamps, self.walls
            uniq = sorted(set(stamps))
            lat_echo = [(self.state_wall_ns[st] - ref) * 1e-9 for st, ref in self.echo_ref_ns.items()
                        if st in self.state_wall_ns]
            period_ns = int(np.median(np.diff(uniq))) if len(uniq) > 1 else None
            expected = (uniq[-1] - uniq[0]) // period_ns + 1 if period_ns else len(uniq)
            rate = None
            if len(stamps) > 1 and period_ns:
                # least-squares slope of stamp (s) against receipt wall time (s): simulated s per wall s
                slope = float(np.polyfit(np.asarray(walls) - walls[0], (np.asarray(stamps) - stamps[0]) * 1e-9, 1)[0])
                rate = slope * 1e9 / period_ns
            lat_value = list(self.lat_value)
        ms = lambda p: {k: (v * 1e3 if isinstance(v, float) else v) for k, v in p.items()}  # noqa: E731
        return {
            "commands_published": n_pub,
            "states_received": len(uniq), "states_expected": int(expected), "duplicates": len(stamps) - len(uniq),
            "period_s": period_ns * 1e-9 if period_ns else None, "rate_hz": rate,
            "latency_value_ms": ms(_percentiles(lat_value)), "latency_echo_ms": ms(_percentiles(lat_echo)),
            "echo_seen": bool(self.echo_ref_ns),
        }


def _cpu_set(text: str) -> frozenset[int]:
    """--cpus: CPU numbers separated by commas."""
    try:
        cpus = frozenset(int(t) for t in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected CPU numbers separated by commas, e.g. 0,2") from None
    if not cpus or min(cpus) < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected CPU numbers >= 0")
    return cpus


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="rt_controller", description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="measured wall seconds (after the first state)")
    ap.add_argument("--rate", type=float, default=1000.0, help="command rate, Hz")
    ap.add_argument("--node", default="/prsm_actuator", help="the node's full name")
    ap.add_argument("--joint-states", default="/joint_states", help="the node's joint_states topic")
    ap.add_argument("--depth", type=int, default=1000, help="keep-last depth of the reliable state reader")
    ap.add_argument("--cpus", type=_cpu_set, metavar="N[,N...]",
                    help="run on these CPUs only (a deployment keeps its controller off the node's step thread CPU)")
    a = ap.parse_args(argv)
    if a.cpus:  # before rclpy starts the middleware's threads, which then inherit it
        from prsm_ros.node.scheduling import pin_calling_thread
        applied = pin_calling_thread(a.cpus)
        if os.sched_getaffinity(0) != a.cpus:
            ap.error(f"--cpus {','.join(map(str, sorted(a.cpus)))}: {applied}")

    import rclpy
    try:  # rclpy's C++ events executor: a small fraction of the per-callback cost of the Python one
        from rclpy.experimental import EventsExecutor as Executor
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor as Executor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState, TimeReference
    from std_msgs.msg import Float64

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("prsm_rt_controller")
    reliable = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=a.depth, reliability=ReliabilityPolicy.RELIABLE)
    pub = node.create_publisher(Float64, f"{a.node}/screw_torque",
                                QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                           reliability=ReliabilityPolicy.RELIABLE))
    probe = _Probe()
    node.create_subscription(JointState, a.joint_states, probe.on_state, reliable, raw=True)
    node.create_subscription(TimeReference, f"{a.node}/command_echo", probe.on_echo, reliable, raw=True)
    executor = Executor()
    executor.add_node(node)

    pacer_thread = threading.Thread(target=probe.pace, args=(lambda t: pub.publish(Float64(data=t)), a.rate),
                                    name="controller-pacer", daemon=True)
    deadline = time.monotonic() + WARMUP_TIMEOUT_S
    pacer_thread.start()
    while not probe.first_state.is_set() and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.1)
    if not probe.first_state.is_set():
        print(json.dumps({"error": f"no joint_states on {a.joint_states} within {WARMUP_TIMEOUT_S:g} s"}))
        return 1
    warm_end = time.monotonic() + 1.0  # let discovery of the echo topic and the queues settle
    while time.monotonic() < warm_end:
        executor.spin_once(timeout_sec=0.01)
    with probe.lock:
        probe.sent.clear()
    probe.measuring.set()
    print("measuring", flush=True)  # the bench samples the node's CPU from here to the summary
    pub0 = probe.published
    end = time.monotonic() + a.duration
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.01)
    probe.measuring.clear()
    print("measured", flush=True)
    probe.stop.set()
    pacer_thread.join(timeout=5.0)
    summary = probe.summary(probe.published - pub0)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    print(json.dumps(summary))
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
