"""`prsm-node`: the simulated PRSM actuator on the ROS 2 graph.

    prsm-node --ros-args --params-file my_params.yaml -p time_mode:=lockstep
    prsm-node --params-template > my_params.yaml       # every parameter, its unit and range
    prsm-node --help

The node is transport: it declares its parameters (`declare`, from `parameters`), hands every
command message to the runtime session (`prsm_sim.Session`: command gate, watchdog, actuator,
faults), steps it on its clock, and turns each step's outputs into messages (`messages`,
`cdr_write`) for the publishers, the MCAP recorder and the Rerun sink (`sinks`), and the session's
status into /diagnostics and ~/events (`diagnostics`).

Time modes. `realtime`: a dedicated thread steps on absolute deadlines (`pacing.DeadlinePacer`);
`fast`: the same thread without sleeping; in both, that thread takes the commands waiting on
the command topics itself before each step (`command_poll`: no executor wake-up per command, the
main cost at 1 kHz otherwise). `lockstep`: every message received on a command topic
(valid or not: the controller's tick keeps the loop going) advances `lockstep_steps` steps in the
command callback, so a slow controller or a debugger never breaks the loop and the same command
sequence always gives the same states. `/clock` is published on every step; joint_states and the
wrench at `joint_states_rate` (and after every lockstep batch), internal loads at
`internal_loads_rate`. Nothing is published before the first step.

What nobody reads costs little (node CPU at 1 kHz): in realtime and fast mode a per-step
topic whose publisher had no matched reader at the last count (every `READER_COUNT_EVERY` steps) asks
for its reader count before each message instead of publishing it (2-3 µs against about 8 µs for a
publish to nobody, paced at 1 kHz on the 2-core VM) and, while it has none, goes only to the bag.
These topics are volatile, so DDS would have delivered such a sample to nobody; a reader gets every
message from the moment the node's publisher has matched it, as without this rule (a command's echo
included). A publisher made transient-local by a QoS override is always published; lockstep always
publishes (a controller waits for each state).

Services (std_srvs): `~/pause` (SetBool: true pauses, false resumes), `~/step` (Trigger: advances
`step_count` steps, only while paused — std_srvs has no integer request, so the count is a
parameter; more than a second of steps is answered "accepted" and ends with a `step_done` event,
`step_jobs`), `~/reset` (Trigger: time zero, at rest at `initial_nut_position`, command and
counters cleared, fault cleared). SIGINT and SIGTERM stop the node cleanly (exit 0, MCAP closed)
whatever is in flight.

Every input is decided per writer: commands, `~/inject_fault` and `~/brake_command` come from the
owner (or anyone while nobody owns the actuator); everything refused is reported once per writer
and reason, then counted (`refusals`), so a flood reaches neither `~/events` nor the bag.
"""

from __future__ import annotations

import functools
import math
import struct
import sys
import threading
import time
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock as RosClock
from rclpy.clock_type import ClockType
from rclpy.exceptions import InvalidHandle, ParameterException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSPolicyKind
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import SetBool, Trigger

from prsm_sim import ModelError, Session, SessionConfig

from prsm_ros.cdr_read import float64_data, joint_state_stamp_effort0
from prsm_ros.node.command_echo import CommandEcho, stamp_of
from prsm_ros.node.command_poll import CommandPoller, PolledGroup
from prsm_ros.node.declare import check_unknown_overrides, declare_parameters
from prsm_ros.node.diagnostics import (FAULT_LOG_LENGTH, Report, energy_fault_event, fault_event_details,
                                       fault_event_line, fault_event_report, simulation_report)
from prsm_ros.node.command_sequence import SupersededCounter
from prsm_ros.node.owned_inputs import OWNED_INPUTS
from prsm_ros.node.ownership import COMMAND_QUEUE_DEPTH, CommandOwnership, participant_name, participant_of
from prsm_ros.node.refusals import Refusals, short
from prsm_ros.node.sinks import open_sinks
from prsm_ros.messages import NODE_NAME, TOPICS, MessageMapper, event_message, stamp, time_ns, with_depth
from prsm_ros.node.parameters import (PHYSICS_PREFIX, ConfigError, ParamSources,
                                      runtime_change)
from prsm_ros.node.urdf import urdf_for_node
from prsm_ros.node.joint_commands import offer_joint_command
from prsm_ros.node.pacing import DeadlinePacer, every_n_steps, reduce_timer_slack, request_realtime_priority
from prsm_ros.node.step_jobs import (INLINE_STEPS, INLINE_WAIT_S, STEP_REQUEST, StepJobs, answer, done_event,
                                     request_refused, stop_reason)

# diagnostics.OK, WARN, ERROR as DiagnosticStatus levels
DIAGNOSTIC_LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
WARN_THROTTLE_S = 2.0  # wall seconds between repeated warnings about bad commands
# fast mode, and realtime mode while it catches up on late steps: a thread that never sleeps keeps
# the GIL and the lock from the executor (services, parameters) — it re-takes the lock before a waiting
# thread wakes — so it really sleeps briefly every few steps that did not sleep.
FAST_YIELD_EVERY = 32
FAST_YIELD_S = 2e-5
OVERRIDABLE_QOS = (QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH, QoSPolicyKind.RELIABILITY, QoSPolicyKind.DURABILITY)
REALTIME_SWITCH_INTERVAL_S = 1e-4  # GIL hand-over bound in realtime mode (Python's default: 5 ms)
# Shutdown waits, each bounded so SIGTERM always ends the process (ros_procs.NodeProcess.stop allows 20 s).
STEP_THREAD_STOP_S = 5.0  # a step in progress (a stiff model step) finishes well within this
RECORDER_CLOSE_S = 5.0  # the queue (at most queue_size messages) and the summary; a stalled disk gives up
RERUN_CLOSE_S = 5.0
PAUSED_POLL_S = 0.05  # paused: wall time between two takes of the commands waiting
PAUSED_POLL_BUSY_S = 0.005  # ... when the last take found some (COMMAND_QUEUE_DEPTH at 10 kHz is 10 ms)
READER_COUNT_EVERY = 50  # steps between two counts of the per-step topics' matched readers (module doc)
# the command topics and the interface each commands (joint_commands: the active one; the reference is only recorded)
COMMAND_TOPICS = {"screw_torque": "effort", "velocity_command": "velocity", "position_command": "position",
                  "joint_commands": None, "nut_position_reference": None}


# Topics whose content is wall-clock (health counters, commands' DDS source stamps): a lockstep bag leaves them
# out so that it is the same bytes for the same run; they are still published.
WALL_CLOCK_TOPICS = ("diagnostics", "command_echo")


def _unmatched(pub) -> bool:
    """True when `pub` has no matched reader (or is destroyed, at shutdown: nobody to publish to either)."""
    try:
        return pub.get_subscription_count() == 0
    except InvalidHandle:
        return True


class PrsmNode(Node):
    """Publishers, subscriptions, services and the step loop; all logic lives in the helpers."""

    def __init__(self, param_sources: ParamSources | None = None, **node_kwargs: Any) -> None:
        self.param_sources = param_sources  # where the start-up names came from (the command line); None: all ours
        super().__init__(NODE_NAME, **node_kwargs)
        self.recorder = self.rerun = self.live = None
        self._unrecorded: frozenset[str] = frozenset()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._resumed = threading.Event()
        try:
            self._setup()
        except BaseException:
            self.close()  # our threads and files; the caller decides about the rcl node
            raise

    def _setup(self) -> None:
        self.config = declare_parameters(self)
        cfg = self.config
        self._lock = threading.Lock()
        self.ownership = CommandOwnership(cfg.ownership_timeout, enabled=cfg.command_ownership)
        self.echo = CommandEcho()
        self.superseded = SupersededCounter()  # commands replaced in a reader's queue before a step took them
        self.session = Session.from_config(SessionConfig(
            params=cfg.params, model=cfg.model, dt_s=cfg.dt_s, actuator=cfg.actuator if cfg.with_actuator else None,
            nut_position_m=cfg.initial_nut_position, load_n=cfg.load_force,
            initial_load_n=cfg.load_force,  # starts in equilibrium at its load
            interface=cfg.command_interface, max_effort_nm=cfg.max_effort, cmd_timeout_s=cfg.cmd_timeout,
            timeout_behaviour=cfg.timeout_behaviour, paused=cfg.start_paused or cfg.wait_for_controller))
        self.mapper = MessageMapper(self.session.layout, cfg.model, joint_names=cfg.joint_names,
                                    nut_frame=cfg.values["frames.nut"])
        # which joint takes which command interface, with the joints' configured names
        self._joints = {"position": cfg.joint_names[1], "velocity": cfg.joint_names[0], "effort": cfg.joint_names[0]}
        self.encoder = self.mapper.encoder()  # per-step messages straight to CDR bytes
        self._batch: list | None = None  # a step's messages for the bag, handed over at once (`_advance`)
        self._set_decimation()

        self._create_topics()
        check_unknown_overrides(self, self.param_sources)
        self.scheduling = {"step_thread": "normal", "other_threads": "normal"}
        if cfg.time_mode == "realtime":
            self._prepare_realtime()
        # lockstep: the bag is the same bytes for the same run (a golden file), so nothing wall-clock goes in
        self._unrecorded = frozenset(WALL_CLOCK_TOPICS) if cfg.time_mode == "lockstep" else frozenset()
        channels = {name: (TOPICS[k].msg_class, (self.pub.get(k) or self.sub[k]).qos_profile, k in self.sub)
                    for k, name in self._topic_names.items() if k not in self._unrecorded}
        self.recorder, self.rerun, self.live = open_sinks(cfg, self.get_fully_qualified_name(), channels,
                                                          self.session.layout)

        for srv_type, name, callback in ((SetBool, "~/pause", self._srv_pause), (Trigger, "~/step", self._srv_step),
                                         (Trigger, "~/reset", self._srv_reset),
                                         (Trigger, "~/release_control", self._srv_release_control),
                                         (SetBool, "~/brake", self._srv_brake),
                                         (Trigger, "~/clear_faults", self._srv_clear_faults)):
            self.create_service(srv_type, name, callback)
        self._fault_log: list[str] = []  # the last fault starts and clears, for /diagnostics
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._steady = RosClock(clock_type=ClockType.STEADY_TIME)  # diagnostics follow wall time, never /clock
        self._diag_timer = self.create_timer(1.0 / cfg.diagnostics_rate, self._publish_diagnostics, clock=self._steady)
        self._diag_last = (time.perf_counter(), 0.0, 0)  # wall s, sim s, overruns at the last report
        self._warned_at: dict[str, float] = {}
        self.publish_failures = 0
        self._energy_fault_reported = False  # one ~/events entry per run (until ~/reset)
        self._model_failure_reported = False  # likewise
        self._step_wall_max_s = 0.0
        self._publish(self.pub["labels"], "labels", self.mapper.labels())
        self._publish(self.pub["robot_description"], "robot_description",
                      String(data=urdf_for_node(cfg, self.get_name(), self.get_namespace())))
        # wait_for_controller: paused until the first command accepted from a controller (`_hand_over`)
        self._await_controller = cfg.wait_for_controller

        self.pacer = DeadlinePacer(cfg.dt_s, cfg.real_time_factor, spin_s=cfg.pacing_spin)
        self.refusals = Refusals()
        self.jobs = StepJobs(self._step_slice, self._step_job_done, self._stop)
        if cfg.time_mode != "lockstep":
            self._thread = threading.Thread(target=self._loop, name="prsm-step-loop", daemon=True)
            self._thread.start()
        self.get_logger().info(
            f"{cfg.model} model, preset {cfg.preset}, {cfg.update_rate} Hz, {cfg.time_mode}"
            + (f" ×{cfg.real_time_factor:g}" if cfg.time_mode == "realtime" else "")
            + (f", recording to {self.recorder.path}" if self.recorder else "")
            + (f", serving Foxglove on {self.live.url}" if self.live else "")
            + (", waiting for a controller's first command" if cfg.wait_for_controller
               else ", paused" if cfg.start_paused else ""))

    def _create_topics(self) -> None:
        """Publishers, command subscriptions (polled by the step thread in realtime and fast mode), topic names."""
        cfg = self.config

        def qos_opts() -> QoSOverridingOptions:  # qos_overrides.<topic>.<publisher|subscription>.<policy>
            return QoSOverridingOptions(policy_kinds=OVERRIDABLE_QOS)
        try:
            self.pub = {k: self.create_publisher(TOPICS[k].msg_class, self._topic(k), TOPICS[k].qos,
                                                 qos_overriding_options=qos_opts())
                        for k in ("joint_states", "wrench", "internal_loads", "labels", "command_echo", "diagnostics",
                                  "events", "robot_description") + (("clock",) if cfg.publish_clock else ())
                        + (("ground_truth",) if self.session.actuator is not None else ())}
            # commands arrive as raw CDR (recorded as they are); in realtime and fast mode the step
            # thread takes them itself before each step (command_poll), in lockstep the executor
            # delivers them because a command is what advances time
            polled = cfg.time_mode != "lockstep"
            group = PolledGroup() if polled else None
            # every input is decided per writer: a reader queue deep enough that a fast writer cannot push
            # the owner's messages out between two takes (ownership.COMMAND_QUEUE_DEPTH)
            self.sub = {k: self.create_subscription(TOPICS[k].msg_class, self._topic(k),
                                                    functools.partial(self._on_command_message, k),
                                                    with_depth(TOPICS[k].qos, COMMAND_QUEUE_DEPTH),
                                                    qos_overriding_options=qos_opts(), raw=True, callback_group=group)
                        for k in COMMAND_TOPICS}
            for k in OWNED_INPUTS:
                self.sub[k] = self.create_subscription(
                    TOPICS[k].msg_class, self._topic(k), functools.partial(self._on_owned_input, k),
                    with_depth(TOPICS[k].qos, COMMAND_QUEUE_DEPTH), qos_overriding_options=qos_opts())
        except (InvalidQosOverridesError, ParameterException) as e:
            raise ConfigError(f"QoS override: {e}") from None
        self.poller = CommandPoller()
        if polled:
            for k in COMMAND_TOPICS:
                self.poller.add(k, self.sub[k], self._on_command)
        self._topic_names = {k: p.topic_name for k, p in self.pub.items()}
        # realtime and fast: a per-step topic with no matched reader is not handed to DDS (module doc)
        self._unread: frozenset[str] = frozenset()
        self._skippable = () if cfg.time_mode == "lockstep" else tuple(
            k for k in ("joint_states", "ground_truth", "wrench", "internal_loads", "command_echo", "clock")
            if k in self.pub and self.pub[k].qos_profile.durability == DurabilityPolicy.VOLATILE)
        self._topic_names.update({k: s.topic_name for k, s in self.sub.items()})

    def _prepare_realtime(self) -> None:
        """Realtime mode: keep the step thread from waiting for the GIL (measured in bench_node).

        The step thread wakes on time under SCHED_FIFO, but then needs the GIL; if the thread
        holding it (executor, recorder) is a normal thread the OS has preempted, the step waits
        for milliseconds (priority inversion). So this thread, and the threads started after it
        (recorder, Rerun), run SCHED_FIFO one level below the step thread when the OS allows, and
        a waiting thread gets the GIL after 100 µs instead of Python's default 5 ms.
        """
        prio = self.config.realtime_priority
        if prio > 1:
            self.scheduling["other_threads"] = request_realtime_priority(prio - 1)
        sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)

    # -- parameters ------------------------------------------------------------------------
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        ours = {p.name: p.value for p in parameters if p.name in self.config.values or p.name.startswith(PHYSICS_PREFIX)}
        if not ours:
            return SetParametersResult(successful=True)
        try:
            new = runtime_change(self.config, ours)
        except ConfigError as e:
            return SetParametersResult(successful=False, reason=str(e))
        with self._lock:
            if new.command_interface != self.config.command_interface:
                reason = self.session.set_interface(new.command_interface)
                if reason is not None:
                    if self.session.actuator is None:
                        reason += "; start the node with an actuator (e.g. -p actuator:='{}') to switch"
                    return SetParametersResult(successful=False, reason=reason)
            old, self.config = self.config, new
            self.session.configure_gate(new.max_effort, new.cmd_timeout, new.timeout_behaviour)
            self.session.load_n = self.session.initial_load_n = new.load_force
            self.session.nut_position_m = new.initial_nut_position
            if new.params != old.params:
                self.session.rebuild(new.params)
            if new.real_time_factor != old.real_time_factor:
                self.pacer.set_rate(new.real_time_factor)
            self._set_decimation()
        if new.diagnostics_rate != old.diagnostics_rate:
            self._diag_timer.timer_period_ns = int(1e9 / new.diagnostics_rate)
        self.get_logger().info("parameters changed: " + ", ".join(f"{k} = {v!r}" for k, v in ours.items()))
        return SetParametersResult(successful=True)

    def _set_decimation(self) -> None:
        cfg = self.config
        self._js_every = every_n_steps(cfg.joint_states_rate, cfg.update_rate)
        # heavy outputs are decimated on DDS only in realtime and fast mode; the bag records every step
        self._il_every = 1 if cfg.time_mode == "lockstep" else every_n_steps(cfg.internal_loads_rate, cfg.update_rate)

    def _topic(self, key: str) -> str:
        return self.config.topics.get(key, TOPICS[key].name)

    # -- publishing and recording -----------------------------------------------------------
    def _publish(self, pub, key: str, msg, stamp_ns: int | None = None) -> None:
        """Serialise once (per-step messages come as CDR bytes already), publish and record the same bytes."""
        if type(msg) is not bytes:
            msg = serialize_message(msg)
        if key in self._unread:  # no reader at the last count: ask again, a publish to nobody is dearer
            if _unmatched(pub):  # DDS would deliver it to nobody (volatile): the bag only
                self._record(key, msg, stamp_ns)
                return
            self._unread = self._unread - {key}  # a reader matched since: it gets this message on
        try:
            handle = pub.handle  # rclpy's Publisher.publish minus its type dispatch: always bytes here
            with handle:
                handle.publish_raw(msg)
        except Exception as e:  # the middleware refused one sample (e.g. a stalled reliable reader): count it
            if not rclpy.ok(context=self.context):
                raise
            self.publish_failures += 1
            self._warn_throttled(f"publish:{key}", f"publishing on {self._topic_names[key]} failed "
                                                   f"({self.publish_failures} so far): {e}")
        self._record(key, msg, stamp_ns)

    def _record(self, key: str, data, stamp_ns: int | None = None) -> None:
        """Into the bag (lock held): with the step's batch when a step is being published, else at once."""
        if (self.recorder is None and self.live is None) or key in self._unrecorded:
            return
        item = (self._topic_names[key], data, time_ns(self.session.time_s) if stamp_ns is None else stamp_ns)
        if self.live is not None:  # the live view gets what the bag gets, as it happens
            self.live.write(*item)
        if self.recorder is None:
            return
        if self._batch is not None:
            self._batch.append(item)
        else:
            self.recorder.write(*item)

    # -- commands in -----------------------------------------------------------------------
    def _on_command_message(self, key: str, raw: bytes, info) -> None:
        """Executor callback (lockstep): one raw command message."""
        with self._lock:
            self._on_command(key, raw, info)

    def _on_command(self, key: str, raw: bytes, info: dict) -> None:
        """Lock held: one command message as CDR bytes, from the executor (lockstep) or the step thread's poll.

        Refused when another participant owns the actuator (counted, not recorded, and in lockstep
        it does not advance time: a flood from another writer costs a counter per message); else
        recorded when it decodes and offered to the gate, and an accepted command makes its sender
        the owner and is echoed with the step that applies it (every command topic). A reference
        is recorded only (from the owner, or from anyone while nobody owns the actuator).
        """
        self.superseded.observe(key, info)  # before anything refuses it: the writer's numbering counts every sample
        who = participant_of(info)
        reason = self.ownership.admit(who)
        if reason is not None:
            self._refused(who, "not_owner", f"{self._topic_names[key]}: {reason}")
            return
        if key == "nut_position_reference":
            # at the stamp of the state it answers, not at the moment it arrived (that races the steps)
            self._record(key, raw, _reference_stamp_ns(raw))
            return
        reason, header_ns, malformed = self._offer(key, raw)
        if malformed:  # not this type's CDR: kept out of the bag
            self._refused(who, f"{key}_malformed", f"{self._topic_names[key]}: {reason}")
            return
        self._record(key, raw)
        if reason is None:
            self.ownership.accepted(who)
            self.echo.offer(stamp_of(header_ns, info.get("source_timestamp")), self._topic_names[key])
            if self._await_controller:
                self._hand_over(key, who)
        else:
            self._refused(who, f"{key}_refused", f"{self._topic_names[key]}: {reason}")
        self._after_command(key, reason)

    def _hand_over(self, key: str, who) -> None:
        """Lock held: wait_for_controller's first accepted command resumes the node (logged, on ~/events)."""
        self._await_controller = False
        self.session.resume()
        self._resumed.set()
        text = (f"resumed at t = {self.session.time_s:.6f} s by the first command on {self._topic_names[key]} "
                f"(controller {participant_name(who)})")
        self.get_logger().info(text)
        self._publish(self.pub["events"], "events", event_message(
            self.session.time_s, "node", "info", "controller_resumed", text, {"topic": self._topic_names[key],
                                                                             "participant": participant_name(who)}))

    def _refused(self, who: bytes | None, code: str, text: str) -> None:
        """Lock held: count a refusal (refusals); the first of a writer for a reason is logged and put on ~/events."""
        writer = participant_name(who)
        if self.refusals.refuse(writer, code):
            text = short(text)
            self.get_logger().warning(f"{text} (further refusals of this kind from {writer} are only counted "
                                      "on /diagnostics)")
            self._publish(self.pub["events"], "events", event_message(
                self.session.time_s, "refusals", "warn", code, text, {"writer": writer}))

    def _offer(self, key: str, raw: bytes) -> tuple[str | None, int | None, bool]:
        """A command's CDR bytes to the session: (the reason it was refused or None, a JointState's header
        stamp ns, whether the bytes were malformed)."""
        try:
            if key != "joint_commands":
                return self.session.offer(COMMAND_TOPICS[key], _float64(raw)), None, False
            msg = deserialize_message(raw, JointState)
            arrays = {"position": msg.position, "velocity": msg.velocity, "effort": msg.effort}
            return (offer_joint_command(self.session, msg.name, arrays, self._joints),
                    msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, False)
        except Exception as e:  # bytes that are not this type's CDR (a raw publisher): refused, never raised
            return self.session.refuse_malformed(f"a {len(raw)}-byte message that is not a valid "
                                                 f"{TOPICS[key].msg_class.__name__} ({type(e).__name__}: {e})"), None, True

    def _on_owned_input(self, key: str, msg, info) -> None:
        """~/inject_fault, ~/brake_command (owned_inputs): from the owner, or anyone while nobody owns the actuator."""
        with self._lock:
            who = participant_of(info)
            reason, code = self.ownership.admit(who), f"{key}_not_owner"
            if reason is None:
                self._record(key, msg)
                reason, code = OWNED_INPUTS[key](self.session, msg), f"{key}_refused"
            if reason is not None:
                self._refused(who, code, f"{self._topic_names[key]}: {reason}")

    def _after_command(self, key: str, reason: str | None) -> None:
        """Called with the lock held after a command: step in lockstep (a long request on the jobs thread)."""
        if self.config.time_mode == "lockstep" and not self.session.paused and not self._stop.is_set():
            n = self.config.lockstep_steps
            if n <= INLINE_STEPS and not self.jobs.busy:
                self._advance(n, publish_last_state=True)
            else:  # more than a moment of work: on the jobs thread, in slices (step_jobs)
                self.jobs.submit(n, "lockstep command")

    def _warn_throttled(self, key: str, text: str) -> None:
        now = time.monotonic()
        if now - self._warned_at.get(key, -math.inf) >= WARN_THROTTLE_S:
            self._warned_at[key] = now
            self.get_logger().warning(text)

    # -- stepping --------------------------------------------------------------------------
    def _advance(self, n: int, publish_last_state: bool = False) -> int:
        """Step n times and publish (lock held); the last state is always published when asked
        (a lockstep controller waits for it). Returns the steps done (fewer after a fault)."""
        done = 0
        rec = self.recorder
        for i in range(n):
            t0 = time.perf_counter()
            # the step's messages (the commands it takes, the states it publishes) go to the bag in
            # one hand-over: one lock and one queue append per step instead of one per message
            self._batch = [] if rec is not None else None
            try:
                self.poller.poll()  # realtime and fast: the commands that arrived since the last step
                try:
                    out = self.session.step()
                except ModelError as e:
                    self._report_model_failure(str(e))
                    break
                done += 1
                if out.energy_fault and not self._energy_fault_reported:
                    self._report_energy_fault(out)
                self._publish_step(out, force_state=publish_last_state and i == n - 1)
            except Exception as e:  # never let a publishing failure take the process down
                if not rclpy.ok(context=self.context):
                    break
                self.session.fail(f"publishing step {self.session.nstep} failed: {type(e).__name__}: {e}")
                self.get_logger().error(self.session.fault)
                break
            finally:
                batch, self._batch = self._batch, None
                if batch:
                    rec.write_many(batch)
            self._step_wall_max_s = max(self._step_wall_max_s, time.perf_counter() - t0)
        return done

    def _report_energy_fault(self, out) -> None:
        """The model's energy books stopped closing (the core's energy guard): one event, an error log;
        /diagnostics says ERROR while it lasts. Stepping goes on: the user decides."""
        self._energy_fault_reported = True
        text, details = energy_fault_event(out.time_s, out.energy_flow_j, out.energy_residual_j, self.config.model)
        self._publish(self.pub["events"], "events", event_message(out.time_s, "energy_guard", "error",
                                                                   "energy_balance", text, details))
        self.get_logger().error(text)

    def _report_model_failure(self, reason: str) -> None:
        """The model failed (Session's ModelError): stepping stops until ~/reset; /diagnostics says
        ERROR with the reason while it lasts, and one ~/events entry (so the bag) says when and why."""
        self.get_logger().error(reason, throttle_duration_sec=WARN_THROTTLE_S)
        if self._model_failure_reported:
            return
        self._model_failure_reported = True
        self._publish(self.pub["events"], "events", event_message(self.session.time_s, "model", "error",
                                                                   "model_failure", reason, {"model": self.config.model}))

    def _count_readers(self) -> None:
        """Note which per-step topics have no matched reader now (lock held; `_publish` skips them on DDS)."""
        self._unread = frozenset(key for key in self._skippable if _unmatched(self.pub[key]))

    def _publish_step(self, out, force_state: bool = False) -> None:
        k = self.session.nstep
        ns = time_ns(out.time_s)
        enc = self.encoder
        if k % READER_COUNT_EVERY == 0:
            self._count_readers()
        # joint_states first: a lockstep controller computes its next command while the rest goes out
        if force_state or k % self._js_every == 0:
            self._publish_state(out, ns)
        if self.session.pending_events:
            self._publish_fault_events(self.session.take_events())
        if self.session.pending_edge_events:
            self._publish_edge_events(self.session.take_edge_events())
        echoed = self.echo.take()
        if echoed is not None:
            cmd_ns, source = echoed
            self._publish(self.pub["command_echo"], "command_echo", enc.time_reference(ns, cmd_ns, source), ns)
            self.echo.record_latency(cmd_ns, time.time_ns())
        if "clock" in self.pub:
            self._publish(self.pub["clock"], "clock", enc.clock(ns), ns)
        if k % self._il_every == 0:
            self._publish(self.pub["internal_loads"], "internal_loads", enc.internal_loads(out), ns)
        elif self.recorder is not None:  # decimated on DDS, every step in the bag
            self._record("internal_loads", enc.internal_loads(out), ns)
        if self.rerun is not None:
            self.rerun.submit(out)

    def _publish_state(self, out, ns: int) -> None:
        """joint_states and the wrench; with an actuator joint_states carries what the sensors
        measure, and the truth goes beside it on ground_truth."""
        enc, act = self.encoder, self.session.actuator
        if act is not None:
            self._publish(self.pub["ground_truth"], "ground_truth", enc.joint_state(out, ns), ns)
        self._publish(self.pub["joint_states"], "joint_states",
                      enc.joint_state(act.measured(out) if act is not None else out, ns), ns)
        self._publish(self.pub["wrench"], "wrench", enc.wrench(out, ns), ns)

    def _publish_rest_state(self) -> None:
        """Lock held: the state just set (reset) on the state topics at once, though no step ran."""
        out = self.session.rest_outputs()
        ns = time_ns(out.time_s)
        self._publish_state(out, ns)
        if "clock" in self.pub:
            self._publish(self.pub["clock"], "clock", self.encoder.clock(ns), ns)

    def _loop(self) -> None:
        """realtime / fast: the step thread (lockstep steps in the command callback instead)."""
        reduce_timer_slack()
        realtime = self.config.time_mode == "realtime"
        if realtime:  # never for fast mode: a busy SCHED_FIFO thread would starve the machine
            self.scheduling["step_thread"] = request_realtime_priority(self.config.realtime_priority)
        self.pacer.restart()
        was_running = False
        unslept = 0  # steps since the thread last slept (and so let the executor take the lock)
        while not self._stop.is_set():
            if self.session.paused or self.session.fault is not None:
                was_running = False
                self._idle()
                continue
            if not was_running:
                self.pacer.restart()
                was_running = True
            if realtime:
                # half a period late: this step was not slept for (catch-up), nor will the next one be
                behind = self.pacer.wait() > 0.5 * self.pacer.period_s
            else:
                self.pacer.count_step()
                behind = True
                self._wait_for_recorder()
            unslept = unslept + 1 if behind else 0
            if unslept >= FAST_YIELD_EVERY:  # an overloaded machine must not starve the services
                time.sleep(FAST_YIELD_S)
                unslept = 0
            try:
                with self._lock:
                    if not self.session.paused:
                        self._advance(1)
            except Exception as e:  # a publish after shutdown, or a bug: never kill the process from here
                if self._stop.is_set() or not rclpy.ok(context=self.context):
                    return
                self.session.fail(f"step loop error: {type(e).__name__}: {e}")
                self.get_logger().error(self.session.fault)

    def _idle(self) -> None:
        """Paused or faulted: commands still count, own and reach the bag while nothing steps."""
        try:
            with self._lock:
                taken = self.poller.sweep()
        except Exception as e:  # a bug: logged, never the end of the step thread
            taken = 0
            self._warn_throttled("poll", f"taking commands failed: {type(e).__name__}: {e}")
        # commands waiting: come back before a flood can overrun the reader queue (COMMAND_QUEUE_DEPTH)
        self._resumed.wait(PAUSED_POLL_BUSY_S if taken else PAUSED_POLL_S)

    def _wait_for_recorder(self) -> None:
        """`fast` mode has no deadline to keep: when the bag writer falls behind (a busy machine),
        wait for it to drain to half its queue rather than drop messages from the bag."""
        rec = self.recorder
        if rec is None:
            return
        while rec.backlog() > rec.queue_size // 2 and rec.error is None and not self._stop.is_set():
            time.sleep(FAST_YIELD_S)

    # -- services --------------------------------------------------------------------------
    def _srv_pause(self, request, response):
        with self._lock:
            if request.data:
                self.session.pause()
                self._resumed.clear()
            else:
                self.session.resume()
                self._resumed.set()
            response.success = True
            response.message = f"{'paused' if self.session.paused else 'running'} at t = {self.session.time_s:.6f} s"
        return response

    def _srv_step(self, request, response):
        """`step_count` steps on the jobs thread: answered when done within INLINE_WAIT_S, else "accepted"
        at once and a `step_done` event when they end (step_jobs)."""
        with self._lock:
            refused = request_refused(self.session, self.jobs)
            if refused:
                response.success, response.message = False, refused
                return response
            job = self.jobs.submit(self.config.step_count, STEP_REQUEST)
        response.success, response.message = answer(job, self.jobs.wait_or_detach(job, INLINE_WAIT_S),
                                                     self.session.time_s)
        return response

    def _step_slice(self, job, n: int) -> tuple[int, str | None]:
        """Jobs thread: up to `n` steps of `job` under the lock (the state published after the last)."""
        with self._lock:
            why = stop_reason(job, self.session, self._stop.is_set())
            return (0, why) if why else (self._advance(n, publish_last_state=n == job.remaining), None)

    def _step_job_done(self, job) -> None:
        """Jobs thread: a request answered "accepted" has ended: an event says how."""
        with self._lock:
            msg = event_message(self.session.time_s, "step", **done_event(job, self.session.time_s))
            self._publish(self.pub["events"], "events", msg)

    def _srv_reset(self, request, response):
        with self._lock:
            self.session.reset(self.config.initial_nut_position)
            self.echo.reset()
            self.superseded.reset()
            self._energy_fault_reported = self._model_failure_reported = False
            self.pacer.restart()
            if self.session.paused:  # nothing steps while paused: a controller still sees the reset now
                self._publish_rest_state()
            response.success = True
            response.message = f"reset to t = 0, nut at {self.config.initial_nut_position:g} m"
        self.get_logger().info(response.message)
        return response

    def _srv_release_control(self, request, response):
        with self._lock:
            response.message = self.ownership.release()
            response.success = True
        self.get_logger().info(f"~/release_control: {response.message}")
        return response

    def _srv_brake(self, request, response):
        """The brake by service, while nobody owns the actuator: rclpy does not say who calls a
        service, so an owned actuator brakes through ~/brake_command from its owner."""
        with self._lock:
            owner = self.ownership.owner_now()
            if owner is not None:
                response.success = False
                response.message = (f"the actuator is owned by {participant_name(owner)}: its owner engages the "
                                    f"brake on {self._topic_names['brake_command']} (std_msgs/Bool)")
                return response
            reason = self.session.brake(bool(request.data))
            response.success = reason is None
            response.message = reason or (f"brake {'engaging' if request.data else 'releasing'} "
                                          f"at t = {self.session.time_s:.6f} s")
        return response

    def _srv_clear_faults(self, request, response):
        with self._lock:
            n = self.session.clear_faults()
            response.success = True
            response.message = f"{n} runtime fault(s) ended at t = {self.session.time_s:.6f} s"
        return response

    def _publish_fault_events(self, events) -> None:
        """Each fault start or clear: logged, on ~/events and on /diagnostics at once (the bag has both)."""
        for e in events:
            line = fault_event_line(e)
            self.get_logger().warning(line) if e.what == "start" else self.get_logger().info(line)
            self._fault_log = (self._fault_log + [line])[-FAULT_LOG_LENGTH:]
            self._publish(self.pub["diagnostics"], "diagnostics",
                          self._diagnostic_array(f"{self.get_name()}: actuator fault", fault_event_report(e)))
            self._publish(self.pub["events"], "events", event_message(
                e.time_s, "actuator", "warn" if e.what == "start" else "info", f"fault_{e.what}", e.describe(),
                fault_event_details(e)))

    def _publish_edge_events(self, events) -> None:
        """The nut reaching or leaving a thread end, its load past the static rating or back: logged and on
        ~/events (the bag keeps it)."""
        for e in events:
            self.get_logger().warning(f"t = {e.time_s:.6f} s: {e.describe()}") if e.what in ("reached", "exceeded") \
                else self.get_logger().info(f"t = {e.time_s:.6f} s: {e.describe()}")
            self._publish(self.pub["events"], "events", event_message(
                e.time_s, "plant", "warn" if e.what in ("reached", "exceeded") else "info", e.event_name, e.describe(),
                {"force_n": e.force_n}))

    # -- diagnostics -----------------------------------------------------------------------
    def _publish_diagnostics(self) -> None:
        with self._lock:
            report = simulation_report(self.session.status(), *self._transport_report(), self._fault_log)
            # the fully qualified name: two actuators in two namespaces report under two names
            self._publish(self.pub["diagnostics"], "diagnostics",
                          self._diagnostic_array(f"{self.get_fully_qualified_name()}: simulation", report))

    def _diagnostic_array(self, name: str, report: Report) -> DiagnosticArray:
        status = DiagnosticStatus(level=DIAGNOSTIC_LEVELS[report.level], name=name, message=report.message,
                                  hardware_id=f"prsm_sim/{self.config.model}",
                                  values=[KeyValue(key=k, value=str(v)) for k, v in report.values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = stamp(self.session.time_s)
        return msg

    def _transport_report(self) -> tuple[dict, list[str]]:
        """The node's own figures since the last report (pacing, publishing, recording, Rerun) and its problems."""
        cfg = self.config
        now_wall, sim_now = time.perf_counter(), self.session.time_s
        wall0, sim0, over0 = self._diag_last
        ps = self.pacer.snapshot()
        self._diag_last = (now_wall, sim_now, ps.overruns)
        values: dict[str, Any] = {
            "time_mode": cfg.time_mode, "model": cfg.model, "preset": cfg.preset,
            "achieved_real_time_factor": f"{(sim_now - sim0) / (now_wall - wall0) if now_wall > wall0 else math.nan:.4f}",
            "target_real_time_factor": cfg.real_time_factor if cfg.time_mode == "realtime" else "n/a",
            "step_overruns": ps.overruns, "skipped_periods": ps.skipped_periods, **self.scheduling,
            "max_step_wall_time_us": f"{self._step_wall_max_s * 1e6:.1f}", "publish_failures": self.publish_failures,
            # rclpy does not report what a reliable writer discards for a slow reader: readers count
            # gaps in the state stamps; the node can say how many there are
            "joint_states_readers": self.pub["joint_states"].get_subscription_count(),
            **self.ownership.diagnostics(), **self.refusals.diagnostics(), **self.echo.report(),
            **self.superseded.report(),
        }
        self._step_wall_max_s = 0.0
        problems = []
        for sink, prefix in ((self.recorder, "record"), (self.rerun, "rerun"), (self.live, "foxglove")):
            if sink is None:
                continue
            if prefix == "record":
                values.update(record_path=str(sink.path), record_written=sink.messages_written,
                              record_dropped=sink.messages_dropped, record_error=sink.error or "")
            else:
                values.update({f"{prefix}_{k}": v for k, v in sink.stats().items() if v is not None})
            if sink.error:
                problems.append(str(sink.error))
        if ps.overruns > over0:
            problems.append(f"{ps.overruns - over0} step overruns since the last report")
        return values, problems

    # -- shutdown --------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the producer, then close the consumers; every wait is bounded (idempotent).

        The step thread goes first (it feeds the recorder and the Rerun sink), then the recorder
        and the sink. Executor callbacks (lockstep steps, services) do not run here: `prsm_ros.cli.node.main` calls
        this after it stopped spinning. If the step thread is still inside a step after
        STEP_THREAD_STOP_S, the files are closed anyway and the error says so: the recorder and
        the sink count whatever that step still hands them as dropped (both are safe to call
        after close), so nothing is written into a finished file and nothing hangs.
        """
        self._stop.set()
        self._resumed.set()
        jobs = getattr(self, "jobs", None)  # absent when set-up failed before it
        if jobs is not None and not jobs.stop():
            self.get_logger().error("the step-jobs thread did not stop within its slice")
        if self._thread is not None:
            self._thread.join(timeout=STEP_THREAD_STOP_S)
            if self._thread.is_alive():
                self.get_logger().error(f"the step thread did not stop within {STEP_THREAD_STOP_S:g} s; "
                                        "closing the recording anyway (later steps are counted as dropped)")
        if self.recorder is not None and not self.recorder.close(timeout_s=RECORDER_CLOSE_S):
            self.get_logger().error(f"{self.recorder.error} ({self.recorder.messages_dropped} messages not recorded)")
        if self.rerun is not None and not self.rerun.close(timeout_s=RERUN_CLOSE_S):
            self.get_logger().error(str(self.rerun.error))
        if self.live is not None and not self.live.close():
            self.get_logger().error(str(self.live.error))


def _float64(raw: bytes) -> float:
    """A Float64 command's value from its CDR bytes; another encapsulation (big-endian) through rclpy."""
    try:
        return float64_data(raw)
    except ValueError:
        return deserialize_message(raw, Float64).data


def _reference_stamp_ns(raw: bytes) -> int | None:
    """The header stamp of a reference's CDR bytes (JointState); None (record it now) when they do not parse."""
    try:
        return joint_state_stamp_effort0(raw)[0]
    except (ValueError, IndexError, struct.error):
        return None
