"""The floor under the node's CPU figure: a bare rclpy loop with the node's realtime DDS traffic and nothing else.

    python -m prsm_ros.bench.rclpy_floor [--rate 1000]     # run by `prsm-bench --only realtime`

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
import signal
import sys
import threading
from types import SimpleNamespace


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m prsm_ros.bench.rclpy_floor", description=__doc__.split("\n")[0])
    ap.add_argument("--rate", type=float, default=1000.0, help="loop rate in Hz (the node's default update rate)")
    ap.add_argument("--lockstep", action="store_true",
                    help="answer each command with a state at once (the lockstep round trip's floor)")
    a = ap.parse_args(argv)
    if a.lockstep:
        return lockstep_floor()

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
    period_s = 1.0 / a.rate
    pacer = DeadlinePacer(period_s)
    state = SimpleNamespace(screw_angle_rad=0.0, nut_position_m=0.0, screw_speed_rad_s=0.0, nut_velocity_m_s=0.0,
                            screw_torque_nm=0.0, nut_force_n=0.0)
    command = SimpleNamespace(ns=None)  # the DDS stamp of the last command taken this period

    def on_command(_key: str, data: bytes, info: dict) -> None:
        state.screw_torque_nm = float64_data(data)
        command.ns = stamp_of(None, info.get("source_timestamp"))
    poller = CommandPoller()
    poller.add("screw_torque", sub, on_command)
    k = 0
    js_handle, echo_handle = js.handle, echo.handle
    while not stop.is_set():
        pacer.wait()
        k += 1
        stamp_ns = round(k * period_s * 1e9)
        command.ns = None
        poller.poll()
        with js_handle:
            js_handle.publish_raw(encoder.joint_state(state, stamp_ns))
        if command.ns is not None:
            with echo_handle:
                echo_handle.publish_raw(encoder.time_reference(stamp_ns, command.ns, source))
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


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
