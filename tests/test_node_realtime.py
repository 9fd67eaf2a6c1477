"""The realtime loop a controller can trust (issue 15), over DDS with real processes.

- `~/command_echo`: each command's own stamp comes back with the step that first applied it, and
  the node reports the command-to-state latency on /diagnostics;
- one controller owns the actuator: another participant's commands are refused, counted and named
  (in lockstep they do not advance time) until `~/release_control`, on every command topic (in
  realtime the step thread takes the commands itself);
- two actuators in one graph, a controller each: one /clock that never goes backwards, two
  /diagnostics names, two complete bags in one directory (never one overwriting the other).

Waits are on events with generous ceilings (the machine may be loaded); no figure is a speed.
"""

from __future__ import annotations

import os
import signal
import time

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from ros_procs import NodeProcess, RosClient, diagnostics_of, ros_test_env, thread_cpus, thread_ids  # noqa: E402

# the slow tier (.ci/run runs it after the README's test command): many node or Ray start-ups
pytestmark = pytest.mark.slow

ENV = ros_test_env("test_node_realtime")


def stamp_ns(t) -> int:
    return t.sec * 1_000_000_000 + t.nanosec


def test_command_echo_carries_the_command_stamp_and_latency_is_reported(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState, TimeReference
    from std_msgs.msg import Float64
    # 200 Hz: the Python test client keeps up with the states on a loaded machine
    params = {"time_mode": "realtime", "record": False, "diagnostics_rate": 10.0, "update_rate": 200}
    with NodeProcess(ENV, params, workdir=tmp_path) as proc, RosClient(ENV) as cli:
        js = cli.subscribe("/joint_states", JointState)
        echo = cli.subscribe("/prsm_actuator/command_echo", TimeReference)
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        cli.publisher("/prsm_actuator/screw_torque", Float64)
        cli.wait_for_node(proc, timeout=60.0)
        for k in range(5):
            value = 1e-4 * (k + 1)
            n_echo = len(echo)
            before = time.time_ns()
            cli.publish("/prsm_actuator/screw_torque", Float64(data=value))
            after = time.time_ns()
            cli.spin_until(lambda: len(echo) > n_echo, 30.0, f"the echo of command {k}")
            e = echo[n_echo]
            # the command's DDS source timestamp, taken inside publish()
            assert before <= stamp_ns(e.time_ref) <= after
            assert e.source == "/prsm_actuator/screw_torque"
            step = stamp_ns(e.header.stamp)
            cli.spin_until(lambda: js and stamp_ns(js[-1].header.stamp) >= step, 30.0, "the echoed step's state")
            by_stamp = {stamp_ns(m.header.stamp): m for m in js}
            assert by_stamp[step].effort[0] == value  # the first state that reflects this command
            assert not any(m.effort[0] == value for t, m in by_stamp.items() if t < step)

        def latency_reported() -> bool:
            return any(diagnostics_of(m)[2].get("command_latency_p50_ms", "n/a") != "n/a" for m in diag)
        cli.spin_until(latency_reported, 30.0, "command latency on /diagnostics")
        v = next(diagnostics_of(m)[2] for m in diag if diagnostics_of(m)[2]["command_latency_p50_ms"] != "n/a")
        assert 0.0 < float(v["command_latency_p50_ms"]) <= float(v["command_latency_max_ms"])
        assert proc.stop(signal.SIGINT) == 0, proc.stderr


def test_a_second_controller_is_refused_counted_and_does_not_advance_lockstep(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger
    params = {"time_mode": "lockstep", "record": False, "cmd_timeout": 0.0, "ownership_timeout": 0.0,
              "diagnostics_rate": 20.0}
    topic = "/prsm_actuator/screw_torque"
    with NodeProcess(ENV, params, workdir=tmp_path) as proc, RosClient(ENV) as a, \
            RosClient(ENV, name="prsm_second_controller") as b:
        js = a.subscribe("/joint_states", JointState)
        diag = a.subscribe("/diagnostics", DiagnosticArray)
        a.publisher(topic, Float64)
        b.publisher(topic, Float64)
        a.wait_for_node(proc, timeout=60.0)
        b.wait_for_node(proc, timeout=60.0)

        a.publish(topic, Float64(data=0.5))
        a.spin_until(lambda: len(js) == 1, 30.0, "the owner's first lockstep state")
        assert js[0].effort[0] == 0.5

        def refused(n: int):
            return lambda: bool(diag) and int(diagnostics_of(diag[-1])[2]["commands_refused_not_owner"]) >= n
        for k in range(3):  # one at a time: the node's command reader keeps only the newest (depth 1)
            b.publish(topic, Float64(data=0.7))
            a.spin_until(refused(k + 1), 30.0, f"refusal {k + 1} on /diagnostics")
        v = diagnostics_of(diag[-1])[2]
        assert len(js) == 1  # refused commands did not advance time
        owner = v["command_owner"]
        assert owner != "none" and owner not in v["refused_participants"] and "(3)" in v["refused_participants"]

        res = b.call("/prsm_actuator/release_control", Trigger)
        assert res.success and owner in res.message
        b.publish(topic, Float64(data=0.7))
        a.spin_until(lambda: len(js) == 2, 30.0, "the new owner's state")
        assert js[1].effort[0] == 0.7
        a.publish(topic, Float64(data=0.1))  # now the first controller is the other one
        a.spin_until(refused(4), 30.0, "the old owner refused")
        assert len(js) == 2 and diagnostics_of(diag[-1])[2]["command_owner"] not in ("none", owner)
        assert proc.stop(signal.SIGINT) == 0, proc.stderr


def test_a_reader_that_joins_later_gets_the_per_step_topics(tmp_path):
    """In realtime a per-step topic with no matched reader is handed only to the bag, not to DDS
    (ros_node module doc: the readers are counted every READER_COUNT_EVERY steps, and such a topic
    asks again before each message). A reader that subscribes after the node has stepped for a while,
    past several counts, still gets every such topic: the wrench, /clock and the internal loads,
    stamped with the node's own increasing steps; and the echo of a command sent as soon as its
    reader is matched, between two counts (a sparse topic: a wait for the next count loses it)."""
    from geometry_msgs.msg import WrenchStamped
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState, TimeReference
    from std_msgs.msg import Float64, Float64MultiArray
    from prsm_ros.node.ros_node import READER_COUNT_EVERY
    params = {"time_mode": "realtime", "record": False, "update_rate": 200, "internal_loads_rate": 50.0}
    with NodeProcess(ENV, params, workdir=tmp_path) as proc, RosClient(ENV) as cli:
        js = cli.subscribe("/joint_states", JointState)
        cli.wait_for_node(proc, timeout=60.0)
        cli.spin_until(lambda: len(js) >= 3 * READER_COUNT_EVERY, 60.0, "the node stepping past three reader counts")
        wrench = cli.subscribe("/prsm_actuator/nut/wrench", WrenchStamped)
        clock = cli.subscribe("/clock", Clock)
        loads = cli.subscribe("/prsm_actuator/internal_loads", Float64MultiArray)
        cli.spin_until(lambda: len(wrench) >= 5 and len(clock) >= 5 and len(loads) >= 2, 60.0,
                       "wrench, /clock and internal loads after joining")
        for stamps in ([stamp_ns(m.header.stamp) for m in wrench], [stamp_ns(m.clock) for m in clock]):
            assert stamps == sorted(set(stamps)) and stamps[0] > stamp_ns(js[0].header.stamp)
        echo = cli.subscribe("/prsm_actuator/command_echo", TimeReference)
        cli.publisher("/prsm_actuator/screw_torque", Float64)
        cli.wait_for_node(proc, timeout=60.0)
        for k in range(3):  # one command at a time, each echoed once
            cli.publish("/prsm_actuator/screw_torque", Float64(data=1e-4 * (k + 1)))
            cli.spin_until(lambda: len(echo) > k, 30.0, f"the echo of command {k}")


def test_velocity_and_position_commands_are_owned_and_echoed_in_realtime(tmp_path):
    """The realtime node takes its commands in the step thread (command_poll), on every command
    topic: a velocity command is echoed with its own DDS stamp and makes its sender the owner;
    bytes that are no Float64 are counted as malformed (the step thread goes on); another
    participant's position and velocity commands are then refused, counted and named;
    after ~/release_control the other participant's position command is accepted and echoed.
    Each command is sent once and waited for (an event), so no timing is asserted."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import TimeReference
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger
    params = {"time_mode": "realtime", "record": False, "update_rate": 200, "diagnostics_rate": 10.0,
              "cmd_timeout": 0.0, "ownership_timeout": 0.0, "actuator": "{motor: {}}",
              "command_interface": "velocity"}
    vel, pos = "/prsm_actuator/velocity_command", "/prsm_actuator/position_command"
    with NodeProcess(ENV, params, workdir=tmp_path) as proc, RosClient(ENV) as a, \
            RosClient(ENV, name="prsm_second_controller") as b:
        echo = a.subscribe("/prsm_actuator/command_echo", TimeReference)
        diag = a.subscribe("/diagnostics", DiagnosticArray)
        for cli in (a, b):
            cli.publisher(vel, Float64)
            cli.publisher(pos, Float64)
        a.wait_for_node(proc, timeout=60.0)
        b.wait_for_node(proc, timeout=60.0)

        before = time.time_ns()
        a.publish(vel, Float64(data=2.0))
        after = time.time_ns()
        a.spin_until(lambda: any(e.source == vel for e in echo), 30.0, "the velocity command's echo")
        e = next(e for e in echo if e.source == vel)
        assert before <= stamp_ns(e.time_ref) <= after

        def values() -> dict:
            return diagnostics_of(diag[-1])[2] if diag else {}
        a.spin_until(lambda: values().get("command_owner", "none") != "none", 30.0, "the owner on /diagnostics")
        owner = values()["command_owner"]
        a.publisher(vel, Float64).publish(b"\x00\x01\x00\x00\x01")  # raw bytes that are no Float64: refused
        a.spin_until(lambda: int(values().get("rejected_malformed", 0)) >= 1, 30.0, "the malformed command counted")
        b.publish(pos, Float64(data=0.001))
        a.spin_until(lambda: int(values().get("commands_refused_not_owner", 0)) >= 1, 30.0, "a refused position command")
        b.publish(vel, Float64(data=-1.0))
        a.spin_until(lambda: int(values().get("commands_refused_not_owner", 0)) >= 2, 30.0, "a refused velocity command")
        v = values()
        assert owner not in v["refused_participants"] and "(2)" in v["refused_participants"]
        assert int(v["joint_states_readers"]) == 0  # nobody here reads the states

        assert b.call("/prsm_actuator/release_control", Trigger).success
        assert b.call("/prsm_actuator/release_control", Trigger).message == "no owner"
        n = len(echo)
        b.publish(vel, Float64(data=-1.0))
        a.spin_until(lambda: len(echo) > n and echo[-1].source == vel, 30.0, "the new owner's command echoed")
        a.spin_until(lambda: values().get("command_owner") not in (None, "none", owner), 30.0, "the new owner")
        assert proc.stop(signal.SIGINT) == 0, proc.stderr


def test_two_actuators_one_clock_two_names_two_complete_bags(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from mcap.reader import make_reader
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    shared = tmp_path / "bags"  # both record into one directory with default names
    shared.mkdir()
    procs = {}
    try:
        for ns, clock in (("a", True), ("b", False)):
            # 200 Hz: a Python test client on a loaded machine keeps up with two nodes' states and /clock
            procs[ns] = NodeProcess(ENV, {"time_mode": "realtime", "publish_clock": clock, "diagnostics_rate": 5.0,
                                          "update_rate": 200},
                                    workdir=tmp_path / ns, cwd=shared, extra_args=["--ros-args", "-r", f"__ns:=/{ns}"])
        with RosClient(ENV, name="controller_a", node_name="a/prsm_actuator") as ca, \
                RosClient(ENV, name="controller_b", node_name="b/prsm_actuator") as cb:
            clocks = ca.subscribe("/clock", Clock)
            diag = ca.subscribe("/diagnostics", DiagnosticArray)
            js = {"a": ca.subscribe("/a/joint_states", JointState), "b": cb.subscribe("/b/joint_states", JointState)}
            ca.publisher("/a/prsm_actuator/screw_torque", Float64)
            cb.publisher("/b/prsm_actuator/screw_torque", Float64)
            ca.wait_for_node(procs["a"], timeout=60.0)
            cb.wait_for_node(procs["b"], timeout=60.0)
            for cli, ns, value in ((ca, "a", 0.03), (cb, "b", -0.02)):
                cli.publish(f"/{ns}/prsm_actuator/screw_torque", Float64(data=value))
                cli.spin_until(lambda: any(m.effort[0] == value for m in js[ns]), 30.0, f"actuator {ns} following its controller")
            ours = {"/a/prsm_actuator: simulation", "/b/prsm_actuator: simulation"}  # one name per actuator
            names = lambda: {s.name for m in diag for s in m.status}  # noqa: E731
            ca.spin_until(lambda: ours <= names() and len(clocks) > 100, 30.0, "both diagnostics and /clock")
            assert ca.node.count_publishers("/clock") == 1
            t = [stamp_ns(m.clock) for m in clocks]
            assert all(t1 >= t0 for t0, t1 in zip(t, t[1:]))  # never backwards
        for p in procs.values():
            assert p.stop(signal.SIGINT) == 0, p.stderr
    finally:
        for p in procs.values():
            p.__exit__(None, None, None)
    bags = sorted(shared.glob("*.mcap"))
    assert [b.name.startswith(f"prsm_{ns}_prsm_actuator_") for b, ns in zip(bags, "ab")] == [True, True], bags
    for bag, ns in zip(bags, "ab"):
        with open(bag, "rb") as f:
            r = make_reader(f)
            summary = r.get_summary()
            assert summary is not None and summary.statistics is not None, f"{bag.name} not closed"
            topics = {c.topic for c in summary.channels.values()}
            assert f"/{ns}/joint_states" in topics and ("/clock" in topics) == (ns == "a")
            counts = summary.statistics.channel_message_counts
            js_id = next(i for i, c in summary.channels.items() if c.topic == f"/{ns}/joint_states")
            assert counts[js_id] > 100


def test_a_stalled_reader_loses_nothing_within_the_queue_and_only_the_oldest_beyond(tmp_path):
    """joint_states is reliable keep-last 100: a reader that stalls for less than 100 states loses
    none; one that stalls far longer gets the newest 100 and loses the oldest, while the node
    keeps stepping on time (its writer never waits for the reader). At update_rate 200 Hz the 100
    states span 0.5 s, so a Python client on a loaded machine is not what limits the test."""
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    params = {"time_mode": "realtime", "record": False, "update_rate": 200}
    period_ns = 5_000_000
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
    with NodeProcess(ENV, params, workdir=tmp_path) as proc, RosClient(ENV) as cli:
        js = cli.subscribe("/joint_states", JointState, qos)
        cli.wait_for_node(proc, timeout=60.0)
        cli.spin_until(lambda: len(js) > 20, 30.0, "states")
        n0 = len(js)
        time.sleep(0.1)  # the stall under test (20 states), not a wait for an event
        cli.spin_until(lambda: len(js) > n0 + 60, 30.0, "states after a short stall")
        t = [stamp_ns(m.header.stamp) for m in js]
        assert all(b - a == period_ns for a, b in zip(t[n0 - 5:], t[n0 - 5 + 1:])), "a state was lost"

        n1, last = len(js), stamp_ns(js[-1].header.stamp)
        time.sleep(2.0)  # 400 states: far more than the queue holds
        cli.spin_until(lambda: stamp_ns(js[-1].header.stamp) >= last + 1_500_000_000, 30.0, "states after a long stall")
        after = [stamp_ns(m.header.stamp) for m in js[n1:]]
        # the node stepped on through the stall; the reader got the newest states, not the oldest
        assert after[0] > last + period_ns
        lost = (after[-1] - last) // period_ns - len(after)
        assert lost > 0
        assert proc.stop(signal.SIGINT) == 0, proc.stderr


if __name__ == "__main__":
    raise SystemExit(pytest.main([__file__, "-q"]))



def test_the_step_thread_runs_on_its_cpu_and_every_other_thread_and_the_writer_off_it(tmp_path):
    """step_thread_cpu: the step thread alone on that CPU; the executor, the middleware's threads, the recorder and
    its writer process on the others (read from the kernel's affinity lists), and /diagnostics says so."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    cpus = sorted(os.sched_getaffinity(0))
    cpu = cpus[-1]
    if len(cpus) < 2:  # one CPU: the start is refused in one line, nothing moved
        with NodeProcess(ENV, {"step_thread_cpu": cpu, "record": False}, workdir=tmp_path / "node") as proc:
            assert proc.wait(60) == 2
            assert proc.stderr.strip() == (f"prsm-node: error: parameter step_thread_cpu = {cpu}: must be -1 here: "
                                           f"this process may run on CPU {cpu} only, and the node's other threads "
                                           "need a CPU besides the step thread's")
        return
    params = {"time_mode": "realtime", "update_rate": 200, "diagnostics_rate": 10.0, "step_thread_cpu": cpu,
              "record_path": str(tmp_path / "run.mcap")}
    with NodeProcess(ENV, params, workdir=tmp_path / "node") as proc, RosClient(ENV) as cli:
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        js = cli.subscribe("/joint_states", JointState)
        cli.wait_for_node(proc, timeout=60.0)
        # a report made after the node's start-up moved its threads
        cli.spin_until(lambda: js and any("middleware_threads_cpus" in diagnostics_of(m)[2] for m in diag), 60.0,
                       "a state and a diagnostics report with the threads' CPUs")
        report = next(diagnostics_of(m)[2] for m in reversed(diag) if "middleware_threads_cpus" in diagnostics_of(m)[2])
        pid = proc.proc.pid
        on_cpu = [t for t in thread_ids(pid) if thread_cpus(pid, t) == {cpu}]
        others = [t for t in thread_ids(pid) if t not in on_cpu]
        writers = [int(c) for t in thread_ids(pid)
                   for c in open(f"/proc/{pid}/task/{t}/children").read().split()]
        assert len(on_cpu) == 1, [(t, sorted(thread_cpus(pid, t))) for t in thread_ids(pid)]
        assert others and all(cpu not in thread_cpus(pid, t) for t in others)
        assert len(writers) == 1  # the MCAP writer process
        assert all(cpu not in thread_cpus(w, t) for w in writers for t in thread_ids(w))
        assert report["step_thread_cpus"] == f"CPU {cpu}"
        assert report["other_threads_cpus"] == ("CPU" if len(cpus) == 2 else "CPUs") + " " + \
            ", ".join(map(str, cpus[:-1]))
        assert report["middleware_threads_cpus"].startswith(report["other_threads_cpus"] + " (")
        assert proc.stop() == 0, proc.stderr
