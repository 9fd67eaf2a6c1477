"""Command subscriptions the step thread reads itself, with no executor wake-up per message (issue 15).

At 1 kHz the rclpy executor was the node's largest cost: every command woke it, and each wake-up
rebuilt the wait set, the task and the callback-group bookkeeping in Python (py-spy: about half a
core for 1,000 commands/s, more than the step and the recorder together). In `realtime` and
`fast` mode the step thread needs a command only at the start of a step, so it takes what is
waiting itself, once per step, with the subscription's non-blocking take (rclpy's
`Subscription.handle.take_message(msg_type, raw)`, the call the executor makes), and hands each
message to the same handler the executor would have called. The newest command is then applied
at the next step, as it would be after an executor callback.

The subscriptions belong to a `PolledGroup`, a callback group the executor never waits on (its
`can_execute` is false), so the executor neither wakes for them nor takes their messages. Their
QoS event handlers (rclpy's default warnings about a publisher with incompatible QoS or type)
stay in that group, so those two warnings are not logged for the command topics: handed to the
executor, they kept it spinning without pause under 1 kHz commands (measured: the main thread
at 52–69 % of a core instead of 1 %; the cause inside the middleware was not traced). The
messages stay raw CDR bytes: the node records them as they are and decodes only what it reads.
`lockstep` keeps the executor: there a command is what advances time, so it must wake the node.
"""

from __future__ import annotations

from collections.abc import Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.exceptions import InvalidHandle

# a handler takes (topic key, CDR bytes, rclpy message info dict), as a two-argument raw callback would
Handler = Callable[[str, bytes, dict], None]


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

    def __init__(self) -> None:
        self._subs: list[tuple[str, object, Handler]] = []

    def add(self, key: str, subscription, handler: Handler) -> None:
        if not subscription.raw:
            raise ValueError(f"subscription {subscription.topic_name}: polled subscriptions are raw (CDR bytes)")
        self._subs.append((key, subscription, handler))

    def poll(self) -> int:
        """Take and handle every waiting message, topic by topic in arrival order; returns how many."""
        n = 0
        for key, sub, handler in self._subs:
            handle, msg_type = sub.handle, sub.msg_type
            while True:
                try:
                    with handle:
                        taken = handle.take_message(msg_type, True)
                except InvalidHandle:  # destroyed (shutdown): nothing more to take
                    break
                if taken is None:
                    break
                handler(key, taken[0], taken[1])
                n += 1
        return n
