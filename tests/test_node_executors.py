"""The node's executors (prsm_ros.node.executors): both deliver a command with its message info, and
neither sees the command subscriptions the step thread polls.

The events executor of rclpy 9.x hands a (message, info) callback one tuple instead of two
arguments; `TakesInfo` must give the callback the same two arguments under both executors, with
the writer's gid in the info (the node decides ownership from it).
"""

from __future__ import annotations

import threading
import time

import pytest
import rclpy
from rclpy.node import Node
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from prsm_ros.cdr_read import float64_data
from prsm_ros.node.command_poll import PolledGroup
from prsm_ros.node.executors import EXECUTORS, TakesInfo, events_executor_class, make_executor
from prsm_ros.node.parameters import ConfigError

from ros_procs import domain_id

WAIT_S = 30.0  # discovery on a loaded machine


@pytest.fixture
def context():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id("executors"),
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    yield ctx
    rclpy.try_shutdown(context=ctx)


def test_takes_info_passes_message_and_info_in_either_calling_form():
    got = []
    cb = TakesInfo(lambda msg, info: got.append((msg, info)))
    cb(b"x", {"publisher_gid": 1})  # the Python executor's form
    cb((b"y", {"publisher_gid": 2}))  # the events executor's form (rclpy 9.x)
    assert got == [(b"x", {"publisher_gid": 1}), (b"y", {"publisher_gid": 2})]


def test_make_executor_refuses_an_unknown_kind_naming_the_choices():
    with pytest.raises(ConfigError, match="executor 'fastest'.*events, single"):
        make_executor("fastest")


@pytest.mark.parametrize("kind", EXECUTORS)
def test_each_executor_delivers_a_raw_command_with_its_writer_and_skips_polled_ones(context, kind):
    """Over DDS in one process: a raw subscription behind `TakesInfo` gets the bytes and the writer's
    gid; a PolledGroup subscription hidden the way PrsmNode hides it keeps its message for the poll."""
    if kind == "events" and events_executor_class() is None:
        pytest.skip("this rclpy has no EventsExecutor")

    class Hiding(Node):  # PrsmNode's rule, on a bare node
        @property
        def subscriptions(self):
            return (s for s in super().subscriptions if not isinstance(s.callback_group, PolledGroup))

    node = Hiding("exec_probe", context=context)
    got, polled_calls = [], []
    arrived = threading.Event()

    def on(msg, info):
        got.append((msg, info))
        arrived.set()
    sub = node.create_subscription(Float64, "/exec_probe/cmd", TakesInfo(on), 10, raw=True,
                                   callback_group=MutuallyExclusiveCallbackGroup())
    polled = node.create_subscription(Float64, "/exec_probe/polled", TakesInfo(lambda m, i: polled_calls.append(m)),
                                      10, raw=True, callback_group=PolledGroup())
    pub = node.create_publisher(Float64, "/exec_probe/cmd", 10)
    pub_polled = node.create_publisher(Float64, "/exec_probe/polled", 10)
    executor, made = make_executor(kind, context)
    executor.add_node(node)
    try:
        assert made == kind
        end = time.monotonic() + WAIT_S
        while (sub.get_publisher_count() == 0 or polled.get_publisher_count() == 0) and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        pub.publish(Float64(data=2.5))
        pub_polled.publish(Float64(data=7.0))
        while not arrived.is_set() and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        for _ in range(5):  # a chance for a wrongly registered polled subscription to run
            executor.spin_once(timeout_sec=0.02)
        assert len(got) == 1
        raw, info = got[0]
        assert isinstance(raw, bytes) and float64_data(raw) == 2.5
        assert info["publisher_gid"] is not None and info["source_timestamp"] > 0
        assert polled_calls == []
        with polled.handle:  # still there for the step thread's take
            taken = polled.handle.take_message(polled.msg_type, True)
        assert taken is not None and float64_data(taken[0]) == 7.0
    finally:
        executor.shutdown()
        node.destroy_node()


@pytest.mark.slow  # builds a whole node (about 3 s)
def test_the_node_hides_its_polled_command_subscriptions_from_executors(context):
    """realtime: the command topics (PolledGroup) are out of `subscriptions` and their QoS event
    handlers out of `waitables`; the owned inputs stay (the executor takes those)."""
    from prsm_ros.node.ros_node import PrsmNode
    node = PrsmNode(context=context, parameter_overrides=[Parameter("record", value=False),
                                                          Parameter("start_paused", value=True)])
    try:
        seen = {s.topic_name for s in node.subscriptions}
        polled = {s.topic_name for s in node._subscriptions if isinstance(s.callback_group, PolledGroup)}
        assert polled and not (seen & polled)
        assert "/prsm_actuator/inject_fault" in seen
        assert not any(isinstance(getattr(w, "callback_group", None), PolledGroup) for w in node.waitables)
    finally:
        node.close()
        node.destroy_node()
