"""The demo's controller under test: a nut-position PID with feed-forward, in its own process over DDS.

    python -m prsm_ros.cli.demo_controller --duration 4 --preset s30 --load 0

It listens to `/joint_states`, answers every state with a command in the node's command interface
(`--command-interface`: a screw torque on `/prsm_actuator/screw_torque`, a screw speed on
`~/velocity_command` or the nut position itself on `~/position_command`, where the node's drive
closes the loops) and publishes its reference on `/prsm_actuator/nut_position_reference`
(so the reference lands in the node's bag). The reference runs on simulation time (the states'
header stamps), so the loop behaves the same in realtime, fast and lockstep modes; in lockstep the
controller's first command starts the simulation. At the end it prints one JSON line with the
tracking summary, which `prsm-demo` reads.

The control law and its reference live in the pure core (`prsm_sim.control`, where its equation
is documented) so that studies and gain tuning (`prsm-sweep tune`) run the very same law offline.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

from prsm_sim import preset
from prsm_sim.control import DEFAULT_AMPLITUDE_M, DEFAULT_FREQUENCY_HZ, DEFAULT_GAINS, DEFAULT_MAX_TORQUE_NM
from prsm_sim.control import PositionController, Tracking, reference
from prsm_sim.models.ideal import reflected_inertia


COMMAND_TOPICS = {"effort": "screw_torque", "velocity": "velocity_command", "position": "position_command"}


def velocity_command(x_ref_m: float, v_ref_m_s: float, x_m: float, lead_per_rad_m: float, bandwidth_hz: float) -> float:
    """Screw speed for the drive's velocity loop: ω = (v_ref + 2π f (x_ref − x)) / (L/2π), rad/s.

    Velocity feed-forward plus a proportional position loop at `bandwidth_hz` (the drive's speed
    loop is faster and holds the load)."""
    return (v_ref_m_s + 2 * math.pi * bandwidth_hz * (x_ref_m - x_m)) / lead_per_rad_m


def run(args: argparse.Namespace) -> dict:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from prsm_ros.messages import TOPICS, with_depth

    params = preset(args.preset)
    ctl = PositionController(reflected_inertia(params), params.geometry.lead_per_rad_m, bandwidth_hz=args.bandwidth,
                             load_n=args.load, max_torque_nm=args.max_torque)
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = Node("prsm_demo_controller")
    cmd_topic = TOPICS[COMMAND_TOPICS[args.command_interface]]
    tau_pub = node.create_publisher(Float64, cmd_topic.resolved(), with_depth(cmd_topic.qos, 10))
    ref_pub = node.create_publisher(Float64, TOPICS["nut_position_reference"].resolved(),
                                    TOPICS["nut_position_reference"].qos)
    track = Tracking()
    st = {"t": 0.0, "x": 0.0, "wall0": None, "t0": None, "done": False, "last_t": None}

    def on_state(msg: JointState) -> None:
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        i = list(msg.name).index("nut_joint")
        x, v = msg.position[i], msg.velocity[i]
        if st["t0"] is None:
            st["t0"], st["wall0"] = t, time.perf_counter()
        dt = t - st["last_t"] if st["last_t"] is not None else 0.0
        st["last_t"], st["t"], st["x"] = t, t, x
        x_ref, v_ref, a_ref = reference(t, args.amplitude, args.frequency)
        track.add(x_ref - x)
        if t >= args.duration:
            st["done"] = True
            return
        ref_pub.publish(Float64(data=x_ref))
        if args.command_interface == "velocity":
            command = velocity_command(x_ref, v_ref, x, params.geometry.lead_per_rad_m, args.bandwidth)
        elif args.command_interface == "position":
            command = x_ref
        else:
            command = ctl.torque(x_ref - x, v_ref - v, a_ref, dt)
        tau_pub.publish(Float64(data=command))

    state_sub = node.create_subscription(JointState, TOPICS["joint_states"].resolved(), on_state,
                                         TOPICS["joint_states"].qos)
    executor = SingleThreadedExecutor()  # one executor: rclpy.spin_once(node) re-adds the node on every call
    executor.add_node(node)
    try:
        deadline = time.monotonic() + args.connect_timeout
        # matched both ways: in lockstep a first state sent before we listen would be lost for good
        while tau_pub.get_subscription_count() == 0 or state_sub.get_publisher_count() == 0:
            if time.monotonic() > deadline:
                print(f"prsm-demo controller: no node listening on {cmd_topic.resolved()} "
                      f"after {args.connect_timeout:g} s", file=sys.stderr)
                break
            executor.spin_once(timeout_sec=0.05)
        else:
            tau_pub.publish(Float64(data=0.0))  # starts a lockstep node; harmless otherwise
            kicked = time.monotonic()
            wall_limit = kicked + args.wall_timeout
            while not st["done"] and time.monotonic() < wall_limit:
                executor.spin_once(timeout_sec=0.1)
                if st["t0"] is None and time.monotonic() > kicked + 2.0:  # no first state yet: kick again
                    tau_pub.publish(Float64(data=0.0))
                    kicked = time.monotonic()
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    wall = time.perf_counter() - st["wall0"] if st["wall0"] is not None else math.nan
    sim = st["t"] - (st["t0"] or 0.0)
    return {"rms_error_m": track.rms_m, "max_error_m": track.max_abs_m, "final_position_m": st["x"],
            "final_reference_m": reference(st["t"], args.amplitude, args.frequency)[0], "sim_time_s": st["t"],
            "states_received": track.n, "wall_time_s": wall, "real_time_factor": sim / wall if wall > 0 else math.nan,
            "completed": st["done"]}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m prsm_ros.cli.demo_controller", description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=4.0, help="simulation seconds to track (s)")
    p.add_argument("--preset", default="s30", help="preset the node runs (for the controller's inertia)")
    p.add_argument("--load", type=float, default=0.0, help="the node's load_force, fed forward (N)")
    p.add_argument("--amplitude", type=float, default=DEFAULT_AMPLITUDE_M, help="reference stroke (m)")
    p.add_argument("--frequency", type=float, default=DEFAULT_FREQUENCY_HZ, help="reference frequency (Hz)")
    p.add_argument("--bandwidth", type=float, default=DEFAULT_GAINS["bandwidth_hz"], help="closed-loop bandwidth (Hz)")
    p.add_argument("--max-torque", type=float, default=DEFAULT_MAX_TORQUE_NM, help="controller torque limit (N·m)")
    p.add_argument("--command-interface", default="effort", choices=tuple(COMMAND_TOPICS),
                   help="what to command: screw torque (effort), screw speed (velocity) or nut position (position)")
    p.add_argument("--connect-timeout", type=float, default=20.0, help="wall seconds to wait for the node")
    p.add_argument("--wall-timeout", type=float, default=120.0, help="wall seconds before giving up")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    summary = run(args)
    print(json.dumps(summary), flush=True)
    return 0 if summary["completed"] else 1


if __name__ == "__main__":
    sys.exit(main())
