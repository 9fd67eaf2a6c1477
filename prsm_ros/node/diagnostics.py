"""What the node reports, as plain data (no ROS): the /diagnostics payloads and the ~/events details.

The node turns a `Report` into a diagnostic_msgs/DiagnosticStatus (level, message, key/value
pairs as strings) and event details into a ~/events document; tests read these functions
without DDS. Every figure comes from `Session.status()` or from what the node measured itself
(pacing, publishing, recording), passed in as `transport` values and problems.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

from prsm_sim.actuator import FaultEvent
from prsm_sim.stepping.ledger import ENERGY_GUARD_REL

OK, WARN, ERROR = 0, 1, 2  # diagnostic_msgs/DiagnosticStatus levels
FAULT_LOG_LENGTH = 10  # fault starts and clears kept for the simulation report


class Report(NamedTuple):
    """One DiagnosticStatus's content: level (OK, WARN, ERROR), one-line message, values by key."""

    level: int
    message: str
    values: dict[str, Any]


def energy_fault_text(flow_j: float, residual_j: float) -> str:
    """The energy guard's verdict in words (models.base: |residual| above a fraction of the flow)."""
    return f"residual {residual_j:.6g} J of {flow_j:.6g} J that flowed (limit {ENERGY_GUARD_REL:g})"


def energy_fault_event(time_s: float, flow_j: float, residual_j: float, model: str) -> tuple[str, dict]:
    """The ~/events message and details of the first step whose energy books did not close."""
    text = (f"energy balance violated at t = {time_s:.6f} s: {energy_fault_text(flow_j, residual_j)}; "
            f"results of model {model} are not trustworthy from here")
    return text, {"residual_j": residual_j, "flow_j": flow_j, "model": model}


def fault_event_line(e: FaultEvent) -> str:
    """A fault start or clear in one line, with its simulation time (log and fault history)."""
    return f"t = {e.time_s:.6f} s: {e.describe()}"


def fault_event_report(e: FaultEvent) -> Report:
    """The /diagnostics entry of a fault start (WARN) or clear (OK)."""
    return Report(WARN if e.what == "start" else OK, e.describe(),
                  {"event": e.what, "kind": e.fault.kind, "time_s": f"{e.time_s:.6f}", "fault": e.fault.describe()})


def fault_event_details(e: FaultEvent) -> dict:
    """The ~/events details of a fault start or clear (a duration of null: until cleared; JSON has no inf)."""
    f = e.fault
    return {"kind": f.kind, "start_s": f.start_s, "duration_s": f.duration_s if math.isfinite(f.duration_s) else None,
            "value": f.value, "sensor": f.sensor, "roller": f.roller}


def simulation_report(status: dict, transport: dict[str, Any], problems: list[str], fault_log: list[str]) -> Report:
    """The node's periodic simulation entry from the session's `status()` and the node's own
    figures (`transport`: values shown as they are; `problems`: what the node found wrong).

    ERROR while the session is stopped by a fault or its energy books do not close; WARN with an
    active actuator fault, a watchdog timeout or a transport problem; else OK ("running" or "paused").
    """
    c, age, act = status["counters"], status["command_age_s"], status["actuator"]
    values: dict[str, Any] = {
        "sim_time_s": f"{status['time_s']:.6f}", "steps": status["nstep"], "paused": status["paused"],
        **transport,
        "command_age_s": "none yet" if age is None else f"{age:.6f}",
        "command_nm": status["command_nm"], "timed_out": status["timed_out"], "load_force_n": status["load_n"],
        "commands_received": c["received"], "commands_accepted": c["accepted"],
        "rejected_non_finite": c["rejected_non_finite"], "rejected_malformed": c["rejected_malformed"],
        "rejected_inactive_interface": c["rejected_inactive_interface"], "saturated": c["saturated"], "timeouts": c["timeouts"],
        "fault": status["fault"] or "", "command_interface": status["command_interface"], "command": status["command"],
    }
    problems = list(problems)
    if act is not None:
        active = act["faults_active"]
        values.update(brake_engaged=act["brake_engaged"], brake_level=f"{act['brake_level']:.3f}",
                      motor_current_a=f"{act['motor_current_a']:.6g}", torque_limited=act["torque_limited"],
                      faults_active="; ".join(active), fault_events="; ".join(fault_log))
        if active:
            problems.insert(0, f"fault(s) active: {'; '.join(active)}")
    if status["timed_out"]:
        problems.append(f"no command for {age:.3f} s (cmd_timeout {status['cmd_timeout_s']:g} s): "
                        + ("zero torque" if status["timeout_behaviour"] == "zero" else "holding the last command"))
    energy = status["energy"]
    if energy is not None:
        values.update(energy_residual_j=f"{energy['residual_j']:.6g}", energy_flow_j=f"{energy['flow_j']:.6g}")
    if status["fault"] is not None:
        return Report(ERROR, status["fault"], values)
    if energy is not None and energy["fault"]:
        return Report(ERROR, "energy balance violated: " + energy_fault_text(energy["flow_j"], energy["residual_j"]),
                      values)
    if problems:
        return Report(WARN, "; ".join(problems), values)
    return Report(OK, "paused" if status["paused"] else "running", values)
