"""`prsm-ctl`: drive a running `prsm-node` from the command line, with rclpy only (no ROS installation).

    prsm-ctl [--node NAME] [--timeout S] [--json] VERB ...

    pause | resume                      ~/pause (std_srvs/SetBool)
    step [N]                            N steps while paused (~/step; N sets step_count for this call)
    reset                               ~/reset: time zero, at rest at initial_nut_position
    state [--follow] [--rate HZ]        one line: time, mode, screw and nut state (joint_states + /diagnostics)
    param get NAME... | set NAME VALUE | list [PREFIX] | dump
    interface effort|velocity|position  the command_interface parameter
    command torque|velocity|position VALUE   one command (N·m, screw rad/s, nut m) on the active interface's topic
    fault inject KIND [key=value ...] | fault clear
    brake on|off                        ~/brake
    release                             ~/release_control (give up ownership of the actuator)
    events [--follow]                   ~/events: the latched history, then (--follow) new ones

The ROS domain comes from the environment (ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE), as for
any ROS 2 tool. `--node` is the node's full name (default /prsm_actuator; with a namespace
/left/prsm_actuator); topic names follow the node's `topics.*` parameters. Exit status: 0 done,
2 a user error, a refusal by the node, or no node of that name within `--timeout` seconds
(one line on stderr saying which), 130 on Ctrl-C.

Each `ros2` command the docs would use has a verb here; e.g. `ros2 param set /prsm_actuator
load_force 500.0` is `prsm-ctl param set load_force 500.0`, `ros2 service call
/prsm_actuator/pause std_srvs/srv/SetBool "{data: false}"` is `prsm-ctl resume`.

A command is sent once, like `ros2 topic pub --once`: this process becomes the actuator's owner
until `ownership_timeout` passes without a command from it, and the node's `cmd_timeout`
watchdog applies as to any controller.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable
from typing import Any

from prsm_sim.errors import PrsmError

from prsm_ros.interrupts import interrupt_handled

PROG = "prsm-ctl"
DEFAULT_NODE = "/prsm_actuator"
COMMAND_KINDS = {"torque": ("effort", "screw_torque", "N·m"), "velocity": ("velocity", "velocity_command", "rad/s"),
                 "position": ("position", "position_command", "m")}
INTERFACES = ("effort", "velocity", "position")
APPLY_WAIT_S = 2.0  # `command`: how long to wait for the node to apply or refuse it
# how long `brake` waits for the node's ~/brake_command reader to be discovered once its services are
BRAKE_TOPIC_WAIT_S = 2.0
EVENTS_SETTLE_S = 0.5  # `events` without --follow: the latched history is complete when nothing came for this long


class CtlError(PrsmError):
    """A user error or a refusal: one line, exit status 2."""


def _split_node(name: str) -> tuple[str, str]:
    """'/ns/prsm_actuator' → ('/ns', 'prsm_actuator'); a bare name is in the root namespace."""
    if not name or name.endswith("/") or " " in name:
        raise CtlError(f"--node {name!r}: expected a node name such as /prsm_actuator or /left/prsm_actuator")
    full = name if name.startswith("/") else "/" + name
    ns, _, base = full.rpartition("/")
    return ns or "/", base


def parse_value(text: str) -> Any:
    """A parameter value typed as `ros2 param set` types it: YAML (true, 3, 3.0, nan, text)."""
    import yaml
    low = text.strip().lower()
    if low in ("nan", ".nan"):
        return math.nan
    if low in ("inf", "+inf", ".inf", "-inf", "-.inf"):
        return -math.inf if low.startswith("-") else math.inf
    number = _number(text)
    if number is not None:
        return number
    try:
        v = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, list) and v and all(type(x) is type(v[0]) for x in v) and isinstance(v[0], (bool, int, float, str)):
        return v
    return text


def _number(text: str) -> int | float | None:
    """`text` as an int or float in any spelling Python reads (-1e-1, 1_000, +.5), else None."""
    t = text.strip()
    for kind in (int, float):
        try:
            return kind(t)
        except ValueError:
            pass
    return None


def typed(text: str) -> Any:
    """A /diagnostics value (always a string there) as what it means: true/false, a number, or the text."""
    if text in ("True", "False"):
        return text == "True"
    number = _number(text)
    return text if number is None or text.strip().lower() in ("nan", "inf", "-inf") else number


def _finite(text: str, what: str) -> float:
    text = text.strip()
    try:
        v = float(text)
    except ValueError:
        raise CtlError(f"{what} = {text!r}: expected a number") from None
    if not math.isfinite(v):
        raise CtlError(f"{what} = {text!r}: must be finite")
    return v


class Ctl:
    """One rclpy node in its own context on the environment's domain, talking to one prsm-node."""

    def __init__(self, node: str = DEFAULT_NODE, timeout_s: float = 10.0) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        self.namespace, self.node_name = _split_node(node)
        self.target = (self.namespace.rstrip("/") + "/" + self.node_name)
        self.timeout_s = timeout_s
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
        self.node = rclpy.create_node("prsm_ctl", context=self.context, start_parameter_services=False,
                                      enable_rosout=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._topics: dict[str, str] | None = None
        self._clients: dict[tuple[str, Any], Any] = {}  # (service name, type) → its client (`_client`)

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    # -- waiting -----------------------------------------------------------------------------
    def wait_until(self, done: Callable[[], bool], within_s: float) -> bool:
        """Spin until `done()` holds or `within_s` wall seconds pass; returns whether it held."""
        end = time.monotonic() + within_s
        while not done():
            if time.monotonic() > end:
                return False
            self.executor.spin_once(timeout_sec=0.02)
        return True

    def spin_until(self, done: Callable[[], bool], what: str, timeout_s: float | None = None) -> None:
        within_s = self.timeout_s if timeout_s is None else timeout_s
        if not self.wait_until(done, within_s):
            raise CtlError(f"{what} within {within_s:g} s")

    def wait_for_node(self) -> None:
        """Until the node's `~/pause` service is ready (endpoint discovery: faster than the node list)."""
        import os

        from std_srvs.srv import SetBool
        client = self._client(SetBool, f"{self.target}/pause")
        domain = os.environ.get("ROS_DOMAIN_ID", "0") or "0"
        self.spin_until(client.service_is_ready,
                        f"node {self.target} not found on ROS_DOMAIN_ID {domain} (is prsm-node running, "
                        "with the same ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE?)")

    def _client(self, srv_class, name: str):
        """One client per service for the life of this Ctl: a new client's endpoints must be discovered
        by the node again before it is ready (seconds, at times), so the one `wait_for_node` matched is
        the one `~/pause` is then called with."""
        client = self._clients.get((name, srv_class))
        if client is None:
            client = self._clients[(name, srv_class)] = self.node.create_client(srv_class, name)
        return client

    # -- services ----------------------------------------------------------------------------
    def call(self, service: str, srv_class, request=None):
        name = service if service.startswith("/") else f"{self.target}/{service}"
        client = self._client(srv_class, name)
        self.spin_until(client.service_is_ready, f"service {name} did not appear")
        future = client.call_async(request if request is not None else srv_class.Request())
        self.spin_until(future.done, f"no answer from {name}")
        return future.result()

    def trigger(self, service: str, request=None) -> dict:
        """Call a Trigger/SetBool service; a refusal is a CtlError with the node's reason."""
        from std_srvs.srv import SetBool, Trigger
        res = self.call(service, SetBool if request is not None else Trigger,
                        SetBool.Request(data=request) if request is not None else None)
        if not res.success:
            raise CtlError(f"{self.target}/{service} refused: {res.message}")
        return {"service": f"{self.target}/{service}", "message": res.message}

    # -- parameters --------------------------------------------------------------------------
    def get_params(self, names: list[str]) -> dict[str, Any]:
        from rcl_interfaces.msg import ParameterType
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        res = self.call("get_parameters", GetParameters, GetParameters.Request(names=names))
        if len(res.values) != len(names):  # rclpy answers nothing at all when one name is not declared
            known = set(self.list_params())
            missing = next((n for n in names if n not in known), names[0])
            raise CtlError(f"parameter {missing}: not a parameter of {self.target}" + self._nearest(missing))
        out = {}
        for n, v in zip(names, res.values):
            if v.type == ParameterType.PARAMETER_NOT_SET:
                raise CtlError(f"parameter {n}: not a parameter of {self.target}" + self._nearest(n))
            out[n] = parameter_value_to_python(v)
        return out

    def _nearest(self, name: str) -> str:
        import difflib
        close = difflib.get_close_matches(name, self.list_params(), n=1)
        return f"; did you mean {close[0]}?" if close else " (prsm-ctl param list shows them)"

    def list_params(self, prefix: str = "") -> list[str]:
        from rcl_interfaces.srv import ListParameters
        # all of them, filtered here: ROS matches prefixes only at whole dotted components
        req = ListParameters.Request(prefixes=[], depth=0)
        names = sorted(self.call("list_parameters", ListParameters, req).result.names)
        return [n for n in names if n.startswith(prefix)]

    def set_param(self, name: str, value: Any) -> dict:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        try:
            msg = Parameter(name, value=value).to_parameter_msg()
        except (TypeError, ValueError) as e:
            raise CtlError(f"parameter {name} = {value!r}: {e}") from None
        res = self.call("set_parameters", SetParameters, SetParameters.Request(parameters=[msg])).results[0]
        if not res.successful:
            reason = res.reason or "refused"
            if "undeclared" in reason.lower() or "not declared" in reason.lower():
                reason += self._nearest(name)
            raise CtlError(f"parameter {name} = {value!r} refused: {reason}")
        return {"name": name, "value": value}

    # -- topics ------------------------------------------------------------------------------
    def topic(self, key: str) -> str:
        """The full name of one of the node's topics, following its `topics.*` parameters."""
        from prsm_ros.interface import TOPIC_DEFS, resolve_name
        if self._topics is None:
            names = self.list_params("topics.")
            self._topics = {n[len("topics."):]: v for n, v in self.get_params(names).items()} if names else {}
        declared = self._topics.get(key, TOPIC_DEFS[key].name)
        return resolve_name(declared, self.node_name, self.namespace)

    def publish_once(self, key: str, msg) -> str:
        """Publish one message on the node's `key` topic once its reader has matched; wait for its acknowledgement."""
        from prsm_ros.messages import TOPICS, with_depth
        name = self.topic(key)
        pub = self.node.create_publisher(type(msg), name, with_depth(TOPICS[key].qos, 10))
        self.spin_until(lambda: pub.get_subscription_count() > 0, f"nobody reads {name}")
        pub.publish(msg)
        from rclpy.duration import Duration
        if not pub.wait_for_all_acked(Duration(nanoseconds=int(self.timeout_s * 1e9))):
            raise CtlError(f"{name}: the node did not acknowledge the message")
        return name

    def participant_of(self, topic: str) -> str | None:
        """This process's DDS participant as the node names writers (GUID prefix, hex), from its writer on `topic`."""
        from prsm_ros.node.ownership import PREFIX_BYTES
        for info in self.node.get_publishers_info_by_topic(topic):
            if info.node_name == self.node.get_name() and info.node_namespace == self.node.get_namespace():
                return bytes(info.endpoint_gid[:PREFIX_BYTES]).hex()
        return None

    def subscribe(self, key: str, msg_class, callback, qos=None):
        from prsm_ros.messages import TOPICS, with_depth
        return self.node.create_subscription(msg_class, self.topic(key), callback,
                                             qos if qos is not None else with_depth(TOPICS[key].qos, 100))


# -- verbs ---------------------------------------------------------------------------------------
def _state_record(js, diag: dict[str, str] | None) -> dict:
    names = list(js.name)
    t = js.header.stamp.sec + js.header.stamp.nanosec * 1e-9

    def joint(i: int) -> dict:
        def at(arr):
            return float(arr[i]) if len(arr) > i else math.nan
        return {"position": at(js.position), "velocity": at(js.velocity), "effort": at(js.effort)}
    rec: dict[str, Any] = {"time_s": t, **{n: joint(i) for i, n in enumerate(names)}}
    if diag is not None:
        for k in ("paused", "command_interface", "command", "command_owner", "fault", "faults_active", "brake_engaged"):
            if k in diag and diag[k] != "":
                rec[k] = typed(diag[k])
    return rec


PAUSED_STATE_KEYS = (("position", "state_{}_position"), ("velocity", "state_{}_velocity"), ("effort", "state_{}_effort"))


def _paused_record(diag: dict[str, str]) -> dict:
    """The state of a paused node from its /diagnostics (joint_states stops while paused): the last
    state the node holds, with the joints' names and values it reports there."""
    rec: dict[str, Any] = {"time_s": float(diag.get("sim_time_s", "nan")), "paused": True}
    for name in filter(None, diag.get("state_joints", "").split(",")):
        rec[name] = {k: float(diag.get(key.format(name), "nan")) for k, key in PAUSED_STATE_KEYS}
    for k in ("command_interface", "command", "command_owner", "fault", "faults_active", "brake_engaged"):
        if diag.get(k, "") != "":
            rec[k] = typed(diag[k])
    return rec


def _state_line(rec: dict) -> str:
    parts = [f"t = {rec['time_s']:.6f} s"]
    if "paused" in rec:
        parts.append("paused" if rec["paused"] is True else "running")
    if "command_interface" in rec:
        parts.append(f"{rec['command_interface']} command {rec.get('command', '?')}")
    units = {0: ("rad", "rad/s", "N·m"), 1: ("m", "m/s", "N")}
    for i, (name, j) in enumerate((k, v) for k, v in rec.items() if isinstance(v, dict)):
        u = units.get(i, ("", "", ""))
        parts.append(f"{name} {j['position']:.6g} {u[0]} {j['velocity']:.6g} {u[1]} {j['effort']:.6g} {u[2]}")
    for k in ("command_owner", "fault", "faults_active", "brake_engaged"):
        if k in rec:
            parts.append(f"{k} {rec[k]}")
    return ", ".join(parts)


def cmd_state(ctl: Ctl, args, emit) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    latest: dict[str, Any] = {"js": None, "diag": None}
    diag_name = f"{ctl.target}: simulation"

    def on_diag(msg) -> None:
        for st in msg.status:
            if st.name == diag_name:
                latest["diag"] = {kv.key: kv.value for kv in st.values}
    ctl.subscribe("joint_states", JointState, lambda m: latest.__setitem__("js", m))
    ctl.subscribe("diagnostics", DiagnosticArray, on_diag, qos=10)
    if not args.follow:
        # the state of a paused node: joint_states stops while paused, /diagnostics says so
        def have() -> bool:
            if latest["diag"] is not None and latest["diag"].get("paused") == "True" and latest["js"] is None:
                return True
            return latest["js"] is not None and latest["diag"] is not None
        ctl.spin_until(have, f"no joint_states or /diagnostics from {ctl.target}")
        if latest["js"] is None:  # paused: the state the node holds, from /diagnostics
            rec = _paused_record(latest["diag"])
            emit(rec, _state_line(rec))
            return
        rec = _state_record(latest["js"], latest["diag"])
        emit(rec, _state_line(rec))
        return
    period = 1.0 / args.rate
    next_t = 0.0
    while True:
        ctl.executor.spin_once(timeout_sec=0.02)
        now = time.monotonic()
        if latest["js"] is not None and now >= next_t:
            rec = _state_record(latest["js"], latest["diag"])
            emit(rec, _state_line(rec))
            latest["js"] = None
            next_t = now + period


def cmd_events(ctl: Ctl, args, emit) -> None:
    from std_msgs.msg import String
    got: list[tuple[float, str]] = []
    ctl.subscribe("events", String, lambda m: got.append((time.monotonic(), m.data)))
    name = ctl.topic("events")
    ctl.spin_until(lambda: ctl.node.count_publishers(name) > 0, f"nobody publishes {name}")
    shown = 0
    start = time.monotonic()
    while True:
        ctl.executor.spin_once(timeout_sec=0.05)
        for _, text in got[shown:]:
            try:
                doc = json.loads(text)
            except ValueError:
                doc = {"message": text}
            emit(doc, f"t = {doc.get('time_s', math.nan):.6f} s {doc.get('severity', '?')} "
                      f"{doc.get('source', '?')}/{doc.get('code', '?')}: {doc.get('message', '')}")
        shown = len(got)
        last = got[-1][0] if got else start
        if not args.follow and time.monotonic() - last > EVENTS_SETTLE_S:
            return


def cmd_param(ctl: Ctl, args, emit) -> None:
    if args.action == "get":
        values = ctl.get_params(args.names)
        for k, v in values.items():
            emit({"name": k, "value": v}, f"{k}: {v!r}" if len(values) > 1 else repr(v))
    elif args.action == "set":
        if len(args.names) != 2:
            raise CtlError("param set: expected NAME VALUE")
        name, text = args.names
        r = ctl.set_param(name, parse_value(text))
        emit(r, f"set {name} = {r['value']!r}")
    elif args.action == "list":
        if len(args.names) > 1:
            raise CtlError("param list: at most one PREFIX")
        names = ctl.list_params(args.names[0] if args.names else "")
        emit({"names": names}, "\n".join(names))
    else:  # dump: a ros__parameters file for this node (loadable with --params-file)
        import yaml
        values = ctl.get_params(ctl.list_params())
        doc = {ctl.target.lstrip("/") if ctl.namespace != "/" else ctl.node_name: {"ros__parameters": values}}
        emit(values, yaml.safe_dump(doc, sort_keys=False, default_flow_style=False).rstrip())


def cmd_command(ctl: Ctl, args, emit) -> None:
    from std_msgs.msg import Float64
    interface, key, unit = COMMAND_KINDS[args.kind]
    value = _finite(args.value, f"command {args.kind}")
    active = ctl.get_params(["command_interface"])["command_interface"]
    if active != interface:
        raise CtlError(f"command {args.kind}: the node's command_interface is {active}; "
                       f"`prsm-ctl interface {interface}` first (or send a {_kind_of(active)} command)")
    from sensor_msgs.msg import TimeReference
    echoes: list = []
    ctl.subscribe("command_echo", TimeReference, echoes.append)
    # applied (echoed by the step that took it) or refused (an event naming this writer), for a while
    name, done = send_and_await(ctl, key, Float64(data=value), f"command {args.kind} {value:g}",
                                lambda name, events: next((m for m in echoes if m.source == name), None))
    if done is not None:
        t = done.header.stamp.sec + done.header.stamp.nanosec * 1e-9
        emit({"topic": name, "value": value, "unit": unit, "applied_at_s": t},
             f"{value:g} {unit} on {name}: applied by the step at t = {t:.6f} s")
        return
    emit({"topic": name, "value": value, "unit": unit, "applied_at_s": None},
         f"sent {value:g} {unit} to {name}; not applied within {min(ctl.timeout_s, APPLY_WAIT_S):g} s "
         "(the node is paused, or see prsm-ctl events)")


def send_and_await(ctl: Ctl, key: str, msg, what: str, applied: Callable[[str, list[str]], Any]) -> tuple[str, Any]:
    """Publish `msg` once on the node's `key` topic and wait up to APPLY_WAIT_S for the node's verdict:
    a refusal event naming this writer is a CtlError (exit 2); `applied(topic, events)` returning
    something ends the wait with it. Returns (topic name, that result or None: no verdict in time)."""
    from std_msgs.msg import String
    events: list[str] = []
    sub = ctl.subscribe("events", String, lambda m: events.append(m.data), qos=_volatile_events_qos())
    ctl.spin_until(lambda: sub.get_publisher_count() > 0, f"nobody publishes {ctl.topic('events')}")
    name = ctl.publish_once(key, msg)
    me = ctl.participant_of(name)
    end = time.monotonic() + min(ctl.timeout_s, APPLY_WAIT_S)
    while time.monotonic() < end:
        ctl.executor.spin_once(timeout_sec=0.02)
        refused = _refusal_for(events, me)
        if refused is not None:
            raise CtlError(f"{what} refused by {ctl.target}: {refused}")
        got = applied(name, events)
        if got is not None:
            return name, got
    return name, None


def _volatile_events_qos():
    """~/events for new events only: a volatile reader gets none of the latched history."""
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    return QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


def _refusal_for(events: list[str], participant: str | None) -> str | None:
    """The message of the first refusal event that names this writer."""
    for text in events:
        try:
            doc = json.loads(text)
        except ValueError:
            continue
        details = doc.get("details") or {}
        if participant is not None and details.get("writer") == participant:
            return str(doc.get("message", doc.get("code", "refused")))
    return None


def _kind_of(interface: str) -> str:
    return next(k for k, v in COMMAND_KINDS.items() if v[0] == interface)


def cmd_fault(ctl: Ctl, args, emit) -> None:
    if args.action == "clear":
        if args.spec:
            raise CtlError("fault clear takes no arguments")
        r = ctl.trigger("clear_faults")
        emit(r, r["message"])
        return
    from std_msgs.msg import String

    from prsm_sim.actuator import parse_fault

    from prsm_ros.param_files import bound_fault
    if not args.spec:
        raise CtlError("fault inject: expected KIND [key=value ...], e.g. fault inject jam duration_s=0.5 value=30")
    first = args.spec[0]
    text = ",".join(args.spec if "=" in first else [f"kind={first}", *args.spec[1:]])
    try:
        bound_fault(parse_fault(text if "start_s" in text else f"{text},start_s=0"))  # the node checks it again
    except PrsmError as e:
        raise CtlError(f"fault inject: {e}") from None
    r = send_owned(ctl, "inject_fault", String(data=text), f"fault inject {text!r}", started="fault_start")
    emit({**r, "fault": text}, r["message"])


def send_owned(ctl: Ctl, key: str, msg, what: str, started: str | None = None) -> dict:
    """Publish one message on an owned input (~/inject_fault, ~/brake_command) and wait for the node's
    verdict (`send_and_await`): `started` (an event code) confirms it took effect; else, after
    APPLY_WAIT_S without a refusal, it was accepted."""
    name, doc = send_and_await(ctl, key, msg, what,
                               lambda name, events: started and _event_with_code(events, started))
    if doc:
        return {"topic": name, "accepted": True,
                "message": f"{what}: {doc.get('message', started)} (t = {doc.get('time_s', math.nan):.6f} s)"}
    return {"topic": name, "accepted": True,
            "message": f"{what} on {name}: accepted (no refusal within {min(ctl.timeout_s, APPLY_WAIT_S):g} s)"}


def _event_with_code(events: list[str], code: str) -> dict | None:
    for text in events:
        try:
            doc = json.loads(text)
        except ValueError:
            continue
        if isinstance(doc, dict) and doc.get("code") == code:
            return doc
    return None


def step(ctl: Ctl, n: int | None) -> dict:
    """~/step (`n` sets step_count for this call only). A request the node runs in the background
    ("accepted") is waited for until its `step_done` event, within --timeout."""
    from std_msgs.msg import String
    events: list[str] = []
    ctl.subscribe("events", String, lambda m: events.append(m.data), qos=_volatile_events_qos())
    old = None
    if n is not None:
        old = ctl.get_params(["step_count"])["step_count"]
        ctl.set_param("step_count", n)
    try:
        r = ctl.trigger("step")
    finally:
        if old is not None:
            ctl.set_param("step_count", old)
    if not r["message"].startswith("accepted"):
        return r

    def done() -> dict | None:
        for text in events:
            try:
                doc = json.loads(text)
            except ValueError:
                continue
            if doc.get("code") == "step_done":
                return doc
        return None
    end = time.monotonic() + ctl.timeout_s
    while time.monotonic() < end:
        ctl.executor.spin_once(timeout_sec=0.05)
        doc = done()
        if doc is not None:
            if doc.get("severity") != "info":
                raise CtlError(f"{ctl.target}/step: {doc.get('message', 'stopped')}")
            return {**r, "message": str(doc.get("message", "done")), "event": doc}
    return {**r, "message": r["message"] + f" (still running after --timeout {ctl.timeout_s:g} s)"}


def brake(ctl: Ctl, engage: bool) -> dict:
    """Engage or release the brake: on the node's owned `~/brake_command` topic where it has one
    (the brake is owned like the commands), else through its `~/brake` service."""
    from std_msgs.msg import Bool
    topic = ctl.topic("brake_command")
    # DDS discovers a node's endpoints one by one, so its services may be known before this reader; the service
    # is for a node that still shows no such reader after a while (the topic is where a command is owned)
    if not ctl.wait_until(lambda: ctl.node.count_subscribers(topic) > 0, BRAKE_TOPIC_WAIT_S):
        return ctl.trigger("brake", engage)
    return send_owned(ctl, "brake_command", Bool(data=engage), f"brake {'on' if engage else 'off'}")


def run(args) -> int:
    emit = _emitter(args.json)
    if args.verb == "param" and args.action in ("get", "set") and not args.names:
        raise CtlError(f"param {args.action}: expected a NAME")
    ctl = Ctl(args.node, args.timeout)
    try:
        ctl.wait_for_node()
        v = args.verb
        if v in ("pause", "resume"):
            r = ctl.trigger("pause", v == "pause")
            emit(r, r["message"])
        elif v == "step":
            r = step(ctl, args.n)
            emit(r, r["message"])
        elif v in ("reset", "release"):
            r = ctl.trigger("reset" if v == "reset" else "release_control")
            emit(r, r["message"])
        elif v == "brake":
            r = brake(ctl, args.on_off == "on")
            emit(r, r["message"])
        elif v == "interface":
            r = ctl.set_param("command_interface", args.interface)
            emit(r, f"command_interface = {args.interface}")
        else:
            {"state": cmd_state, "events": cmd_events, "param": cmd_param, "command": cmd_command,
             "fault": cmd_fault, "play": _play}[v](ctl, args, emit)
    finally:
        ctl.close()
    return 0


def _play(ctl: Ctl, args, emit) -> None:
    from prsm_ros.cli.ctl_play import cmd_play
    cmd_play(ctl, args, emit, CtlError)


def _emitter(as_json: bool) -> Callable[[Any, str], None]:
    from prsm_ros.json_out import jsonable

    def emit(record: Any, text: str) -> None:
        print(json.dumps(jsonable(record), ensure_ascii=False, allow_nan=False) if as_json else text, flush=True)
    return emit


def _positive_int(v: str) -> int:
    try:
        n = int(v)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"{v!r}: must be a whole number >= 1")
    return n


def _positive_float(v: str) -> float:
    try:
        x = float(v)
    except ValueError:
        x = math.nan
    if not (math.isfinite(x) and x > 0):
        raise argparse.ArgumentTypeError(f"{v!r}: must be a positive number")
    return x


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    # SUPPRESS: given before or after the verb, the option keeps the value given
    common.add_argument("--node", default=argparse.SUPPRESS, metavar="NAME",
                        help=f"the node's full name (default {DEFAULT_NODE})")
    common.add_argument("--timeout", type=_positive_float, default=argparse.SUPPRESS, metavar="S",
                        help="seconds to wait for the node, a service or a reader (default 10)")
    common.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help="one JSON object per line")
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0], parents=[common],
                                 epilog="See the module help: python -m prsm_ros.cli.ctl --help; README.md and docs/ros.md.")
    from prsm_sim import __version__
    ap.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = ap.add_subparsers(dest="verb", required=True, metavar="VERB")
    sub.add_parser("pause", parents=[common], help="pause stepping (~/pause true)")
    sub.add_parser("resume", parents=[common], help="resume stepping (~/pause false)")
    st = sub.add_parser("step", parents=[common], help="advance N steps while paused (~/step)")
    st.add_argument("n", nargs="?", type=_positive_int, metavar="N", help="steps (default: the node's step_count)")
    sub.add_parser("reset", parents=[common], help="time zero, at rest (~/reset)")
    s = sub.add_parser("state", parents=[common], help="the current state in one line")
    s.add_argument("--follow", action="store_true", help="keep printing until Ctrl-C")
    s.add_argument("--rate", type=_positive_float, default=10.0, metavar="HZ", help="lines per second with --follow")
    p = sub.add_parser("param", parents=[common], help="get, set, list or dump the node's parameters")
    p.add_argument("action", choices=("get", "set", "list", "dump"))
    p.add_argument("names", nargs="*", metavar="ARG", help="get: NAME...; set: NAME VALUE; list: [PREFIX]")
    i = sub.add_parser("interface", parents=[common], help="switch the command interface")
    i.add_argument("interface", choices=INTERFACES)
    c = sub.add_parser("command", parents=[common], help="send one command on the active interface")
    c.add_argument("kind", choices=tuple(COMMAND_KINDS))
    c.add_argument("value", metavar="VALUE", help="N·m (torque), screw rad/s (velocity), nut m (position)")
    f = sub.add_parser("fault", parents=[common], help="inject or clear actuator faults")
    f.add_argument("action", choices=("inject", "clear"))
    f.add_argument("spec", nargs="*", metavar="ARG", help="KIND [key=value ...] (start_s, duration_s, value, sensor)")
    b = sub.add_parser("brake", parents=[common], help="engage or release the holding brake")
    b.add_argument("on_off", choices=("on", "off"))
    sub.add_parser("release", parents=[common], help="give up ownership of the actuator (~/release_control)")
    e = sub.add_parser("events", parents=[common], help="the node's events (latched history)")
    e.add_argument("--follow", action="store_true", help="keep printing new events until Ctrl-C")
    from prsm_ros.cli.ctl_play import register as register_play  # play FILE.csv: a verb of its own module
    register_play(sub, common)
    return ap


def _negative_number(arg: str) -> bool:
    return arg.startswith("-") and _number(arg) is not None


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    # argparse takes "-1e-1" for an option (it knows only "-1" and "-.5" as numbers): a leading space keeps
    # a negative number a value, and every consumer strips it
    args = ap.parse_args([" " + a if _negative_number(a) else a for a in argv])
    args.node = getattr(args, "node", DEFAULT_NODE)
    args.timeout = getattr(args, "timeout", 10.0)
    args.json = getattr(args, "json", False)
    try:
        _split_node(args.node)
        return run(args)
    except CtlError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"{PROG}: error: {e.name or e} is not installed; install the ros extra: pip install 'prsm[ros]'",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        interrupt_handled()
        print(f"{PROG}: interrupted (what was printed above is complete)", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
