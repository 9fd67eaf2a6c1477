"""`prsm-node`: the simulated PRSM actuator on the ROS 2 graph.

    prsm-node --ros-args --params-file my_params.yaml -p time_mode:=lockstep
    prsm-node --params-template > my_params.yaml       # every parameter, its unit and range
    prsm-node --help

The node is transport: it declares its parameters (`declare`, from `parameters`), and composes
four collaborators around one runtime session (`prsm_sim.Session`: command gate, watchdog,
actuator, faults): `intake.CommandIntake` hands every command message to the session, decided per
writer; `outlets.Outlets` turns each step's outputs into messages (`messages`, `cdr_write`) for
the publishers and the sinks (`sinks`: the MCAP recorder, the Rerun view, any other in its list);
`services.NodeServices` answers the services; `status.StatusReporter` turns the session's status
into /diagnostics and ~/events (`diagnostics`). The node itself owns the lock, the step thread and
the order of shutdown.

Time modes. `realtime`: a dedicated thread steps on absolute deadlines (`pacing.DeadlinePacer`);
`fast`: the same thread without sleeping; in both, that thread takes the commands waiting on
the command topics itself before each step (`command_poll`: no executor wake-up per command, the
main cost at 1 kHz otherwise). `lockstep`: every message received on a command topic
(valid or not: the controller's tick keeps the loop going) advances `lockstep_steps` steps in the
command callback, so a slow controller or a debugger never breaks the loop and the same command
sequence always gives the same states. `/clock` is published on every step; joint_states and the
wrench at `joint_states_rate` (and after every lockstep batch), internal loads at
`internal_loads_rate`. Nothing is published before the first step.

What nobody reads costs little (node CPU at 1 kHz, lockstep round trips): in every time mode a
per-step topic whose publisher had no matched reader at the last count (every `READER_COUNT_EVERY`
steps) asks for its reader count before each message instead of publishing it (1-3 µs against
8-16 µs for a publish to nobody on the 2-core VM, which holds the interpreter lock) and, while it
has none, goes only to the bag. These topics are volatile, so DDS would have delivered such a
sample to nobody; a reader gets every message from the moment the node's publisher has matched it,
as without this rule (a command's echo included, and in lockstep the state a controller waits for:
before the node's writer has matched its reader, a published sample would reach nobody either
way). A publisher made transient-local by a QoS override is always published.

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
import sys
import threading
import time
from typing import Any

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock as RosClock
from rclpy.clock_type import ClockType
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.qos import QoSPolicyKind
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from std_msgs.msg import String

from prsm_sim import ModelError, PrsmError, Session, SessionConfig

from prsm_ros.messages import NODE_NAME, TOPICS, MessageMapper, with_depth
from prsm_ros.node.command_echo import CommandEcho
from prsm_ros.node.command_poll import CommandPoller, PolledGroup
from prsm_ros.node.command_sequence import SupersededCounter
from prsm_ros.node.declare import check_unknown_overrides, declare_parameters
from prsm_ros.node.executors import TakesInfo, make_executor
from prsm_ros.node.locking import NodeLock
from prsm_ros.node.intake import COMMAND_TOPICS, CommandIntake, float64_of, reference_stamp_ns
from prsm_ros.node.outlets import READER_COUNT_EVERY, Outlets, WarnThrottle
from prsm_ros.node.owned_inputs import OWNED_INPUTS
from prsm_ros.node.ownership import COMMAND_QUEUE_DEPTH, CommandOwnership
from prsm_ros.node.pacing import DeadlinePacer, reduce_timer_slack, request_realtime_priority
from prsm_ros.node.parameters import PHYSICS_PREFIX, ConfigError, ParamSources, runtime_change
from prsm_ros.node.refusals import Refusals
from prsm_ros.node.scheduling import other_cpus, pin_calling_thread
from prsm_ros.node.services import NodeServices
from prsm_ros.node.sinks import FoxgloveSink, RecorderSink, RerunOutputSink, Sinks, open_sinks
from prsm_ros.node.status import StatusReporter
from prsm_ros.node.step_jobs import StepJobs, stop_reason
from prsm_ros.node.urdf import urdf_for_node

__all__ = ["PrsmNode", "COMMAND_TOPICS", "READER_COUNT_EVERY", "WALL_CLOCK_TOPICS"]
_float64, _reference_stamp_ns = float64_of, reference_stamp_ns  # their former names here

# fast mode, and realtime mode while it catches up on late steps: a thread that never sleeps keeps
# the GIL and the lock from the executor (services, parameters) — it re-takes the lock before a waiting
# thread wakes — so it really sleeps briefly every few steps that did not sleep.
FAST_YIELD_EVERY = 32
FAST_YIELD_S = 2e-5
OVERRIDABLE_QOS = (QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH, QoSPolicyKind.RELIABILITY, QoSPolicyKind.DURABILITY)
REALTIME_SWITCH_INTERVAL_S = 1e-4  # GIL hand-over bound in realtime mode (Python's default: 5 ms)
# Shutdown waits, each bounded so SIGTERM always ends the process (ros_procs.NodeProcess.stop allows 20 s).
STEP_THREAD_STOP_S = 5.0  # a step in progress (a stiff model step) finishes well within this
SINK_CLOSE_S = 5.0  # each sink: its queue and its summary; a stalled disk or viewer gives up
RECORDER_CLOSE_S = RERUN_CLOSE_S = SINK_CLOSE_S
PAUSED_POLL_S = 0.05  # paused: wall time between two takes of the commands waiting
PAUSED_POLL_BUSY_S = 0.005  # ... when the last take found some (COMMAND_QUEUE_DEPTH at 10 kHz is 10 ms)
PUBLISHED = ("joint_states", "wrench", "internal_loads", "labels", "command_echo", "diagnostics", "events",
             "robot_description")

# Topics whose content is wall-clock (health counters, commands' DDS source stamps): a lockstep bag leaves them
# out so that it is the same bytes for the same run; they are still published.
WALL_CLOCK_TOPICS = ("diagnostics", "command_echo")


class PrsmNode(Node):
    """The lock, the step thread and the order of things; the jobs are its collaborators (module doc)."""

    def __init__(self, param_sources: ParamSources | None = None, **node_kwargs: Any) -> None:
        self.param_sources = param_sources  # where the start-up names came from (the command line); None: all ours
        super().__init__(NODE_NAME, **node_kwargs)
        self.sinks = Sinks([])
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._resumed = threading.Event()
        try:
            self._setup()
        except BaseException:
            self.close()  # our threads and files; the caller decides about the rcl node
            raise

    @property
    def recorder(self):
        """The MCAP recorder (None when not recording)."""
        sink = self.sinks.of(RecorderSink)
        return sink.recorder if sink is not None else None

    @property
    def rerun(self):
        """The live Rerun sink (None when off)."""
        sink = self.sinks.of(RerunOutputSink)
        return sink.rerun if sink is not None else None

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def _setup(self) -> None:
        self.config = declare_parameters(self)
        cfg = self.config
        self.lock = NodeLock()
        self.ownership = CommandOwnership(cfg.ownership_timeout, enabled=cfg.command_ownership)
        self.echo = CommandEcho()
        self.superseded = SupersededCounter()  # commands replaced in a reader's queue before a step took them
        self.refusals = Refusals()
        self.session = Session.from_config(SessionConfig(
            params=cfg.params, model=cfg.model, dt_s=cfg.dt_s, actuator=cfg.actuator if cfg.with_actuator else None,
            nut_position_m=cfg.initial_nut_position, load_n=cfg.load_force,
            initial_load_n=cfg.load_force,  # starts in equilibrium at its load
            interface=cfg.command_interface, max_effort_nm=cfg.max_effort, cmd_timeout_s=cfg.cmd_timeout,
            timeout_behaviour=cfg.timeout_behaviour, paused=cfg.start_paused or cfg.wait_for_controller))
        self.mapper = MessageMapper(self.session.layout, cfg.model, joint_names=cfg.joint_names,
                                    nut_frame=cfg.values["frames.nut"])
        pub, sub = self._create_topics()
        check_unknown_overrides(self, self.param_sources)
        self.scheduling = {"step_thread": "normal", "other_threads": "normal"}
        if cfg.time_mode == "realtime":
            self._prepare_realtime()
        names = {**{k: p.topic_name for k, p in pub.items()}, **{k: s.topic_name for k, s in sub.items()}}
        # lockstep: the bag is the same bytes for the same run (a golden file), so nothing wall-clock goes in
        unrecorded = frozenset(WALL_CLOCK_TOPICS) if cfg.time_mode == "lockstep" else frozenset()
        channels = {name: (TOPICS[k].msg_class, (pub.get(k) or sub[k]).qos_profile, k in sub)
                    for k, name in names.items() if k not in unrecorded}
        self.sinks = open_sinks(cfg, self.get_fully_qualified_name(), channels, self.session.layout)
        self.outlets = Outlets(self, pub, names, self.sinks, unrecorded, WarnThrottle(self.get_logger()))
        self.reporter = StatusReporter(self, self.outlets)
        self.intake = CommandIntake(self, self.outlets)
        self.pacer = DeadlinePacer(cfg.dt_s, cfg.real_time_factor, spin_s=cfg.pacing_spin)
        self.service_handlers = NodeServices(self, self.outlets)
        self.jobs = StepJobs(self._step_slice, self.service_handlers.step_job_done, self._stop)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._steady = RosClock(clock_type=ClockType.STEADY_TIME)  # diagnostics follow wall time, never /clock
        self._diag_timer = self.create_timer(1.0 / cfg.diagnostics_rate, self._publish_diagnostics, clock=self._steady)
        self.outlets.publish("labels", self.mapper.labels())
        self.outlets.publish("robot_description", String(data=urdf_for_node(cfg, self.get_name(),
                                                                            self.get_namespace())))
        if cfg.time_mode != "lockstep":
            self._thread = threading.Thread(target=self._loop, name="prsm-step-loop", daemon=True)
            self._thread.start()
        self.get_logger().info(self._started_line())

    def _started_line(self) -> str:
        cfg, rec = self.config, self.recorder
        live = self.sinks.of(FoxgloveSink)
        return (f"{cfg.model} model, " + (f"parameters {cfg.params_file}" if cfg.params_file else f"preset {cfg.preset}")
                + f", {cfg.update_rate} Hz, {cfg.time_mode}"
                + (f" ×{cfg.real_time_factor:g}" if cfg.time_mode == "realtime" else "")
                + (f", recording to {rec.path}" if rec is not None else "")
                + (f", serving Foxglove on {live.live.url}" if live is not None else "")
                + (", waiting for a controller's first command" if cfg.wait_for_controller
                   else ", paused" if cfg.start_paused else ""))

    @staticmethod
    def _qos_opts() -> QoSOverridingOptions:  # qos_overrides.<topic>.<publisher|subscription>.<policy>
        return QoSOverridingOptions(policy_kinds=OVERRIDABLE_QOS)

    def _create_topics(self) -> tuple[dict, dict]:
        """Publishers and command subscriptions (polled by the step thread in realtime and fast mode)."""
        cfg = self.config
        keys = PUBLISHED + (("clock",) if cfg.publish_clock else ()) + (
            ("ground_truth",) if self.session.actuator is not None else ())
        try:
            pub = {k: self.create_publisher(TOPICS[k].msg_class, self._topic(k), TOPICS[k].qos,
                                            qos_overriding_options=self._qos_opts()) for k in keys}
            # commands arrive as raw CDR (recorded as they are); in realtime and fast mode the step
            # thread takes them itself before each step (command_poll), in lockstep the executor
            # delivers them because a command is what advances time
            polled = cfg.time_mode != "lockstep"
            group = PolledGroup() if polled else None
            # every input is decided per writer: a reader queue deep enough that a fast writer cannot push
            # the owner's messages out between two takes (ownership.COMMAND_QUEUE_DEPTH)
            sub = {k: self.create_subscription(TOPICS[k].msg_class, self._topic(k),
                                               TakesInfo(functools.partial(self._on_command_message, k)),
                                               with_depth(TOPICS[k].qos, COMMAND_QUEUE_DEPTH),
                                               qos_overriding_options=self._qos_opts(), raw=True, callback_group=group)
                   for k in COMMAND_TOPICS}
            for k in OWNED_INPUTS:  # taken by the executor, which spins once the node is built
                sub[k] = self.create_subscription(
                    TOPICS[k].msg_class, self._topic(k), TakesInfo(functools.partial(self._on_owned_input, k)),
                    with_depth(TOPICS[k].qos, COMMAND_QUEUE_DEPTH), qos_overriding_options=self._qos_opts())
        except (InvalidQosOverridesError, ParameterException) as e:
            raise ConfigError(f"QoS override: {e}") from None
        self.poller = CommandPoller()
        if polled:
            for k in COMMAND_TOPICS:
                self.poller.add(k, sub[k], self._on_command)
        return pub, sub

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
        cpu = self.config.step_thread_cpu
        if cpu >= 0:  # the threads started from here on start off the step thread's CPU (`scheduling`)
            self.scheduling["step_thread_cpus"] = "any CPU (the step loop not started)"
            self.scheduling["other_threads_cpus"] = pin_calling_thread(other_cpus(cpu))
        sys.setswitchinterval(REALTIME_SWITCH_INTERVAL_S)

    # -- what an executor sees -------------------------------------------------------------------
    # The command subscriptions the step thread polls (and their QoS event handlers) are hidden from
    # every executor: the events executor ignores callback groups and would take their messages, and
    # the Python executor need not put them in its wait set on every wake-up.
    @property
    def subscriptions(self):
        return (s for s in super().subscriptions if not isinstance(s.callback_group, PolledGroup))

    @property
    def waitables(self):
        return (w for w in super().waitables if not isinstance(getattr(w, "callback_group", None), PolledGroup))

    def make_executor(self):
        """The executor the `executor` parameter names (`executors`), on this node's context, the node added."""
        executor, kind = make_executor(self.config.executor, self.context)
        self.scheduling["executor"] = kind
        executor.add_node(self)
        return executor

    def _topic(self, key: str) -> str:
        return self.config.topics.get(key, TOPICS[key].name)

    # -- pause state ---------------------------------------------------------------------------
    def pause(self) -> None:
        """Lock held."""
        self.session.pause()
        self._resumed.clear()

    def resume(self) -> None:
        """Lock held."""
        self.session.resume()
        self._resumed.set()

    # -- parameters ----------------------------------------------------------------------------
    def _on_set_parameters(self, parameters) -> SetParametersResult:
        """A runtime change: checked as at start-up (`runtime_change`), applied all at once or not at all."""
        if any(not p.name.strip() for p in parameters):  # rclpy takes an empty name as a new parameter
            return SetParametersResult(successful=False, reason="a parameter name must not be empty")
        ours = {p.name: p.value for p in parameters if p.name in self.config.values or p.name.startswith(PHYSICS_PREFIX)}
        if not ours:
            return SetParametersResult(successful=True)
        try:
            new = runtime_change(self.config, ours)
            with self.lock:
                self._apply(new)
        except PrsmError as e:  # refused by the checks, or by the session building what they allowed
            return SetParametersResult(successful=False, reason=str(e))
        except (ArithmeticError, ValueError) as e:  # a model the checks let through but cannot step: refused
            return SetParametersResult(successful=False, reason=f"{type(e).__name__}: {e}")
        self.get_logger().info("parameters changed: " + ", ".join(f"{k} = {v!r}" for k, v in ours.items()))
        return SetParametersResult(successful=True)

    def _apply(self, new) -> None:
        """Lock held: the session follows `new`; the part that can refuse (interface, physics) goes first."""
        old = self.config
        if new.command_interface != old.command_interface:
            reason = self.session.set_interface(new.command_interface)
            if reason is not None:
                if self.session.actuator is None:
                    reason += "; start the node with an actuator (e.g. -p actuator:='{}') to switch"
                raise ConfigError(reason)
        if new.params != old.params:
            self.session.rebuild(new.params)
        self.config = new
        self.session.configure_gate(new.max_effort, new.cmd_timeout, new.timeout_behaviour)
        self.session.load_n = self.session.initial_load_n = new.load_force
        self.session.nut_position_m = new.initial_nut_position
        if new.real_time_factor != old.real_time_factor:
            self.pacer.set_rate(new.real_time_factor)
        if new.ownership_timeout != old.ownership_timeout:
            self.ownership.configure(new.ownership_timeout, new.command_ownership)
        self.outlets.set_decimation(new)
        if new.diagnostics_rate != old.diagnostics_rate:
            self._diag_timer.timer_period_ns = int(1e9 / new.diagnostics_rate)

    # -- commands in ---------------------------------------------------------------------------
    def _on_command_message(self, key: str, raw: bytes, info) -> None:
        """Executor callback (lockstep): one raw command message."""
        with self.lock:
            self.intake.on_command(key, raw, info)

    def _on_command(self, key: str, raw: bytes, info: dict) -> None:
        """Step thread's poll (lock held): one raw command message."""
        self.intake.on_command(key, raw, info)

    def _on_owned_input(self, key: str, msg, info) -> None:
        with self.lock:
            self.intake.on_owned_input(key, msg, info)

    # -- stepping ------------------------------------------------------------------------------
    def advance(self, n: int, publish_last_state: bool = False) -> int:
        """Step n times and publish (lock held); the last state is always published when asked
        (a lockstep controller waits for it). Returns the steps done (fewer after a fault)."""
        done = 0
        outlets, reporter = self.outlets, self.reporter
        for i in range(n):
            t0 = time.perf_counter()
            outlets.begin_step()
            try:
                self.poller.poll()  # realtime and fast: the commands that arrived since the last step
                try:
                    out = self.session.step()
                except ModelError as e:
                    reporter.model_failure(str(e))
                    break
                done += 1
                if out.energy_fault:
                    reporter.energy_fault(out)
                outlets.publish_step(out, reporter, self.echo, force_state=publish_last_state and i == n - 1)
            except Exception as e:  # never let a publishing failure take the process down
                if not rclpy.ok(context=self.context):
                    break
                self.session.fail(f"publishing step {self.session.nstep} failed: {type(e).__name__}: {e}")
                self.get_logger().error(self.session.fault)
                break
            finally:
                outlets.end_step()
            reporter.step_wall_max_s = max(reporter.step_wall_max_s, time.perf_counter() - t0)
        return done

    def _step_slice(self, job, n: int) -> tuple[int, str | None]:
        """Jobs thread: up to `n` steps of `job` under the lock (the state published after the last);
        a callback waiting for the lock goes first (`NodeLock`)."""
        self.lock.let_waiters_first()
        with self.lock:
            why = stop_reason(job, self.session, self._stop.is_set())
            return (0, why) if why else (self.advance(n, publish_last_state=n == job.remaining), None)

    def _loop(self) -> None:
        """realtime / fast: the step thread (lockstep steps in the command callback instead)."""
        reduce_timer_slack()
        realtime = self.config.time_mode == "realtime"
        if realtime:  # never for fast mode: a busy SCHED_FIFO thread would starve the machine
            self.scheduling["step_thread"] = request_realtime_priority(self.config.realtime_priority)
            if self.config.step_thread_cpu >= 0:
                self.scheduling["step_thread_cpus"] = pin_calling_thread({self.config.step_thread_cpu})
        self.pacer.restart()
        was_running = False
        raw_lock = self.lock.raw
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
                self.sinks.wait_drained(self._stop)  # fast: no deadline, so the bag keeps every message
            unslept = unslept + 1 if behind else 0
            if unslept >= FAST_YIELD_EVERY:  # an overloaded machine must not starve the services
                time.sleep(FAST_YIELD_S)
                unslept = 0
            try:
                with raw_lock:  # the bare mutex: this thread sleeps or yields between steps (NodeLock)
                    if not self.session.paused:
                        self.advance(1)
            except Exception as e:  # a publish after shutdown, or a bug: never kill the process from here
                if self._stop.is_set() or not rclpy.ok(context=self.context):
                    return
                self.session.fail(f"step loop error: {type(e).__name__}: {e}")
                self.get_logger().error(self.session.fault)

    def step_thread_ids(self) -> frozenset[int]:
        """The OS thread id of the step thread (realtime and fast mode), for what moves the other threads."""
        native = self._thread.native_id if self._thread is not None else None
        return frozenset() if native is None else frozenset({native})

    def _idle(self) -> None:
        """Paused or faulted: commands still count, own and reach the bag while nothing steps."""
        try:
            with self.lock:
                taken = self.poller.sweep()
        except Exception as e:  # a bug: logged, never the end of the step thread
            taken = 0
            self.outlets.warn("poll", f"taking commands failed: {type(e).__name__}: {e}")
        # commands waiting: come back before a flood can overrun the reader queue (COMMAND_QUEUE_DEPTH)
        self._resumed.wait(PAUSED_POLL_BUSY_S if taken else PAUSED_POLL_S)

    def _publish_diagnostics(self) -> None:
        with self.lock:
            self.reporter.publish_diagnostics()

    # -- shutdown ------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop the producer, then close the consumers; every wait is bounded (idempotent).

        The step thread goes first (it feeds the sinks), then the sinks in their order. Executor
        callbacks (lockstep steps, services) do not run here: `prsm_ros.node.process.main` calls
        this after it stopped spinning. If the step thread is still inside a step after
        STEP_THREAD_STOP_S, the sinks are closed anyway and the error says so: each counts
        whatever that step still hands it as dropped (all are safe to call after close), so
        nothing is written into a finished file and nothing hangs.
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
        self.sinks.close(SINK_CLOSE_S, self.get_logger().error)

