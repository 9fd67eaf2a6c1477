"""The demo's controller under test: a nut-position PID with feed-forward, in its own process over DDS.

    python -m prsm_ros.cli.demo_controller --duration 4 --preset s30 --load 0

It listens to `/joint_states` through a keep-last-1 reader that reads the CDR bytes (only the newest
state, never a backlog), answers every state with a command in the node's command interface
(`--command-interface`: a screw torque on `/prsm_actuator/screw_torque`, a screw speed on
`~/velocity_command` or the nut position itself on `~/position_command`, where the node's drive
closes the loops) and publishes its reference on `/prsm_actuator/nut_position_reference`
(so the reference lands in the node's bag), stamped with the stamp of the state it answers, so
`prsm-bag report` pairs each reference with that state as this controller did. The reference runs on simulation time (the states'
header stamps), so the loop behaves the same in realtime and lockstep modes. The node starts paused
(`start_paused`): once both topics are matched the controller resumes it through `~/pause`, so no
step runs before it listens, and in lockstep its first command starts the simulation; at the end it
pauses the node again. With `--realtime-priority` every thread of the controller, the middleware's
included, runs SCHED_FIFO where the OS allows. At the end it prints one JSON line with the tracking
summary, which `prsm-demo` reads.

`--gains FILE` takes the gains `prsm-sweep tune` writes (`prsm_ros.sweep.gains`); `--bandwidth` and
`--max-torque`, when given, override the file's.

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


def state_reader_qos(qos):
    """The topic's reliability with a keep-last-1 history: the reader holds only the newest state.

    The node offers `joint_states` keep-last 100 so that loggers lose nothing; a controller that
    reads such a queue in order acts, whenever it falls behind once, on states up to 100 ms old, and
    a position loop at 8 Hz bandwidth goes unstable with that delay (tracking error
    hundreds of mm, torque at max_effort)."""
    from rclpy.qos import HistoryPolicy, QoSProfile
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=qos.reliability,
                      durability=qos.durability)


def _executor():
    """rclpy's C++ events executor where it exists: a small fraction of the per-callback latency of the
    Python one (prsm_ros.bench.rt_controller measures the loop with the same choice)."""
    try:
        from rclpy.experimental import EventsExecutor
        return EventsExecutor()
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor()


def controller(args: argparse.Namespace, params) -> PositionController:
    """The position law with the demo's defaults, then the gains file's, then --bandwidth/--max-torque."""
    from prsm_ros.sweep.gains import load_gains
    gains = {**DEFAULT_GAINS, "max_torque_nm": DEFAULT_MAX_TORQUE_NM, **(load_gains(args.gains) if args.gains else {})}
    if args.bandwidth is not None:
        gains["bandwidth_hz"] = args.bandwidth
    if args.max_torque is not None:
        gains["max_torque_nm"] = args.max_torque
    return PositionController(reflected_inertia(params), params.geometry.lead_per_rad_m, load_n=args.load, **gains)


def run(args: argparse.Namespace) -> dict:
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool

    from prsm_ros.cdr_read import joint_state_at, joint_state_names
    from prsm_ros.interface import NUT_JOINT, resolve_name
    from prsm_ros.messages import TOPICS, with_depth
    from prsm_ros.node.scheduling import raise_process_threads

    params = preset(args.preset)
    ctl = controller(args, params)
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("prsm_demo_controller")
    cmd_topic = TOPICS[COMMAND_TOPICS[args.command_interface]]
    tau_pub = node.create_publisher(Float64, cmd_topic.resolved(), with_depth(cmd_topic.qos, 10))
    ref_pub = node.create_publisher(JointState, TOPICS["nut_position_reference"].resolved(),
                                    TOPICS["nut_position_reference"].qos)
    ref_msg = JointState(name=[NUT_JOINT], position=[0.0], velocity=[0.0], effort=[math.nan])  # see MessageBuilder.reference
    pause = node.create_client(SetBool, resolve_name("~/pause"))
    track = Tracking()
    # callbacks run in this thread, inside spin_once: st has one owner and needs no lock
    st = {"t": 0.0, "x": 0.0, "wall0": None, "t0": None, "done": False, "last_ns": None, "nut": None, "shown": -1.0}

    def on_state(raw: bytes) -> None:
        if st["done"]:
            return
        if st["nut"] is None:
            st["nut"] = joint_state_names(raw).index(NUT_JOINT)
        stamp_ns, x, v = joint_state_at(raw, st["nut"])
        if st["last_ns"] is not None and stamp_ns <= st["last_ns"]:
            return  # not newer than the state acted on last: answering it would repeat a step's command
        t = stamp_ns * 1e-9
        if st["t0"] is None:
            st["t0"], st["wall0"] = t, time.perf_counter()
        dt = t - st["last_ns"] * 1e-9 if st["last_ns"] is not None else 0.0
        st["last_ns"], st["t"], st["x"] = stamp_ns, t, x
        x_ref, v_ref, a_ref = reference(t, args.amplitude, args.frequency)
        track.add(x_ref - x)
        ref_msg.header.stamp.sec, ref_msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        ref_msg.position[0], ref_msg.velocity[0] = x_ref, v_ref
        if args.progress:
            show_progress(st, t, args.duration)
        if t >= args.duration:  # the last state is tracked too: its reference goes to the bag, no command
            ref_pub.publish(ref_msg)
            st["done"] = True
            return
        if args.command_interface == "velocity":
            command = velocity_command(x_ref, v_ref, x, params.geometry.lead_per_rad_m, ctl.bandwidth_hz)
        elif args.command_interface == "position":
            command = x_ref
        else:
            command = ctl.torque(x_ref - x, v_ref - v, a_ref, dt)
        tau_pub.publish(Float64(data=command))  # the command first: the reference only goes to the bag
        ref_pub.publish(ref_msg)

    state_sub = node.create_subscription(JointState, TOPICS["joint_states"].resolved(), on_state,
                                         state_reader_qos(TOPICS["joint_states"].qos), raw=True)
    executor = _executor()
    executor.add_node(node)
    # after the middleware's threads exist, so that they are raised too (a state must not wait in a socket)
    scheduling = raise_process_threads(args.realtime_priority)
    try:
        _drive(executor, tau_pub, state_sub, pause, st, args, cmd_topic.resolved())
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    wall = time.perf_counter() - st["wall0"] if st["wall0"] is not None else math.nan
    sim = st["t"] - (st["t0"] or 0.0)
    return {"rms_error_m": track.rms_m, "max_error_m": track.max_abs_m, "final_position_m": st["x"],
            "final_reference_m": reference(st["t"], args.amplitude, args.frequency)[0], "sim_time_s": st["t"],
            "states_received": track.n, "wall_time_s": wall, "real_time_factor": sim / wall if wall > 0 else math.nan,
            "completed": st["done"], "scheduling": scheduling,
            "gains": {"bandwidth_hz": ctl.bandwidth_hz, "damping": ctl.damping, "integral_ratio": ctl.integral_ratio,
                      "max_torque_nm": ctl.max_torque_nm}}


def _drive(executor, tau_pub, state_sub, pause, st: dict, args, cmd_name: str) -> None:
    """Wait for the node (matched both ways, its pause service up), resume it, spin until the run is done
    (`st["done"]`) or the wall limit, then pause it again."""
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool
    deadline = time.monotonic() + args.connect_timeout
    # matched both ways and the pause service up: the node waits, paused, for us to resume it,
    # so no step runs before we listen (in lockstep a first state sent before then is lost for good)
    while (tau_pub.get_subscription_count() == 0 or state_sub.get_publisher_count() == 0
           or not pause.service_is_ready()):
        if time.monotonic() > deadline:
            print(f"prsm-demo controller: no node listening on {cmd_name} with {pause.srv_name} "
                  f"after {args.connect_timeout:g} s", file=sys.stderr)
            return
        executor.spin_once(timeout_sec=0.05)
    resumed = pause.call_async(SetBool.Request(data=False))
    executor.spin_until_future_complete(resumed, timeout_sec=max(0.0, deadline - time.monotonic()))
    if not resumed.done():
        print(f"prsm-demo controller: {pause.srv_name} did not answer within {args.connect_timeout:g} s",
              file=sys.stderr)
        return
    tau_pub.publish(Float64(data=0.0))  # starts a lockstep node; harmless otherwise
    kicked = time.monotonic()
    wall_limit = kicked + args.wall_timeout
    while not st["done"] and time.monotonic() < wall_limit:
        executor.spin_once(timeout_sec=0.1)
        if st["t0"] is None and time.monotonic() > kicked + 2.0:  # no first state yet: kick again
            tau_pub.publish(Float64(data=0.0))
            kicked = time.monotonic()
    # pause the node where the run ends, so the bag stops with the tracked profile rather
    # than with the load pushing an uncontrolled nut (not waited for beyond a few seconds)
    executor.spin_until_future_complete(pause.call_async(SetBool.Request(data=True)), timeout_sec=5.0)


PROGRESS_EVERY_S = 0.25  # simulated seconds between progress updates (a line on stderr, rewritten in place)


def show_progress(st: dict, t: float, duration_s: float) -> None:
    """The run's simulated time on stderr, every PROGRESS_EVERY_S, and a newline when it ends."""
    if t - st["shown"] < PROGRESS_EVERY_S and t < duration_s:
        return
    st["shown"] = t
    end = "\n" if t >= duration_s else ""
    print(f"\rprsm-demo: {min(t, duration_s):.2f} of {duration_s:g} s simulated", end=end, file=sys.stderr, flush=True)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m prsm_ros.cli.demo_controller", description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=4.0, help="simulation seconds to track (s)")
    p.add_argument("--preset", default="s30", help="preset the node runs (for the controller's inertia)")
    p.add_argument("--load", type=float, default=0.0, help="the node's load_force, fed forward (N)")
    p.add_argument("--amplitude", type=float, default=DEFAULT_AMPLITUDE_M, help="reference stroke (m)")
    p.add_argument("--frequency", type=float, default=DEFAULT_FREQUENCY_HZ, help="reference frequency (Hz)")
    p.add_argument("--gains", metavar="FILE", help="gains file (prsm-sweep tune writes one: DIR/gains.yaml)")
    p.add_argument("--bandwidth", type=float, help=f"closed-loop bandwidth (Hz; default {DEFAULT_GAINS['bandwidth_hz']:g})")
    p.add_argument("--max-torque", type=float, help=f"controller torque limit (N·m; default {DEFAULT_MAX_TORQUE_NM:g})")
    p.add_argument("--command-interface", default="effort", choices=tuple(COMMAND_TOPICS),
                   help="what to command: screw torque (effort), screw speed (velocity) or nut position (position)")
    p.add_argument("--realtime-priority", type=int, default=0,
                   help="SCHED_FIFO priority of every thread of the controller where the OS allows (0: normal)")
    p.add_argument("--connect-timeout", type=float, default=120.0,
                   help="wall seconds to wait for the node (a first start compiles its kernels)")
    p.add_argument("--wall-timeout", type=float, default=120.0, help="wall seconds before giving up")
    p.add_argument("--progress", action="store_true", help="show the simulated time on stderr as the run goes")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    summary = run(args)
    print(json.dumps(summary), flush=True)
    return 0 if summary["completed"] else 1


if __name__ == "__main__":
    sys.exit(main())
