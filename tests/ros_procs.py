"""Shared helpers for tests that run real ROS 2 processes talking over DDS on this machine.

- `ros_test_env(salt)`: an environment isolated per test module and per pytest process: a unique
  ROS_DOMAIN_ID (`ros_domains.domain_id`: from the pid and a salt, in
  this pytest-xdist worker's slice of 1..232), localhost-only discovery, RERUN=off
  (`prsm_ros.ros_env.isolated_env`, ignoring whatever the developer's shell has set).
- `NodeProcess`: `prsm-node` in its own OS process with `-p name:=value` parameters; stop it with
  SIGINT/SIGTERM and get its exit code and output.
- `RosClient`: an rclpy node in the test process (its own context on the same domain) that
  publishes commands, collects messages per topic, calls services and sets parameters.

MCAP and Rerun tests may import these; nothing here knows about the node's internals.
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from prsm_ros.ros_env import isolated_env, ros_args, start_module
from ros_domains import domain_id

# Every timeout here is a ceiling on waiting for an event, never a duration: a passing test does not
# wait for it. The ceilings the tests name are what a quiet machine needs with margin; they are
# stretched by this factor, so a machine whose every core is busy (several suites side by side,
# CPU hogs) only makes the tests slower, never makes them fail.
CEILING_FACTOR = 6.0


def ros_test_env(salt: str = "", **extra: str) -> dict[str, str]:
    """os.environ with the isolation this project's ROS tests use (see module docstring)."""
    env = isolated_env(domain_id(salt), respect_user=False, RERUN="off", PYTHONFAULTHANDLER="1", **extra)
    env.pop("ROS_STATIC_PEERS", None)
    return env


class NodeProcess:
    """`prsm-node` as a child process (python -m prsm_ros.cli.node), output captured to files."""

    def __init__(self, env: dict[str, str], params: dict[str, Any] | None = None, *, workdir: Path,
                 extra_args: list[str] | None = None, module: str = "prsm_ros.cli.node",
                 cwd: Path | None = None) -> None:
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.stdout_path = self.workdir / "node.stdout"
        self.stderr_path = self.workdir / "node.stderr"
        args = (extra_args or []) + (ros_args(params) if params else [])
        with open(self.stdout_path, "wb") as out, open(self.stderr_path, "wb") as err:
            self.proc = start_module(module, args, env, cwd=cwd or self.workdir, stdout=out, stderr=err)

    def wait(self, timeout: float = 20.0) -> int:
        return self.proc.wait(timeout=timeout * CEILING_FACTOR)

    def stop(self, sig: int = signal.SIGINT, timeout: float = 20.0) -> int:
        """Send `sig` and wait for the exit code (kills after `timeout` s and fails loudly)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            timeout *= CEILING_FACTOR
            try:
                return self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise AssertionError(f"node did not exit within {timeout} s of signal {sig}; stderr:\n{self.stderr}") from None
        return self.proc.returncode

    @property
    def stdout(self) -> str:
        return self.stdout_path.read_text(errors="replace")

    @property
    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace")

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, *exc) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class RosClient:
    """An rclpy node in the test process on `env`'s domain: publish, collect, call, set parameters."""

    def __init__(self, env: dict[str, str], name: str = "prsm_test_client", node_name: str = "prsm_actuator") -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node_path = f"/{node_name}"
        self.domain = env["ROS_DOMAIN_ID"]
        self.context = rclpy.Context()
        # The domain is the env's: the context reads it at init; localhost discovery comes from the env too.
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
        rclpy.init(context=self.context, domain_id=int(env["ROS_DOMAIN_ID"]),
                   signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.received: dict[str, list] = {}
        self._pubs: dict[str, Any] = {}
        self._subs: dict[str, Any] = {}
        self._clients: dict[tuple[str, Any], Any] = {}

    # -- topics --------------------------------------------------------------------------
    def subscribe(self, topic: str, msg_class, qos=None) -> list:
        """Collect every message on `topic` into the returned list (the same list every call)."""
        from prsm_ros.messages import TOPICS, with_depth
        if topic not in self.received:
            spec = next((t for t in TOPICS.values() if t.resolved() == topic), None)
            qos = qos or (with_depth(spec.qos, 10000) if spec else 10000)
            self.received[topic] = []
            self._subs[topic] = self.node.create_subscription(msg_class, topic, self.received[topic].append, qos)
        return self.received[topic]

    def publisher(self, topic: str, msg_class):
        from prsm_ros.messages import TOPICS, with_depth
        if topic not in self._pubs:
            spec = next((t for t in TOPICS.values() if t.resolved() == topic), None)
            self._pubs[topic] = self.node.create_publisher(msg_class, topic, with_depth(spec.qos, 10) if spec else 10)
        return self._pubs[topic]

    def publish(self, topic: str, msg) -> None:
        self.publisher(topic, type(msg)).publish(msg)

    def spin_until(self, done: Callable[[], bool], timeout: float = 10.0, what: str = "condition") -> None:
        """Spin the client until `done()` is true; AssertionError naming `what` after `timeout` × CEILING_FACTOR s."""
        timeout *= CEILING_FACTOR
        end = time.monotonic() + timeout
        while not done():
            if time.monotonic() > end:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.01)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def wait_for_node(self, proc: NodeProcess | None = None, timeout: float = 20.0) -> None:
        """Until the node is on the graph and every publisher, subscription and client we made is matched.

        Matching both ways matters in lockstep: a state published before our reader matched the
        node's writer is lost (volatile QoS), and the loop would wait for it forever.
        """
        def ready() -> bool:
            if proc is not None and proc.proc.poll() is not None:
                raise AssertionError(f"node exited with {proc.proc.returncode}:\n{proc.stderr}")
            if self.node.count_subscribers(f"{self.node_path}/screw_torque") == 0:
                return False
            return all(p.get_subscription_count() > 0 for p in self._pubs.values()) and \
                all(s.get_publisher_count() > 0 for s in self._subs.values()) and \
                all(c.service_is_ready() for c in self._clients.values())
        self.spin_until(ready, timeout, "the node to appear on the graph")
        others = [n for n in self.node.get_node_names() if n not in (self.node_path.split("/")[-1], self.node.get_name())]
        n_torque = self.node.count_subscribers(f"{self.node_path}/screw_torque")
        assert n_torque == 1, (f"{n_torque} nodes listen on {self.node_path}/screw_torque: another ROS graph shares "
                               f"ROS_DOMAIN_ID {self.domain} (nodes: {others})")

    # -- services and parameters -----------------------------------------------------------
    def client(self, service: str, srv_class):
        """One client per service for the life of this RosClient.

        Creating and destroying a client per call makes DDS discover a new pair of endpoints each
        time; one client per service is discovered once (and a test may make it before
        `wait_for_node`, which then waits for it too).
        """
        key = (service, srv_class)
        if key not in self._clients:
            self._clients[key] = self.node.create_client(srv_class, service)
        return self._clients[key]

    def call(self, service: str, srv_class, request=None, timeout: float = 10.0, proc: NodeProcess | None = None):
        """Call `service` and return its response; a timeout names what the graph held then."""
        client = self.client(service, srv_class)

        def ready() -> bool:
            if proc is not None and proc.proc.poll() is not None:
                raise AssertionError(f"node exited with {proc.proc.returncode}:\n{proc.stderr}")
            return client.service_is_ready()
        try:
            self.spin_until(ready, timeout, f"service {service}")
        except AssertionError as e:
            listed = service in dict(self.node.get_service_names_and_types())
            raise AssertionError(f"{e} (on the graph: {listed}; nodes: {self.node.get_node_names()})") from None
        future = client.call_async(request if request is not None else srv_class.Request())
        self.spin_until(future.done, timeout, f"the response of {service}")
        return future.result()

    def set_parameters(self, values: dict[str, Any], timeout: float = 10.0):
        """Set the node's parameters atomically (SetParametersAtomically); returns its SetParametersResult."""
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.parameter import Parameter
        req = SetParametersAtomically.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                          for k, v in values.items()])
        return self.call(f"{self.node_path}/set_parameters_atomically", SetParametersAtomically, req, timeout).result

    def get_parameters(self, names: list[str], timeout: float = 10.0) -> dict[str, Any]:
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        res = self.call(f"{self.node_path}/get_parameters", GetParameters, GetParameters.Request(names=names), timeout)
        return {n: parameter_value_to_python(v) for n, v in zip(names, res.values)}

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self) -> RosClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def diagnostics_of(msg) -> tuple[int, str, dict[str, str]]:
    """(level, message, values) of the first status in a DiagnosticArray."""
    st = msg.status[0]
    return int.from_bytes(st.level, "little") if isinstance(st.level, bytes) else int(st.level), st.message, \
        {kv.key: kv.value for kv in st.values}


def thread_cpus(pid: int, tid: int) -> frozenset[int]:
    """The CPUs a thread may run on, as the kernel lists them (/proc: an oracle beside what a process reports)."""
    with open(f"/proc/{pid}/task/{tid}/status") as fh:
        listed = next(line.split(":", 1)[1].strip() for line in fh if line.startswith("Cpus_allowed_list"))
    cpus: set[int] = set()
    for part in listed.split(","):
        lo, _, hi = part.partition("-")
        cpus.update(range(int(lo), int(hi or lo) + 1))
    return frozenset(cpus)


def thread_ids(pid: int) -> list[int]:
    """The ids of a process's threads (/proc)."""
    return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
