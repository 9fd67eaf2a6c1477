"""What the node says about the run: /diagnostics, and the events of ~/events with their log lines.

`StatusReporter` turns the session's status and the node's own figures (pacing, publishing,
sinks, ownership, refusals) into the periodic /diagnostics entry (`diagnostics.simulation_report`),
and the session's fault and thread-end events, an energy-guard breach and a model failure into
~/events entries and log lines. Its methods run with the node's lock held.
"""

from __future__ import annotations

import math
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from prsm_ros.messages import event_message, stamp
from prsm_ros.node.diagnostics import (FAULT_LOG_LENGTH, Report, energy_fault_event, fault_event_details,
                                       fault_event_line, fault_event_report, simulation_report)

# diagnostics.OK, WARN, ERROR as DiagnosticStatus levels
DIAGNOSTIC_LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
WARN_THROTTLE_S = 2.0  # wall seconds between repeated log lines of a model failure


class StatusReporter:
    """/diagnostics and ~/events for one node (`node`: its config, session, pacer and counters)."""

    def __init__(self, node, outlets) -> None:
        self.node, self.outlets, self.session = node, outlets, node.session
        self.log = node.get_logger()
        self.fault_log: list[str] = []  # the last fault starts and clears, for /diagnostics
        self._last = (time.perf_counter(), 0.0, 0)  # wall s, sim s, overruns at the last report
        self.step_wall_max_s = 0.0
        self.energy_fault_reported = False  # one ~/events entry per run (until ~/reset)
        self.model_failure_reported = False  # likewise
        self.namesakes = 1  # nodes with this node's full name on the graph at the last look (itself included)

    def rearm(self) -> None:
        """After ~/reset: the next energy-guard breach and model failure are reported again."""
        self.energy_fault_reported = self.model_failure_reported = False

    def event(self, time_s: float, source: str, severity: str, code: str, text: str, details: dict) -> None:
        self.outlets.publish("events", event_message(time_s, source, severity, code, text, details))

    # -- events ------------------------------------------------------------------------------
    def step_events(self) -> None:
        """The fault and thread-end events the last step raised, if any."""
        if self.session.pending_events:
            self.fault_events(self.session.take_events())
        if self.session.pending_edge_events:
            self.edge_events(self.session.take_edge_events())

    def fault_events(self, events) -> None:
        """Each fault start or clear: logged, on ~/events and on /diagnostics at once (the bag has both)."""
        for e in events:
            line = fault_event_line(e)
            self.log.warning(line) if e.what == "start" else self.log.info(line)
            self.fault_log = (self.fault_log + [line])[-FAULT_LOG_LENGTH:]
            self.outlets.publish("diagnostics", self.diagnostic_array(f"{self.node.get_name()}: actuator fault",
                                                                      fault_event_report(e)))
            self.event(e.time_s, "actuator", "warn" if e.what == "start" else "info", f"fault_{e.what}",
                       e.describe(), fault_event_details(e))

    def edge_events(self, events) -> None:
        """The nut reaching or leaving a thread end, its load past the static rating or back: logged and
        on ~/events (the bag keeps it)."""
        for e in events:
            line = f"t = {e.time_s:.6f} s: {e.describe()}"
            warn = e.what in ("reached", "exceeded")
            self.log.warning(line) if warn else self.log.info(line)
            self.event(e.time_s, "plant", "warn" if warn else "info", e.event_name, e.describe(), {"force_n": e.force_n})

    def energy_fault(self, out) -> None:
        """The model's energy books stopped closing (the core's energy guard): one event, an error log;
        /diagnostics says ERROR while it lasts. Stepping goes on: the user decides."""
        if self.energy_fault_reported:
            return
        self.energy_fault_reported = True
        text, details = energy_fault_event(out.time_s, out.energy_flow_j, out.energy_residual_j,
                                           self.node.config.model)
        self.event(out.time_s, "energy_guard", "error", "energy_balance", text, details)
        self.log.error(text)

    def model_failure(self, reason: str) -> None:
        """The model failed (Session's ModelError): stepping stops until ~/reset; /diagnostics says
        ERROR with the reason while it lasts, and one ~/events entry (so the bag) says when and why."""
        self.log.error(reason, throttle_duration_sec=WARN_THROTTLE_S)
        if self.model_failure_reported:
            return
        self.model_failure_reported = True
        self.event(self.session.time_s, "model", "error", "model_failure", reason, {"model": self.node.config.model})

    # -- diagnostics -------------------------------------------------------------------------
    def publish_diagnostics(self) -> None:
        self.look_for_namesakes()
        report = simulation_report(self.session.status(), *self.transport_report(), self.fault_log)
        # the fully qualified name: two actuators in two namespaces report under two names
        self.outlets.publish("diagnostics", self.diagnostic_array(f"{self.node.get_fully_qualified_name()}: "
                                                                  "simulation", report))

    def look_for_namesakes(self) -> None:
        """Another node with this full name on the graph: services, parameters and commands would reach
        either of them. ROS 2 does not refuse it, so the node says so loudly (an error line and a
        ~/events entry each time the count rises; WARN on /diagnostics while it lasts)."""
        node = self.node
        ns, name = node.get_namespace(), node.get_name()
        n = sum(1 for other, other_ns in node.get_node_names_and_namespaces() if other == name and other_ns == ns)
        if n > self.namesakes:
            text = (f"{n} nodes named {node.get_fully_qualified_name()} on this ROS domain: services, parameters and "
                    "commands reach any of them; give each its own name (-r __node:=NAME) or namespace (-r __ns:=/NS)")
            self.log.error(text)
            self.event(self.session.time_s, "node", "error", "duplicate_node_name", text, {"nodes": n})
        self.namesakes = max(n, 1)

    def paused_state(self) -> dict[str, Any]:
        """While paused, the state the node holds (joint_states stops, and a reader that joins later
        would see none): each joint's position, velocity and effort as joint_states would carry them."""
        session = self.session
        if not session.paused or session.fault is not None:
            return {}
        out = session.rest_outputs()
        act = session.actuator
        if act is not None:
            out = act.measured(out)
        screw, nut = self.node.config.joint_names
        joints = ((screw, out.screw_angle_rad, out.screw_speed_rad_s, out.screw_torque_nm),
                  (nut, out.nut_position_m, out.nut_velocity_m_s, out.nut_force_n))
        values: dict[str, Any] = {"state_joints": f"{screw},{nut}"}
        for name, x, v, f in joints:
            values.update({f"state_{name}_position": repr(float(x)), f"state_{name}_velocity": repr(float(v)),
                           f"state_{name}_effort": repr(float(f))})
        return values

    def diagnostic_array(self, name: str, report: Report) -> DiagnosticArray:
        status = DiagnosticStatus(level=DIAGNOSTIC_LEVELS[report.level], name=name, message=report.message,
                                  hardware_id=f"prsm_sim/{self.node.config.model}",
                                  values=[KeyValue(key=k, value=str(v)) for k, v in report.values.items()])
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = stamp(self.session.time_s)
        return msg

    def transport_report(self) -> tuple[dict, list[str]]:
        """The node's own figures since the last report (pacing, publishing, sinks) and its problems."""
        node, cfg = self.node, self.node.config
        now_wall, sim_now = time.perf_counter(), self.session.time_s
        wall0, sim0, over0 = self._last
        ps = node.pacer.snapshot()
        self._last = (now_wall, sim_now, ps.overruns)
        values: dict[str, Any] = {
            "time_mode": cfg.time_mode, "model": cfg.model, "preset": cfg.preset, "params_file": cfg.params_file,
            "achieved_real_time_factor": f"{(sim_now - sim0) / (now_wall - wall0) if now_wall > wall0 else math.nan:.4f}",
            "target_real_time_factor": cfg.real_time_factor if cfg.time_mode == "realtime" else "n/a",
            "step_overruns": ps.overruns, "skipped_periods": ps.skipped_periods, **node.scheduling,
            "max_step_wall_time_us": f"{self.step_wall_max_s * 1e6:.1f}",
            "publish_failures": self.outlets.publish_failures,
            # rclpy does not report what a reliable writer discards for a slow reader: readers count
            # gaps in the state stamps; the node can say how many there are
            "joint_states_readers": self.outlets.pub["joint_states"].get_subscription_count(),
            **node.ownership.diagnostics(), **node.refusals.diagnostics(), **node.echo.report(),
            **node.superseded.report(), **node.jobs.report(),
        }
        self.step_wall_max_s = 0.0
        values.update(self.paused_state())
        sink_values, problems = node.sinks.report()
        values.update(sink_values)
        if self.namesakes > 1:
            problems.append(f"{self.namesakes} nodes named {node.get_fully_qualified_name()} on this ROS domain")
        values["nodes_with_this_name"] = self.namesakes
        if ps.overruns > over0:
            problems.append(f"{ps.overruns - over0} step overruns since the last report")
        return values, problems
