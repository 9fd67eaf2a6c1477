"""The executor that runs the node's callbacks (services, parameters, timers, lockstep commands).

`executor` (a start-up parameter) chooses it:

- `events` (the default where rclpy has it): rclpy's `EventsExecutor` (`rclpy.experimental`, C++).
  The middleware calls it back when an entity has work, so there is no wait set to rebuild in
  Python on every wake-up. In lockstep, where every command wakes the executor, the Python
  executor's own bookkeeping (wait set, tasks, callback groups) was about half of the node's
  main thread (py-spy, 200 Hz, fu2018 at the controller's pace): that is what this one removes.
- `single`: rclpy's `SingleThreadedExecutor` (pure Python), kept for an rclpy without the
  events executor and to compare the two.

Both run every callback on the thread that spins, one at a time, in arrival order per entity, so
the node's lock and ordering hold the same way. Two differences are dealt with here and in the
node: the events executor ignores callback groups (so the command subscriptions the step thread
polls are kept out of every executor's sight by the node, `PrsmNode.subscriptions`), and some
rclpy releases hand a (message, info) callback its two arguments as one tuple (`TakesInfo`).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

import rclpy.executors

from prsm_ros.node.parameters import EXECUTORS, ConfigError

__all__ = ["EXECUTORS", "TakesInfo", "events_executor_class", "make_executor"]


def events_executor_class():
    """rclpy's EventsExecutor factory, or None in an rclpy without it."""
    try:
        from rclpy.experimental import EventsExecutor
    except ImportError:
        return None
    return EventsExecutor


def make_executor(kind: str, context=None):
    """The executor named `kind` (one of EXECUTORS) on `context`; `events` falls back to `single`
    where rclpy has no EventsExecutor. Returns (executor, the kind actually made)."""
    if kind not in EXECUTORS:
        raise ConfigError(f"executor {kind!r}: expected one of {', '.join(EXECUTORS)}")
    events = events_executor_class() if kind == "events" else None
    if events is not None:
        return events(context=context), "events"
    return rclpy.executors.SingleThreadedExecutor(context=context), "single"


_INFO_SIGNATURE = inspect.Signature([inspect.Parameter("msg", inspect.Parameter.POSITIONAL_ONLY),
                                     inspect.Parameter("info", inspect.Parameter.POSITIONAL_ONLY)])


class TakesInfo:
    """A subscription callback `fn(msg, info)` that either executor calls correctly.

    rclpy decides from the callback's signature whether it wants the message info; the Python
    executor then calls `fn(msg, info)`, while the events executor of rclpy 9.x (Kilted) calls
    `fn((msg, info))`, which a two-argument function refuses (surfacing as "SystemError: null
    argument to internal routine"). This callable declares two parameters and accepts both forms.
    """

    __signature__ = _INFO_SIGNATURE

    def __init__(self, fn: Callable[[object, dict], None]) -> None:
        self.fn = fn

    def __call__(self, *args) -> None:
        if len(args) == 1:  # the events executor's form: one (message, info) tuple
            args = args[0]
        msg, info = args
        self.fn(msg, info)
