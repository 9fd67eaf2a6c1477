"""The floors `prsm-bench --only realtime` sets beside the node's CPU: `rclpy_floor`, bare and recording.

Real processes over DDS: the floor and the bench's reference controller (`rt_controller`), each in its own
process on this test's domain; the recording floor's file is read back by the `mcap` library's reader, not by
the writer that made it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time

import pytest

from prsm_ros.ros_env import start_module
from ros_procs import CEILING_FACTOR, NodeProcess, ros_test_env, thread_cpus, thread_ids

pytestmark = pytest.mark.slow


def test_the_recording_floor_writes_what_the_node_records_for_every_period_it_publishes(tmp_path):
    """`rclpy_floor --record`: each period's joint_states, the echo of each command taken, the command itself and a
    jones2016 step's wrench, internal loads and /clock, all written to an MCAP file by foxglove-sdk's writer, while
    the controller gets its states. Oracles: the controller's own count of the states it received, the floor's
    rules (one state, wrench, loads and /clock per period; one echo per command taken), and the bytes of the bench's
    prepared jones2016 steps, built by the node's encoder."""
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64MultiArray

    from prsm_ros.bench.recorder import prepared_steps
    from prsm_ros.interface import STEP_TOPICS
    from prsm_ros.messages import TOPICS

    env = ros_test_env("bench_floor")
    path = tmp_path / "floor.mcap"
    with NodeProcess(env, workdir=tmp_path / "floor", module="prsm_ros.bench.rclpy_floor",
                     extra_args=["--record", "--record-to", str(path)]) as floor:
        ctl = start_module("prsm_ros.bench.rt_controller", ["--duration", "2"], env, cwd=tmp_path,
                           stdout=subprocess.PIPE)
        out, _ = ctl.communicate(timeout=120 * CEILING_FACTOR)
        assert ctl.returncode == 0, out[-500:]
        summary = json.loads(out.decode().strip().splitlines()[-1])
        assert floor.stop(signal.SIGINT) == 0, floor.stderr
    assert summary["states_received"] > 1000 and summary["echo_seen"]

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary_section = reader.get_summary()
        assert summary_section is not None  # closed with its summary: the floor ended cleanly
        by_topic: dict[str, list[bytes]] = {}
        for _schema, channel, message in reader.iter_messages():
            by_topic.setdefault(channel.topic, []).append(message.data)
        profile = reader.get_header().profile
    assert profile == "ros2"
    name = {k: TOPICS[k].resolved() for k in ("screw_torque", "command_echo", *STEP_TOPICS)}
    periods = len(by_topic[name["joint_states"]])
    assert periods >= summary["states_received"]  # every state a reader got was recorded (and the rest too)
    for key in ("wrench", "internal_loads", "clock"):
        assert len(by_topic[name[key]]) == periods, key
    commands = len(by_topic[name["screw_torque"]])
    assert 0 < len(by_topic[name["command_echo"]]) <= commands  # one echo per period that took a command
    # decoded, not compared byte for byte: rclpy's serialiser leaves the CDR alignment padding as it finds it in
    # memory, so two processes' bytes for one message can differ there (the recorder zeroes it for golden bags)
    steps = prepared_steps("jones2016", 1000)
    loads = 1 + STEP_TOPICS.index("internal_loads")
    decoded = [deserialize_message(data, Float64MultiArray) for data in by_topic[name["internal_loads"]][:5]]
    expected = [deserialize_message(steps[k % len(steps)][1][loads], Float64MultiArray) for k in range(1, 6)]
    assert [list(m.data) for m in decoded] == [list(m.data) for m in expected]
    assert [[(d.label, d.size) for d in m.layout.dim] for m in decoded] == \
        [[(d.label, d.size) for d in m.layout.dim] for m in expected]


def test_the_floor_and_the_controller_keep_off_the_loops_cpu_as_the_node_does(tmp_path):
    """`rclpy_floor --step-thread-cpu N` and `rt_controller --cpus`: the floor's loop thread alone on CPU N, its
    other threads (the middleware's) and every thread of the controller off it, read from the kernel's affinity
    lists while the controller gets its states (the bench's pinned floor: the node's `step_thread_cpu`)."""
    cpus = sorted(os.sched_getaffinity(0))
    cpu, rest = cpus[-1], cpus[:-1]
    env = ros_test_env("bench_floor_cpu")
    if not rest:  # one CPU: the floor refuses it, as the node does
        with NodeProcess(env, workdir=tmp_path / "floor", module="prsm_ros.bench.rclpy_floor",
                         extra_args=["--step-thread-cpu", str(cpu)]) as floor:
            assert floor.wait(60) == 2
            assert "--step-thread-cpu" in floor.stderr and "with another left for the other threads" in floor.stderr
        return
    with NodeProcess(env, workdir=tmp_path / "floor", module="prsm_ros.bench.rclpy_floor",
                     extra_args=["--step-thread-cpu", str(cpu)]) as floor:
        ctl = start_module("prsm_ros.bench.rt_controller",
                           ["--duration", "3", "--cpus", ",".join(map(str, rest))], env, cwd=tmp_path,
                           stdout=subprocess.PIPE)
        seen = None
        deadline = time.monotonic() + 120 * CEILING_FACTOR
        for raw in ctl.stdout:  # the controller says "measuring" once states flow: the loop is running by then
            if raw.strip() == b"measuring":
                seen = ({t: thread_cpus(floor.proc.pid, t) for t in thread_ids(floor.proc.pid)},
                        {t: thread_cpus(ctl.pid, t) for t in thread_ids(ctl.pid)})
            if time.monotonic() > deadline:
                break
        assert ctl.wait(timeout=120 * CEILING_FACTOR) == 0
        assert floor.stop(signal.SIGINT) == 0, floor.stderr
    assert seen is not None, "the controller never started measuring"
    floor_threads, ctl_threads = seen
    assert [t for t, c in floor_threads.items() if c == {cpu}] == [floor.proc.pid]  # the loop: the main thread
    assert all(cpu not in c for t, c in floor_threads.items() if t != floor.proc.pid), floor_threads
    assert ctl_threads and all(c == set(rest) for c in ctl_threads.values()), ctl_threads
