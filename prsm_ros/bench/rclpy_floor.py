"""The floor under the node's CPU figure: a bare rclpy loop with the node's realtime DDS traffic and nothing else.

    python -m prsm_ros.bench.rclpy_floor [--rate 1000] [--record [--record-to FILE]] [--step-thread-cpu N]
                                                     # `prsm-bench --only realtime`

It stands where `prsm-node` stands for the reference controller (`prsm_ros.bench.rt_controller`):
node name `prsm_actuator`, paced by the node's `DeadlinePacer` at 1 kHz, it takes the commands
waiting on `~/screw_torque` (the node's poll: `command_poll`) and each period publishes
`joint_states` (reliable, keep-last 100, the last torque in `effort[0]`, encoded by the node's
`StepEncoder`) and, after a command, its echo on `~/command_echo` with the command's DDS stamp.
No model, no gate, no recording, no other topic: what it costs is what rclpy and the middleware
cost for the traffic a controller needs, the least a Python node with this interface can use.
The bench measures it in the same run as the node, so the two figures can be compared.

`--lockstep` is the floor under the lockstep round trip instead (`prsm-bench --only node`): the
demo controller's peer as `prsm-node -p time_mode:=lockstep` is, with rclpy's events executor.
It answers `~/pause` (the controller resumes the node before its first command) and every
command on `~/screw_torque` with one `joint_states` (the next step's stamp, the torque in
`effort[0]`), and takes the controller's `~/nut_position_reference` without reading it: the
round trips a Python node can give that controller with no model, no gate and no recording.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from pathlib import Path
from types import SimpleNamespace


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m prsm_ros.bench.rclpy_floor", description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=1000.0, help="loop rate in Hz (the node's default update rate)")
    ap.add_argument("--lockstep", action="store_true",
                    help="answer each command with a state at once (the lockstep round trip's floor)")
    ap.add_argument("--record", action="store_true",
                    help="also write the node's recorded messages with foxglove-sdk's native MCAP writer")
    ap.add_argument("--record-to", type=Path, metavar="FILE",
                    help="with --record: the MCAP file to write (default: one in a temporary directory)")
    ap.add_argument("--step-thread-cpu", type=int, default=-1, metavar="N",
                    help="run the loop on CPU N and every other thread off it, as prsm-node's step_thread_cpu does")
    a = ap.parse_args(argv)
    if a.step_thread_cpu >= 0:
        from prsm_ros.node.scheduling import allowed_cpus
        if a.step_thread_cpu not in allowed_cpus() or len(allowed_cpus()) < 2:
            ap.error(f"--step-thread-cpu {a.step_thread_cpu}: must be one of the CPUs this process may run on "
                     f"({', '.join(map(str, sorted(allowed_cpus())))}), with another left for the other threads")
    if a.lockstep:
        return lockstep_floor()
    if a.record:
        with native_recording(a.record_to) as log:
            return realtime_floor(a.rate, log, a.step_thread_cpu)
    return realtime_floor(a.rate, None, a.step_thread_cpu)


def realtime_floor(rate_hz: float, log, step_thread_cpu: int = -1) -> int:
    """The paced loop (module doc); `log(k, stamp_ns, command, state, echo)` writes period k's messages (or None);
    `step_thread_cpu` >= 0: the loop on that CPU and every other thread off it (`prsm_ros.node.scheduling`)."""
    import rclpy
    from sensor_msgs.msg import JointState, TimeReference
    from std_msgs.msg import Float64

    from prsm_ros.cdr_read import float64_data
    from prsm_ros.interface import TOPIC_DEFS
    from prsm_ros.messages import NODE_NAME, TOPICS, MessageMapper
    from prsm_ros.node.command_echo import stamp_of
    from prsm_ros.node.command_poll import CommandPoller
    from prsm_ros.node.pacing import DeadlinePacer, reduce_timer_slack
    from prsm_sim import Simulator, preset

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node(NODE_NAME)
    js = node.create_publisher(JointState, TOPIC_DEFS["joint_states"].name, TOPICS["joint_states"].qos)
    echo = node.create_publisher(TimeReference, TOPIC_DEFS["command_echo"].name, TOPICS["command_echo"].qos)
    sub = node.create_subscription(Float64, TOPIC_DEFS["screw_torque"].name, lambda *_: None,
                                   TOPICS["screw_torque"].qos, raw=True)
    encoder = MessageMapper(Simulator(preset("s30"), "ideal", 1e-3).layout, "ideal").encoder()
    source = sub.topic_name
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())

    reduce_timer_slack()
    if step_thread_cpu >= 0:  # every thread exists now (the middleware's, the native writer's)
        from prsm_ros.node.scheduling import move_process_threads, other_cpus, pin_calling_thread
        moved = move_process_threads(other_cpus(step_thread_cpu), keep=frozenset({threading.get_native_id()}))
        pinned = pin_calling_thread({step_thread_cpu})
        if os.sched_getaffinity(0) != {step_thread_cpu} or moved.startswith("any CPU"):
            # never a floor labelled pinned that is not: the bench would set it beside a pinned node
            raise SystemExit(f"--step-thread-cpu {step_thread_cpu}: the loop {pinned}, the other threads {moved}")
    period_s = 1.0 / rate_hz
    pacer = DeadlinePacer(period_s)
    state = SimpleNamespace(screw_angle_rad=0.0, nut_position_m=0.0, screw_speed_rad_s=0.0, nut_velocity_m_s=0.0,
                            screw_torque_nm=0.0, nut_force_n=0.0)
    command = SimpleNamespace(ns=None, data=None)  # the DDS stamp and bytes of the last command taken this period

    def on_command(_key: str, data: bytes, info: dict) -> None:
        state.screw_torque_nm = float64_data(data)
        command.ns = stamp_of(None, info.get("source_timestamp"))
        command.data = data
    poller = CommandPoller()
    poller.add("screw_torque", sub, on_command)
    k = 0
    js_handle, echo_handle = js.handle, echo.handle
    while not stop.is_set():
        pacer.wait()
        k += 1
        stamp_ns = round(k * period_s * 1e9)
        command.ns = command.data = None
        poller.poll()
        js_data = encoder.joint_state(state, stamp_ns)
        with js_handle:
            js_handle.publish_raw(js_data)
        echo_data = None
        if command.ns is not None:
            echo_data = encoder.time_reference(stamp_ns, command.ns, source)
            with echo_handle:
                echo_handle.publish_raw(echo_data)
        if log is not None:
            log(k, stamp_ns, command.data, js_data, echo_data)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


@contextlib.contextmanager
def native_recording(path: Path | None = None):
    """`realtime_floor`'s `log` for `--record` (module doc), its file at `path` or in a temporary directory."""
    from prsm_ros.bench.recorder import foxglove_writing, prepared_steps
    from prsm_ros.interface import STEP_TOPICS
    from prsm_ros.mcap.recorder import FLUSH_INTERVAL_S

    steps = prepared_steps("jones2016", 1000)  # [command, *STEP_TOPICS] per step
    at = {key: 1 + STEP_TOPICS.index(key) for key in ("wrench", "internal_loads", "clock")}
    flush_every = max(int(round(FLUSH_INTERVAL_S * 1000)), 1)
    with foxglove_writing(echo=True, path=path) as opened:
        if opened is None:
            raise SystemExit("--record needs foxglove-sdk (pip install -e '.[bag]')")
        writer, channels = opened
        by_topic = dict(zip(("screw_torque", *STEP_TOPICS, "command_echo"), channels, strict=True))
        torque, js, echo = by_topic["screw_torque"], by_topic["joint_states"], by_topic["command_echo"]
        rest = [(by_topic[key], i) for key, i in at.items()]

        def log(k: int, stamp_ns: int, command: bytes | None, state: bytes, echoed: bytes | None) -> None:
            if command is not None:
                torque.log(command, log_time=stamp_ns)
            js.log(state, log_time=stamp_ns)
            if echoed is not None:
                echo.log(echoed, log_time=stamp_ns)
            msgs = steps[k % len(steps)][1]
            for channel, i in rest:
                channel.log(msgs[i], log_time=stamp_ns)
            if k % flush_every == 0:
                writer.flush()
        yield log


def lockstep_floor() -> int:
    """Each command answered at once by one state, in the events executor's callback (module doc)."""
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool

    from prsm_ros.cdr_read import float64_data
    from prsm_ros.interface import TOPIC_DEFS
    from prsm_ros.messages import NODE_NAME, TOPICS, MessageMapper
    from prsm_ros.node.executors import make_executor
    from prsm_sim import Simulator, preset

    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node(NODE_NAME)
    js = node.create_publisher(JointState, TOPIC_DEFS["joint_states"].name, TOPICS["joint_states"].qos)
    encoder = MessageMapper(Simulator(preset("s30"), "ideal", 1e-3).layout, "ideal").encoder()
    state = SimpleNamespace(screw_angle_rad=0.0, nut_position_m=0.0, screw_speed_rad_s=0.0, nut_velocity_m_s=0.0,
                            screw_torque_nm=0.0, nut_force_n=0.0, step=0)
    js_handle = js.handle

    def on_command(data: bytes) -> None:
        state.screw_torque_nm = float64_data(data)
        state.step += 1
        with js_handle:
            js_handle.publish_raw(encoder.joint_state(state, state.step * 1_000_000))

    def on_pause(request, response):
        response.success = True
        return response

    node.create_subscription(Float64, TOPIC_DEFS["screw_torque"].name, on_command, TOPICS["screw_torque"].qos,
                             raw=True)
    node.create_subscription(JointState, TOPIC_DEFS["nut_position_reference"].name, lambda _data: None,
                             TOPICS["nut_position_reference"].qos, raw=True)
    node.create_service(SetBool, "~/pause", on_pause)
    executor, _ = make_executor("events")
    executor.add_node(node)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    while not stop.is_set():  # short slices: Python runs the signal handlers between them
        executor.spin_once(timeout_sec=0.1)
    executor.shutdown()
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
