"""The step thread's command poller (prsm_ros.node.command_poll): which subscriptions each step takes from.

Pure Python: stand-in subscriptions with what the poller uses (`raw`, `msg_type` and the handle's `take_message`
and `get_publisher_count`, as rclpy's bindings have them), so what is taken, when, and in which order is
checked exactly; tests/test_node_realtime.py checks the same path over DDS.
"""

from __future__ import annotations

from collections import deque

from prsm_ros.node.command_poll import CommandPoller


class FakeHandle:
    def __init__(self, sub: FakeSub) -> None:
        self.sub = sub

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        return None

    def take_message(self, msg_type, raw: bool):
        self.sub.takes += 1
        return (self.sub.queue.popleft(), {"source_timestamp": 0}) if self.sub.queue else None

    def get_publisher_count(self) -> int:
        return self.sub.publishers


class FakeSub:
    """A raw subscription: a queue of messages and a matched-publisher count the test sets."""

    raw = True
    msg_type = bytes

    def __init__(self, name: str) -> None:
        self.topic_name = name
        self.queue: deque = deque()
        self.publishers = 0
        self.takes = 0
        self.handle = FakeHandle(self)


def make(sweep_every=10):
    got = []
    poller = CommandPoller(sweep_every=sweep_every)
    subs = {k: FakeSub(k) for k in ("torque", "velocity", "position")}
    for k, s in subs.items():
        poller.add(k, s, lambda key, raw, info: got.append((key, raw)))
    return poller, subs, got


def test_each_step_takes_only_from_topics_with_a_publisher():
    poller, subs, got = make()
    subs["torque"].publishers = 1
    poller.poll()  # the first poll sweeps: every subscription once
    assert {k: s.takes for k, s in subs.items()} == {"torque": 1, "velocity": 1, "position": 1}
    for i in range(9):
        subs["torque"].queue.append(b"t%d" % i)
        assert poller.poll() == 1
    # the torque topic was taken from every step (its message and the empty take that ends it), the others not
    assert subs["torque"].takes == 1 + 9 * 2
    assert subs["velocity"].takes == subs["position"].takes == 1
    assert got == [("torque", b"t%d" % i) for i in range(9)]


def test_a_message_on_a_topic_without_publisher_is_taken_at_the_next_sweep_never_lost():
    """A publisher that matched, sent and left between two sweeps (count 0 at both) leaves its message
    queued: the next sweep, at most `sweep_every` polls later, takes it."""
    poller, subs, got = make(sweep_every=5)
    poller.poll()  # sweep: nobody publishes
    subs["position"].queue.append(b"once")  # came and went since
    taken = [poller.poll() for _ in range(5)]
    assert taken == [0, 0, 0, 0, 1]  # polls 2-5 skip it, poll 6 sweeps
    assert got == [("position", b"once")]


def test_a_topic_that_delivered_stays_active_and_order_is_kept_per_topic():
    poller, subs, got = make(sweep_every=3)
    subs["velocity"].queue.extend([b"v1", b"v2"])  # no count yet (discovery lag), messages already there
    poller.poll()  # sweep takes both and marks the topic active for the next polls
    subs["velocity"].queue.append(b"v3")
    poller.poll()
    assert got == [("velocity", b"v1"), ("velocity", b"v2"), ("velocity", b"v3")]
    subs["torque"].publishers = 1
    subs["torque"].queue.append(b"t1")
    assert poller.poll() == 0  # not yet known to publish: waits for the sweep
    assert poller.poll() == 1  # the sweep (every 3rd poll)
    assert got[-1] == ("torque", b"t1")


def test_sweep_on_demand_takes_everything():
    """While paused the node sweeps (every subscription) each time it polls."""
    poller, subs, got = make()
    for k, s in subs.items():
        s.queue.append(k.encode())
    assert poller.sweep() == 3
    assert sorted(got) == [("position", b"position"), ("torque", b"torque"), ("velocity", b"velocity")]
