"""Command subscriptions the step thread reads itself, with no executor wake-up per message.

At 1 kHz the rclpy executor was the node's largest cost: every command woke it, and each wake-up
rebuilt the wait set, the task and the callback-group bookkeeping in Python (py-spy: about half a
core for 1,000 commands/s, more than the step and the recorder together). In `realtime` and
`fast` mode the step thread needs a command only at the start of a step, so it takes what is
waiting itself, once per step, with the subscription's non-blocking take (rclpy's
`Subscription.handle.take_message(msg_type, raw)`, the call the executor makes), and hands each
message to the same handler the executor would have called. The newest command is then applied
at the next step, as it would be after an executor callback.

The subscriptions belong to a `PolledGroup`, a callback group the executor never waits on (its
`can_execute` is false), so the executor neither wakes for them nor takes their messages. rclpy's
events executor ignores callback groups, so the node also leaves the group's entities out of what
it shows any executor (`PrsmNode.subscriptions` and `waitables`). Their
QoS event handlers (rclpy's default warnings about a publisher with incompatible QoS or type)
stay in that group, so those two warnings are not logged for the command topics: handed to the
executor, they kept it spinning without pause under 1 kHz commands (measured: the main thread
at 52–69 % of a core instead of 1 %; the cause inside the middleware was not traced). The
messages stay raw CDR bytes: the node records them as they are and decodes only what it reads.
`lockstep` keeps the executor: there a command is what advances time, so it must wake the node.

Most command topics have no publisher (a controller uses one interface), and an empty take still
costs a few microseconds, more right after the thread wakes (measured at 1 kHz on this 2-core VM:
five empty takes 16–23 µs of thread time per step, 4–7 µs back to back). So each step takes only
from the subscriptions that had a matched publisher at the last sweep (or a message since), and
every `SWEEP_EVERY` polls a sweep takes from all of them and refreshes that set: a new
publisher's first commands wait at most that many steps, none is ever left behind (a publisher
that comes and goes between two sweeps leaves its messages for the next sweep to take).
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.exceptions import InvalidHandle

from prsm_sim.errors import InputError

# a handler takes (topic key, CDR bytes, rclpy message info dict), as a two-argument raw callback would
Handler = Callable[[str, bytes, dict], None]

SWEEP_EVERY = 10  # polls (steps) between two takes from every subscription


class PolledGroup(CallbackGroup):
    """A callback group whose entities the executor never runs: their owner takes their messages."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


class CommandPoller:
    """Takes every message waiting on some raw subscriptions and hands each to its handler (caller's thread).

    Not thread-safe by itself: the node calls `poll` from the step thread with its lock held, the
    lock its services take too, so a handler sees the same state it would see in an executor callback.
    """

    def __init__(self, sweep_every: int = SWEEP_EVERY) -> None:
        # (topic key, rclpy's bindings' subscription, message type, handler): `Subscription.handle` is a Python
        # property, taken once here rather than per take
        self._subs: list[tuple[str, object, type, Handler]] = []
        self._active: list[tuple[str, object, type, Handler]] = []  # the ones with a publisher at the last sweep
        self._sweep_every = sweep_every
        self._until_sweep = 0

    def add(self, key: str, subscription, handler: Handler) -> None:
        if not subscription.raw:
            raise InputError(f"subscription {subscription.topic_name}: polled subscriptions are raw (CDR bytes)")
        self._subs.append((key, subscription.handle, subscription.msg_type, handler))
        self._until_sweep = 0  # the next poll sweeps

    def poll(self) -> int:
        """Take and handle every waiting message of the active subscriptions (all of them every
        `sweep_every` polls), topic by topic in arrival order; returns how many."""
        self._until_sweep -= 1
        if self._until_sweep <= 0:
            return self.sweep()
        n = 0
        for entry in self._active:
            n += _take_all(*entry)
        return n

    def sweep(self) -> int:
        """Take from every subscription now and note which have a matched publisher; returns the messages taken."""
        self._until_sweep = self._sweep_every
        active, n = [], 0
        for entry in self._subs:
            taken = _take_all(*entry)
            n += taken
            try:
                if taken or _publisher_count(entry[1]) > 0:
                    active.append(entry)
            except InvalidHandle:  # destroyed (shutdown)
                pass
        self._active = active
        return n


def _publisher_count(handle) -> int:
    with handle:
        return handle.get_publisher_count()


def _take_all(key: str, handle, msg_type: type, handler: Handler) -> int:
    """Hand every message waiting on the subscription `handle` (of `msg_type`) to `handler`; returns how many."""
    n = 0
    while True:
        try:
            with handle:
                taken = handle.take_message(msg_type, True)
        except InvalidHandle:  # destroyed (shutdown): nothing more to take
            return n
        if taken is None:
            return n
        handler(key, taken[0], taken[1])
        n += 1
