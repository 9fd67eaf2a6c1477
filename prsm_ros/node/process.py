"""The `prsm-node` process around `PrsmNode`: arguments, init, spin, a clean shutdown.

`prsm_ros.cli.node.main` (the `prsm-node` entry point) and `python -m prsm_ros.node` run `main`;
node replay (`prsm_ros.node.replay`) starts the node as `python -m prsm_ros.node`, its own unit.
Every refusal before the node runs is one line on stderr and exit 2: an unknown argument, a
parameter file that cannot be read, a malformed ROS argument (`check_ros_args` names it before
rcl's parser would raise), a parameter refused.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import warnings

import rclpy
import rclpy.executors
import rclpy.signals
from rclpy.node import Node
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

import prsm_sim  # noqa: E402
from prsm_sim import PrsmError  # noqa: E402

from prsm_ros.messages import NODE_NAME  # noqa: E402
from prsm_ros.node.declare import check_unknown_overrides, declare_parameters, usage  # noqa: E402
from prsm_ros.node.parameters import ConfigError, ParamSources, check_ros_args, param_sources, params_template  # noqa: E402
from prsm_ros.node.ros_node import PrsmNode  # noqa: E402
from prsm_ros.node.scheduling import move_process_threads, other_cpus, raise_process_threads  # noqa: E402
from prsm_ros.node.urdf import urdf_for_node  # noqa: E402

RCLError = _rclpy.RCLError  # rcl's refusal of an argument at init (rclpy exports it nowhere public)


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
    if "--version" in user:
        print(f"prsm-node {prsm_sim.__version__}")
        return 0
    if "--params-template" in user:
        return _print_template(user)
    urdf = "--urdf" in user
    user = [a for a in user if a != "--urdf"]
    if user:
        return _refuse(f"unknown argument {user[0]!r}; ROS arguments go after --ros-args (see prsm-node --help)")
    try:  # a malformed argument or a broken params file: one line here, not rcl's traceback at init
        check_ros_args(args)
        sources = param_sources(args, NODE_NAME)
    except ConfigError as e:
        return _refuse(str(e))
    for warning in sources.warnings():
        print(f"prsm-node: warning: {warning}", file=sys.stderr)
    try:
        rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    except RCLError as e:  # an argument rcl reads differently from `check_ros_args`: its reason, in one line
        return _refuse(f"ROS arguments: {rcl_reason(e)}")
    if urdf:
        return _print_urdf(sources)
    return _run(sources)


def _refuse(text: str) -> int:
    print(f"prsm-node: error: {text}", file=sys.stderr)
    return 2


def _print_template(user: list[str]) -> int:
    """`prsm-node --params-template [PRESET]`: every parameter at its default, as a params file."""
    i = user.index("--params-template")
    name = user[i + 1] if i + 1 < len(user) else "s30"
    try:
        print(params_template(name), end="")
    except ConfigError as e:
        return _refuse(str(e))
    return 0


def rcl_reason(e: Exception) -> str:
    """rcl's error in one line: its reason without the C source locations it appends."""
    text = str(e).splitlines()[0] if str(e) else type(e).__name__
    text = text.removeprefix("failed to initialize rcl: ")
    return text.split(", at /")[0].split(". Error: error not set")[0]


def _run(sources: ParamSources) -> int:
    """The node, spun until SIGINT/SIGTERM or an external shutdown; closed in order (exit 0)."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = executor = None
    try:
        try:
            with warnings.catch_warnings(record=True) as said:
                node = PrsmNode(param_sources=sources)
        except PrsmError as e:  # a parameter refused (ConfigError), or a model the parameters cannot build
            _exit_now(2, f"prsm-node: error: {e}")
        except Exception as e:  # e.g. an RCLError for a QoS override the middleware refuses
            if os.environ.get("PRSM_DEBUG"):
                raise
            _exit_now(1, f"prsm-node: error: could not start: {type(e).__name__}: {e} (PRSM_DEBUG=1 shows where)")
        _log_warnings(node.get_logger(), said)
        executor = node.make_executor()
        if node.config.time_mode == "realtime" and node.config.realtime_priority > 1:
            # our own process: the middleware's threads too (not done when PrsmNode is embedded elsewhere)
            node.scheduling["middleware_threads"] = raise_process_threads(node.config.realtime_priority - 1)
        if node.config.time_mode == "realtime" and node.config.step_thread_cpu >= 0:
            # the same for the CPU: the middleware's threads existed before the node moved its own (`scheduling`)
            node.scheduling["middleware_threads_cpus"] = move_process_threads(
                other_cpus(node.config.step_thread_cpu), keep=node.step_thread_ids())
        # Python runs signal handlers only between bytecodes, so spin in short slices. An external
        # shutdown ends the loop through the context's callback rather than an rclpy.ok() per wake-up:
        # in lockstep every command wakes the executor, and that check (a lock, the context's own) was
        # 4.5 % of the main thread (py-spy --gil, fu2018 lockstep with recording).
        rclpy.get_default_context().on_shutdown(stop.set)
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.1)
    except rclpy.executors.ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.close()
            if executor is not None:  # its callbacks off the node's entities before they are destroyed
                executor.shutdown()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _log_warnings(logger, said: list[warnings.WarningMessage]) -> None:
    """Python's warnings (a drive loop that cannot settle, a loop rate off the step grid, a load past the
    static rating) as the node's own log lines, where a ROS user's tools read them (the console in ROS's
    format, /rosout): those its start gave, then every later one."""
    def log(message, category, *_where, **_kw) -> None:
        logger.warning(f"{category.__name__}: {message}")

    for w in said:
        log(w.message, w.category)
    warnings.showwarning = log


def _print_urdf(sources: ParamSources) -> int:
    """`prsm-node --urdf [--ros-args …]`: the parameters read as the node reads them, the URDF on stdout."""
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
