"""Command safety and the watchdog, pure Python (no ROS): what torque the simulator gets.

The node hands every received command to a `CommandGate` and asks it, once per step, for the
torque to apply. Rules (issue 4, item 4):

- a non-finite torque is rejected and counted; the last valid command stays in force;
- a torque beyond ±max_effort is saturated to the limit and counted;
- a joint command without `screw_joint`, or whose arrays do not match `name` in length, is
  rejected with the reason (the node logs it, throttled); `position`/`velocity` may be empty,
  as in ros2_control's topic-based hardware interface, `effort` may not;
- with `cmd_timeout_s` > 0, a command older than that in *simulation* time triggers the timeout
  behaviour: "zero" applies no torque, "hold" keeps the last valid torque. A fresh valid command
  ends the timeout. Before the first command the torque is zero and no timeout is counted.

Simulation time makes the watchdog deterministic (lockstep runs repeat bit for bit) and keeps a
paused or debugged simulation from timing out while no time passes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

TIMEOUT_BEHAVIOURS = ("zero", "hold")


@dataclass
class GateCounters:
    """Monotonic counters since start (or reset)."""

    received: int = 0  # every command message offered, valid or not
    accepted: int = 0
    rejected_non_finite: int = 0
    rejected_malformed: int = 0
    saturated: int = 0
    timeouts: int = 0  # entries into the timed-out state


class CommandGate:
    """Validates commands, saturates them, and applies the watchdog on simulation time."""

    def __init__(self, max_effort_nm: float, cmd_timeout_s: float = 0.0, timeout_behaviour: str = "zero",
                 joint_name: str = "screw_joint") -> None:
        self.joint_name = joint_name
        self.configure(max_effort_nm, cmd_timeout_s, timeout_behaviour)
        self.reset()

    def configure(self, max_effort_nm: float, cmd_timeout_s: float, timeout_behaviour: str) -> None:
        """Change the limits; a runtime parameter change calls this after validation."""
        if not (math.isfinite(max_effort_nm) and max_effort_nm > 0):
            raise ValueError(f"max_effort = {max_effort_nm!r}: must be a finite number > 0 (N·m)")
        if not (math.isfinite(cmd_timeout_s) and cmd_timeout_s >= 0):
            raise ValueError(f"cmd_timeout = {cmd_timeout_s!r}: must be a finite number >= 0 (s; 0 disables)")
        if timeout_behaviour not in TIMEOUT_BEHAVIOURS:
            raise ValueError(f"timeout_behaviour = {timeout_behaviour!r}: must be one of {', '.join(TIMEOUT_BEHAVIOURS)}")
        self.max_effort_nm = float(max_effort_nm)
        self.cmd_timeout_s = float(cmd_timeout_s)
        self.timeout_behaviour = timeout_behaviour

    def reset(self) -> None:
        """Forget the command and the counters (the simulation was reset to time zero)."""
        self.command_nm = 0.0
        self.command_time_s: float | None = None
        self.timed_out = False
        self.counters = GateCounters()

    # -- commands in ----------------------------------------------------------------------
    def offer_torque(self, torque_nm: float, now_s: float) -> str | None:
        """Take a screw torque command at simulation time `now_s`; returns the rejection reason or None."""
        self.counters.received += 1
        try:
            value = float(torque_nm)
        except (TypeError, ValueError):
            value = math.nan
        if not math.isfinite(value):
            self.counters.rejected_non_finite += 1
            return f"screw torque {torque_nm!r} is not a finite number; keeping {self.command_nm:g} N·m"
        if abs(value) > self.max_effort_nm:
            self.counters.saturated += 1
            value = math.copysign(self.max_effort_nm, value)
        self.counters.accepted += 1
        self.command_nm = value
        self.command_time_s = now_s
        self.timed_out = False
        return None

    def offer_joint_command(self, names: Sequence[str], effort: Sequence[float], position: Sequence[float],
                            velocity: Sequence[float], now_s: float) -> str | None:
        """Take a JointState-style command: the effort of `joint_name`. Returns the rejection reason or None."""
        reason = self._malformed(names, effort, position, velocity)
        if reason is not None:
            self.counters.received += 1
            self.counters.rejected_malformed += 1
            return reason
        return self.offer_torque(effort[list(names).index(self.joint_name)], now_s)

    def _malformed(self, names, effort, position, velocity) -> str | None:
        n = len(names)
        if self.joint_name not in names:
            return f"joint command has no {self.joint_name!r} (names: {list(names)}); expected its effort in N·m"
        if len(effort) != n:
            return f"joint command has {n} names but {len(effort)} efforts; effort must match name in length"
        for field, arr in (("position", position), ("velocity", velocity)):
            if len(arr) not in (0, n):
                return f"joint command has {n} names but {len(arr)} {field} values; {field} must be empty or match name"
        return None

    # -- torque out -----------------------------------------------------------------------
    def torque(self, now_s: float) -> float:
        """The torque to hold over the step starting at simulation time `now_s`."""
        if self.cmd_timeout_s > 0 and self.command_time_s is not None:
            if now_s - self.command_time_s > self.cmd_timeout_s:
                if not self.timed_out:
                    self.timed_out = True
                    self.counters.timeouts += 1
                return 0.0 if self.timeout_behaviour == "zero" else self.command_nm
        return self.command_nm

    def command_age_s(self, now_s: float) -> float:
        """Simulation time since the last valid command (inf before the first)."""
        return math.inf if self.command_time_s is None else now_s - self.command_time_s
