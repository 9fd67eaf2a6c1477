"""Command safety and the watchdog: what command the model gets.

A `Session` hands every command it is offered to its `CommandGate` and asks it, once per step,
for the command of the active interface (`effort`: screw torque N·m, `velocity`: screw speed
rad/s, `position`: nut position m). Rules:

- a command for an interface that is not the active one is refused with a reason naming the
  active one and counted as such (`rejected_inactive_interface`, not malformed); a non-finite value is rejected and counted; the last valid command stays in force;
- a torque beyond ±max_effort is saturated to the limit and counted;
- a message a transport could not read at all (`refuse_malformed`) is counted as received and
  malformed;
- with `cmd_timeout_s` > 0, a command older than that in *simulation* time triggers the timeout
  behaviour: "zero" applies no torque (effort) or no speed (velocity), "hold" keeps the last
  valid command; in `position` mode both hold the last position (commanding the nut to 0 m is
  no safe state). A fresh valid command ends the timeout. Before the first command the command
  is zero (position: the nut position given at start) and no timeout is counted.

Simulation time makes the watchdog deterministic (lockstep runs repeat bit for bit) and keeps a
paused or debugged simulation from timing out while no time passes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from prsm_sim.actuator.params import check_interface
from prsm_sim.checks import is_finite_number
from prsm_sim.errors import ParamError

TIMEOUT_BEHAVIOURS = ("zero", "hold")
# the unit of each command interface's value, for messages
INTERFACE_UNIT = {"position": "m (nut position)", "velocity": "rad/s (screw speed)", "effort": "N·m (screw torque)"}


@dataclass
class GateCounters:
    """Monotonic counters since start (or reset)."""

    received: int = 0  # every command message offered, valid or not
    accepted: int = 0
    rejected_non_finite: int = 0
    rejected_malformed: int = 0
    rejected_inactive_interface: int = 0  # a well-formed command for an interface that is not the active one
    saturated: int = 0
    timeouts: int = 0  # entries into the timed-out state


class CommandGate:
    """Validates commands for the active interface, saturates torques, and applies the watchdog on simulation time."""

    def __init__(self, max_effort_nm: float, cmd_timeout_s: float = 0.0, timeout_behaviour: str = "zero",
                 interface: str = "effort") -> None:
        self.configure(max_effort_nm, cmd_timeout_s, timeout_behaviour)
        self.interface = check_interface(interface)
        self.reset()

    def configure(self, max_effort_nm: float, cmd_timeout_s: float, timeout_behaviour: str) -> None:
        """Change the limits; a runtime parameter change calls this after validation."""
        for name, v, ok, allowed in (
                ("max_effort_nm", max_effort_nm, lambda x: x > 0, "a finite number > 0 (N·m)"),
                ("cmd_timeout_s", cmd_timeout_s, lambda x: x >= 0, "a finite number >= 0 (s; 0 disables)")):
            if not (is_finite_number(v) and ok(v)):
                raise ParamError(f"{name} = {v!r}: must be {allowed}")
        if timeout_behaviour not in TIMEOUT_BEHAVIOURS:
            raise ParamError(f"timeout_behaviour = {timeout_behaviour!r}: must be one of {', '.join(TIMEOUT_BEHAVIOURS)}")
        self.max_effort_nm = float(max_effort_nm)
        self.cmd_timeout_s = float(cmd_timeout_s)
        self.timeout_behaviour = timeout_behaviour

    def reset(self, position_m: float = 0.0) -> None:
        """Forget the command and the counters (the simulation was reset to time zero, nut at `position_m`)."""
        self.value = position_m if self.interface == "position" else 0.0
        self.command_time_s: float | None = None
        self.timed_out = False
        self.counters = GateCounters()

    def set_interface(self, interface: str, present_value: float) -> None:
        """Switch the active interface; the command starts at `present_value` (the measured speed or
        position, or 0 N·m), so nothing jumps until the controller speaks in the new unit."""
        self.interface = check_interface(interface)
        self.value = float(present_value)

    @property
    def command_nm(self) -> float:
        """The last valid torque command (0 when another interface is active)."""
        return self.value if self.interface == "effort" else 0.0

    # -- commands in ----------------------------------------------------------------------
    def offer(self, interface: str, value: float, now_s: float) -> str | None:
        """Take a command for `interface` at simulation time `now_s`; returns the rejection reason or None."""
        self.counters.received += 1
        if interface != self.interface:
            self.counters.rejected_inactive_interface += 1
            return (f"{interface} command refused: the active command interface is {self.interface!r} "
                    f"({INTERFACE_UNIT[self.interface]})")
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = math.nan
        if not math.isfinite(v):
            self.counters.rejected_non_finite += 1
            unit = INTERFACE_UNIT[interface].split(" ")[0]
            return f"{interface} command {value!r} is not a finite number; keeping {self.value:g} {unit}"
        if interface == "effort" and abs(v) > self.max_effort_nm:
            self.counters.saturated += 1
            v = math.copysign(self.max_effort_nm, v)
        self.counters.accepted += 1
        self.value = v
        self.command_time_s = now_s
        self.timed_out = False
        return None

    def offer_torque(self, torque_nm: float, now_s: float) -> str | None:
        """A screw torque command (effort interface)."""
        return self.offer("effort", torque_nm, now_s)

    def refuse_malformed(self, reason: str) -> str:
        """A command message that could not be read at all (e.g. bytes that are not its type's CDR):
        counted as received and malformed; returns the reason."""
        self.counters.received += 1
        self.counters.rejected_malformed += 1
        return reason

    # -- command out ----------------------------------------------------------------------
    def command(self, now_s: float) -> float:
        """The command of the active interface to hold over the step starting at simulation time `now_s`."""
        if self.cmd_timeout_s > 0 and self.command_time_s is not None:
            if now_s - self.command_time_s > self.cmd_timeout_s:
                if not self.timed_out:
                    self.timed_out = True
                    self.counters.timeouts += 1
                if self.timeout_behaviour == "zero" and self.interface != "position":
                    return 0.0
        return self.value

    def torque(self, now_s: float) -> float:
        """The gated command in `effort` mode (screw torque, N·m)."""
        return self.command(now_s)

    def command_age_s(self, now_s: float) -> float:
        """Simulation time since the last valid command (inf before the first)."""
        return math.inf if self.command_time_s is None else now_s - self.command_time_s

