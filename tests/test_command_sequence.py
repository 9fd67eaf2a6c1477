"""Commands superseded in a reader's queue, counted from each writer's publication sequence numbers.

Oracle: sequences written by hand (a writer that sent 1..10 of which the node took 1, 4, 10 lost
2, 3, 5..9 = 7 commands), and a real keep-last-1 reader on this machine's DDS that is sent N
commands before it takes one: N − 1 superseded.
"""

from __future__ import annotations

import time

import pytest

from prsm_ros.node.command_sequence import SupersededCounter


def info(writer: int, seq: int) -> dict:
    return {"publication_sequence_number": seq, "publisher_gid": {"data": bytes([writer]) * 16}}


def test_gaps_per_writer_and_topic():
    c = SupersededCounter()
    assert [c.observe("screw_torque", info(1, s)) for s in (1, 4, 10)] == [0, 2, 5]
    assert c.observe("screw_torque", info(2, 7)) == 6  # another writer, first taken at 7: its 1..6 never taken
    assert c.observe("position_command", info(2, 9)) == 1
    assert c.total == 14 and dict(c.by_topic) == {"screw_torque": 13, "position_command": 1}
    assert c.report()["commands_superseded"] == "14"
    c.reset()
    assert c.observe("screw_torque", info(1, 11)) == 0 and c.total == 0


def test_without_sequence_numbers_the_count_says_unknown():
    c = SupersededCounter()
    assert c.observe("screw_torque", {"source_timestamp": 1}) == 0
    assert c.report()["commands_superseded"].startswith("unknown")


def test_a_keep_last_1_reader_on_dds(monkeypatch):
    rclpy = pytest.importorskip("rclpy")
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64
    from ros_procs import CEILING_FACTOR, ros_test_env
    env = ros_test_env("test_command_sequence")
    ctx = rclpy.Context()
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", env["ROS_AUTOMATIC_DISCOVERY_RANGE"])
    rclpy.init(context=ctx, domain_id=int(env["ROS_DOMAIN_ID"]), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node("seq_test", context=ctx)
        sub = node.create_subscription(Float64, "cmd", lambda m: None,
                                       QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE), raw=True)
        pub = node.create_publisher(Float64, "cmd", QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        end = time.monotonic() + 20 * CEILING_FACTOR
        counter, taken = SupersededCounter(), []

        def take_all():
            while True:
                with sub.handle:
                    t = sub.handle.take_message(Float64, True)
                if t is None:
                    return
                taken.append(t)
                counter.observe("cmd", t[1])
        while sub.get_publisher_count() == 0:
            assert time.monotonic() < end, "the reader never matched"
        pub.publish(Float64(data=-1.0))
        while not taken:  # the first sample (number 1)
            take_all()
            assert time.monotonic() < end
        assert counter.total == 0
        for k in range(6):
            pub.publish(Float64(data=float(k)))
        assert pub.wait_for_all_acked(rclpy.duration.Duration(seconds=10 * CEILING_FACTOR))
        take_all()
        assert len(taken) == 2 and counter.total == 5  # 6 sent, the newest kept, 5 replaced in the queue
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.slow
def test_node_counts_what_its_reader_replaced_and_the_bag_says_so(tmp_path, capsys):
    """A controller bursts N torques into a realtime node: every command is either in the bag
    (received) or counted as superseded, on /diagnostics and in `prsm-bag info`."""
    pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64
    from prsm_ros.cli.bag import main as bag_main
    from ros_procs import NodeProcess, RosClient, diagnostics_of, ros_test_env
    env = ros_test_env("test_command_sequence_node")
    n = 300
    bag = tmp_path / "run.mcap"
    params = {"model": "ideal", "record_path": str(bag), "diagnostics_rate": 20.0, "cmd_timeout": 0.0}
    with NodeProcess(env, params, workdir=tmp_path / "run") as proc, RosClient(env) as cli:
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        pub = cli.publisher("/prsm_actuator/screw_torque", Float64)
        cli.wait_for_node(proc)
        for k in range(n):
            pub.publish(Float64(data=1e-3 * k))

        def counts():
            for m in reversed(diag):
                level, _, v = diagnostics_of(m)
                if "commands_superseded" in v:
                    return int(v["commands_received"]), int(v["commands_superseded"])
            return 0, 0
        cli.spin_until(lambda: sum(counts()) == n, 20.0, f"received + superseded = {n}")
        received, superseded = counts()
        assert proc.stop() == 0, proc.stderr
    assert bag_main(["info", str(bag), "--json"]) == 0
    import json
    d = json.loads(capsys.readouterr().out)
    assert d["commands"]["commands_received"] + d["commands"]["commands_superseded"] == n
    assert next(t["count"] for t in d["topics"] if t["topic"] == "/prsm_actuator/screw_torque") == \
        d["commands"]["commands_received"]
