"""One controller owns the actuator, pure Python (no ROS), so it is tested without DDS.

The first participant to send a *valid* command owns the actuator across all its command topics;
commands from any other participant are refused and counted per participant until the owner
releases it (`release()`, the node's `~/release_control` service) or goes quiet for longer than
`timeout_s` (wall time on a monotonic clock: in lockstep simulation time stops with the owner's
commands, so it cannot measure the owner's silence). A participant is the DDS participant prefix
of the message info's `publisher_gid` (the first 12 bytes of the writer GUID: one controller may
use several topics, each with its own writer, and still be one owner).

This is a guard against mistakes (two controllers started on one actuator), not against an
attacker: anyone on the domain can call `~/release_control` (docs/security.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from prsm_sim.errors import ParamError

PREFIX_BYTES = 12  # RTPS GUID prefix: the participant; the last 4 bytes name the writer
# The node's reader queue on each command topic (keep last N, whatever depth the interface gives
# the writers). All writers of a topic share it: with depth 1 a second writer sending ten times
# faster than the owner replaced the owner's command before the node took it, the watchdog zeroed
# the torque and ownership lapsed to the flooder. The node drains the queue once per step and
# decides per message by its writer (a refusal is a counter), so with depth 100 the owner's
# commands survive a writer up to ~100 messages per step (100 kHz at update_rate 1 kHz).
COMMAND_QUEUE_DEPTH = 100
# Participants listed by name with their refusal counts on /diagnostics (and so in the bag every
# report): the most recently refused ones; older ones are counted only, so memory and the report
# stay bounded however many participants a graph sees.
REFUSED_LISTED = 16


def participant_of(message_info: dict | None) -> bytes | None:
    """The participant prefix from an rclpy message info dict (None when the middleware gives none)."""
    gid = (message_info or {}).get("publisher_gid")
    data = gid.get("data") if isinstance(gid, dict) else None
    if not data:
        return None
    return bytes(data[:PREFIX_BYTES])


def participant_name(prefix: bytes | None) -> str:
    """A printable name for a participant prefix (hex), as on /diagnostics."""
    return "unknown" if prefix is None else prefix.hex()


@dataclass
class OwnershipCounters:
    refused: int = 0  # commands refused because another participant owns the actuator
    refused_by: dict[str, int] = field(default_factory=dict)  # the last REFUSED_LISTED participants → refusals
    refused_unlisted: int = 0  # participants that dropped out of `refused_by` (their refusals stay in `refused`)
    takeovers: int = 0  # times a participant became owner
    releases: int = 0  # by service
    lapses: int = 0  # by the owner's silence


class CommandOwnership:
    """Who may command the actuator. `admit(participant)` before a command; `accepted(participant)` after.

    `timeout_s` 0 never lets ownership lapse (only `release()` ends it); `enabled` False admits all.
    """

    def __init__(self, timeout_s: float = 1.0, *, enabled: bool = True,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.configure(timeout_s, enabled)
        self._clock = clock
        self.owner: bytes | None = None
        self._last_s = 0.0
        self.counters = OwnershipCounters()

    def configure(self, timeout_s: float, enabled: bool = True) -> None:
        if not (timeout_s >= 0.0):
            raise ParamError(f"ownership timeout = {timeout_s!r}: must be a number >= 0 (s; 0: never lapses)")
        self.timeout_s = float(timeout_s)
        self.enabled = bool(enabled)

    def _lapse_if_quiet(self, now: float) -> None:
        if self.owner is not None and self.timeout_s > 0 and now - self._last_s > self.timeout_s:
            self.owner = None
            self.counters.lapses += 1

    def admit(self, participant: bytes | None) -> str | None:
        """None if `participant` may command now; else the refusal reason (and it is counted)."""
        if not self.enabled:
            return None
        self._lapse_if_quiet(self._clock())
        if self.owner is None or participant == self.owner:
            return None
        name = participant_name(participant)
        self._count_refusal(name)
        return (f"command from participant {name} refused: the actuator is owned by {participant_name(self.owner)} "
                "(until it calls ~/release_control or stays quiet for the ownership timeout)")

    def _count_refusal(self, name: str) -> None:
        c = self.counters
        c.refused += 1
        n = c.refused_by.pop(name, 0) + 1  # re-inserted: the dict's order is the order of last refusal
        c.refused_by[name] = n
        if len(c.refused_by) > REFUSED_LISTED:
            del c.refused_by[next(iter(c.refused_by))]
            c.refused_unlisted += 1

    def owner_now(self) -> bytes | None:
        """The owner at this moment (after a lapse is applied); None when nobody owns or ownership is off."""
        if not self.enabled:
            return None
        self._lapse_if_quiet(self._clock())
        return self.owner

    def accepted(self, participant: bytes | None) -> None:
        """A valid command from an admitted participant: it owns (or keeps) the actuator."""
        if not self.enabled:
            return
        if self.owner is None:
            self.owner = participant
            self.counters.takeovers += 1
        self._last_s = self._clock()

    def release(self) -> str:
        """End the current ownership (the service); returns what happened, in words."""
        if self.owner is None:
            return "no owner"
        name = participant_name(self.owner)
        self.owner = None
        self.counters.releases += 1
        return f"released by {name}"

    def diagnostics(self) -> dict[str, object]:
        self._lapse_if_quiet(self._clock())
        c = self.counters
        return {"command_owner": participant_name(self.owner) if self.owner is not None else "none",
                "commands_refused_not_owner": c.refused,
                "refused_participants": ", ".join(f"{k} ({v})" for k, v in sorted(c.refused_by.items())) or "none",
                "refused_participants_unlisted": c.refused_unlisted,
                "ownership_releases": c.releases, "ownership_lapses": c.lapses}
