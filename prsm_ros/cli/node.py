"""`prsm-node`: the entry point around `PrsmNode` (arguments, init, spin, a clean shutdown).

It sits above the node (a command line is a transport's front door, not the node's business), so
`prsm_ros.node` never imports it. `python -m prsm_ros.cli.node` is the same as `prsm-node`.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

import rclpy
import rclpy.executors
import rclpy.signals
from rclpy.node import Node

from prsm_sim import PrsmError

from prsm_ros.messages import NODE_NAME
from prsm_ros.node.declare import check_unknown_overrides, declare_parameters, usage
from prsm_ros.node.parameters import ConfigError, ParamSources, param_sources, params_template
from prsm_ros.node.ros_node import PrsmNode
from prsm_ros.node.scheduling import raise_process_threads
from prsm_ros.node.urdf import urdf_for_node


def _exit_now(code: int, message: str) -> None:
    """Report a refused start-up and leave without tearing down the rcl node.

    Destroying a node within milliseconds of creating it sometimes crashes (SIGSEGV in
    rcl's node destruction) or hangs in the middleware while its discovery threads are still
    starting (seen about once in 50 start-ups on a loaded machine). Nothing of ours is open
    at this point (PrsmNode closed its recorder and threads), so skipping the teardown loses nothing.
    """
    print(message, file=sys.stderr)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    """Entry point: init, spin until SIGINT/SIGTERM or external shutdown, close everything, exit 0."""
    args = list(sys.argv if argv is None else argv)
    user = args[1:args.index("--ros-args")] if "--ros-args" in args else args[1:]
    if "-h" in user or "--help" in user:
        print(usage())
        return 0
    if "--params-template" in user:
        i = user.index("--params-template")
        name = user[i + 1] if i + 1 < len(user) else "s30"
        try:
            print(params_template(name), end="")
        except ConfigError as e:
            print(f"prsm-node: error: {e}", file=sys.stderr)
            return 2
        return 0
    urdf = "--urdf" in user
    user = [a for a in user if a != "--urdf"]
    if user:
        print(f"prsm-node: error: unknown argument {user[0]!r}; ROS arguments go after --ros-args "
              "(see prsm-node --help)", file=sys.stderr)
        return 2
    try:  # a missing or broken params file: one line here, not rcl's traceback at init
        sources = param_sources(args, NODE_NAME)
    except ConfigError as e:
        print(f"prsm-node: error: {e}", file=sys.stderr)
        return 2
    for warning in sources.warnings():
        print(f"prsm-node: warning: {warning}", file=sys.stderr)
    if urdf:
        return _print_urdf(args, sources)

    stop = threading.Event()
    rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = None
    try:
        try:
            node = PrsmNode(param_sources=sources)
        except PrsmError as e:  # a parameter refused (ConfigError), or a model the parameters cannot build
            _exit_now(2, f"prsm-node: error: {e}")
        except Exception as e:  # e.g. an RCLError for a QoS override the middleware refuses
            if os.environ.get("PRSM_DEBUG"):
                raise
            _exit_now(1, f"prsm-node: error: could not start: {type(e).__name__}: {e} (PRSM_DEBUG=1 shows where)")
        executor = rclpy.executors.SingleThreadedExecutor()
        executor.add_node(node)
        if node.config.time_mode == "realtime" and node.config.realtime_priority > 1:
            # our own process: the middleware's threads too (not done when PrsmNode is embedded elsewhere)
            node.scheduling["middleware_threads"] = raise_process_threads(node.config.realtime_priority - 1)
        # Python runs signal handlers only between bytecodes, so spin in short slices.
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except rclpy.executors.ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _print_urdf(args: list[str], sources: ParamSources) -> int:
    """`prsm-node --urdf [--ros-args …]`: the parameters read as the node reads them, the URDF on stdout."""
    rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        node = Node(NODE_NAME, start_parameter_services=False, enable_rosout=False)
        cfg = declare_parameters(node)
        check_unknown_overrides(node, sources)
        text = urdf_for_node(cfg, node.get_name(), node.get_namespace())
    except PrsmError as e:
        _exit_now(2, f"prsm-node: error: {e}")
    print(text, end="", flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
