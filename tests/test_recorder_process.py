"""The MCAP writer in a child process (`McapProcessRecorder`): the same bytes as the thread recorder, and
what each side's death does.

Oracles: the thread recorder's file for the same input (byte for byte, lockstep mode); the count
of messages offered (written + dropped + malformed); the values written, read back exactly as a
gapless prefix; the kernel's word that the child exited (a pidfd).
"""

from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from prsm_ros.bag.reader import open_bag, scan_records
from prsm_ros.messages import TOPICS
from prsm_ros.mcap.recorder import McapRecorder
from prsm_ros.mcap.recorder_process import McapProcessRecorder

from ros_procs import CEILING_FACTOR, NodeProcess, RosClient, diagnostics_of, ros_test_env

CHILD_ENV = {**os.environ, "RERUN": "off", "PYTHONUNBUFFERED": "1"}


def _wait_until(done, ceiling_s: float, what: str) -> None:
    end = time.monotonic() + ceiling_s * CEILING_FACTOR
    while not done():
        assert time.monotonic() < end, f"{what}: not within {ceiling_s * CEILING_FACTOR:g} s"
        time.sleep(0.005)


def _exited_within(pid: int, ceiling_s: float) -> bool:
    """Whether process `pid` (not our child) exits within `ceiling_s`: the kernel signals its pidfd."""
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    try:
        ready, _, _ = select.select([fd], [], [], ceiling_s)
        return bool(ready)
    finally:
        os.close(fd)


def _children(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    stat = f.read()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry))
    return out


def _steps(rec, steps: int, late_every: int = 7) -> None:
    """A lockstep node's traffic: a state per step, a command per step (untrusted, some malformed, padding
    not zeroed), and a reference that arrives one step behind the state it answers."""
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Header

    qos = TOPICS["screw_torque"].qos
    rec.add_channel("/joint_states", JointState, TOPICS["joint_states"].qos)
    rec.add_channel("/cmd", Float64, qos, untrusted=True)
    rec.add_channel("/ref", JointState, qos, untrusted=True)
    for k in range(steps):
        t = k * 1_000_000
        js = JointState(name=["screw_joint", "nut_joint"], position=[k * 0.1, k * 1e-4], velocity=[1.0, 2.0])
        js.header = Header()
        js.header.stamp.sec, js.header.stamp.nanosec = divmod(t, 10**9)
        cmd = serialize_message(Float64(data=0.5 * k)) if k % 50 else b"\x00\x01\x00\x00"  # too short: malformed
        items = [("/joint_states", js, t), ("/cmd", cmd, t)]
        if k % late_every == 0 and k:
            items.append(("/ref", serialize_message(js), t - 1_000_000))  # answers the previous state, late
        rec.write_many(items)


def test_lockstep_bag_is_byte_identical_to_the_thread_recorders(tmp_path):
    """The same input through both recorders in deterministic (lockstep) mode: the same file, byte for byte."""
    meta = {"prsm_run": {"preset": "s30", "model": "jones2016"}}
    files = []
    for Recorder in (McapRecorder, McapProcessRecorder):
        path = tmp_path / f"{Recorder.__name__}.mcap"
        rec = Recorder(path, metadata=meta, deterministic=True, chunk_size=64 << 10)  # several chunks
        _steps(rec, 3000)
        assert rec.close() and rec.error is None
        files.append(path.read_bytes())
        assert (rec.messages_written, rec.messages_malformed, rec.messages_dropped) == (2 * 3000 + 428 - 60, 60, 0)
    assert len(files[0]) > 200_000 and files[0] == files[1]
    bag = open_bag(tmp_path / "McapProcessRecorder.mcap")
    assert bag.complete and bag.topics["/cmd"].count == 3000 - 60 and bag.topics["/cmd"].malformed == 0


def test_a_hand_over_wakes_the_forwarder_once_its_time_has_come_not_its_clock(tmp_path, monkeypatch):
    """After a drain the forwarding thread is woken by the first `write_many` `FORWARD_NUDGE_AFTER_S` later (a
    paced caller's step has just ended then), not only by its clock. With the clock at an hour and the nudge at
    once, a step handed over is taken from the queue and written: only the nudge can have woken the forwarder.
    Oracle: the queue emptied within the ceiling, and the file read back (mcap's reader) holds the message."""
    from std_msgs.msg import Float64

    from prsm_ros.mcap import recorder_process
    monkeypatch.setattr(recorder_process, "FORWARD_WAKE_S", 3600.0)
    monkeypatch.setattr(recorder_process, "FORWARD_NUDGE_AFTER_S", 0.0)
    path = tmp_path / "n.mcap"
    rec = McapProcessRecorder(path, flush_interval_s=7200.0)  # its clock: min(flush interval / 2, FORWARD_WAKE_S)
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    rec.write_many([("/a", Float64(data=1.5), 7)])
    _wait_until(lambda: rec.queue_length == 0, 30, "the forwarder took the step")
    assert rec.close() and rec.messages_written == 1 and rec.messages_dropped == 0
    assert [m.msg.data for m in open_bag(path).messages(["/a"])] == [1.5]


def test_writer_killed_mid_run_sets_error_the_caller_runs_on_and_counts_stay_exact(tmp_path):
    from std_msgs.msg import Float64

    path = tmp_path / "k.mcap"
    rec = McapProcessRecorder(path, flush_interval_s=0.01)
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    offered = 0
    for k in range(2000):
        rec.write("/a", Float64(data=float(k)), k)
        offered += 1
    _wait_until(lambda: rec.messages_written == 2000, 20, "the child wrote the first 2000")
    _wait_until(lambda: scan_records(path).chunks >= 1, 20, "a chunk on disk")
    child = rec._proc.pid
    os.kill(child, signal.SIGKILL)
    assert _exited_within(child, 10 * CEILING_FACTOR)
    for k in range(2000, 30_000):  # never raises, never blocks: the caller is the node's step thread
        rec.write_many([("/a", Float64(data=float(k)), k)])
        offered += 1
    _wait_until(lambda: rec.error is not None, 10, "the error")
    assert rec.error == f"recording to {path} stopped: the writer process was killed by SIGKILL"
    assert not rec.close()
    assert rec.messages_written + rec.messages_dropped + rec.messages_malformed == offered
    assert rec.messages_dropped >= 28_000
    bag = open_bag(path)  # no summary: read up to its last complete chunk
    assert not bag.complete
    values = [m.msg.data for m in bag.messages(["/a"])]
    assert values == [float(k) for k in range(len(values))] and 0 < len(values) <= rec.messages_written


def test_a_writer_process_that_cannot_start_is_an_error_at_once_and_counts_stay_exact(tmp_path, monkeypatch):
    from std_msgs.msg import Float64

    def no_process(*args, **kwargs):
        raise BlockingIOError(11, "Resource temporarily unavailable")  # fork/exec refused: EAGAIN

    monkeypatch.setattr(subprocess, "Popen", no_process)
    rec = McapProcessRecorder(tmp_path / "n.mcap")
    assert rec.error == (f"recording to {tmp_path / 'n.mcap'} stopped: the writer process could not start: "
                         "Resource temporarily unavailable")
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    rec.write_many([("/a", Float64(data=1.0), k) for k in range(3)])
    assert not rec.close() and (rec.messages_written, rec.messages_dropped) == (0, 3)
    assert not (tmp_path / "n.mcap").exists()


def test_a_stalled_writer_process_lets_close_return_within_its_timeout(tmp_path):
    """The child stopped (SIGSTOP: a disk that no longer answers looks the same from here): close gives up
    within its timeout, kills it, says so, and counts every message."""
    from std_msgs.msg import Float64

    path = tmp_path / "s.mcap"
    rec = McapProcessRecorder(path)
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    os.kill(rec._proc.pid, signal.SIGSTOP)
    for k in range(20_000):
        rec.write_many([("/a", Float64(data=float(k)), k)])
    t0 = time.monotonic()
    assert not rec.close(timeout_s=1.0)
    assert time.monotonic() - t0 < 1.0 + 2.0  # the kill's reaping, bounded
    assert "did not finish within 1 s" in rec.error and "no summary" in rec.error
    assert rec.messages_written + rec.messages_dropped + rec.messages_malformed == 20_000
    assert rec._proc.poll() == -signal.SIGKILL


_WRITER = """
    import json, sys, time
    from std_msgs.msg import Float64
    from rclpy.qos import QoSProfile
    from prsm_ros.mcap.recorder_process import McapProcessRecorder
    rec = McapProcessRecorder(sys.argv[1], flush_interval_s=0.02)
    rec.add_channel("/value", Float64, QoSProfile(depth=10))
    print(json.dumps({"child": rec._proc.pid}), flush=True)
    k = 0
    while True:
        rec.write_many([("/value", Float64(data=float(j)), j) for j in range(k, k + 100)])
        k += 100
        time.sleep(0.001)
        if k % 2000 == 0:
            print(json.dumps({"written": rec.messages_written}), flush=True)
"""


def test_parent_killed_leaves_no_child_and_a_file_readable_to_its_last_chunk_and_repairable(tmp_path):
    path, fixed = tmp_path / "p.mcap", tmp_path / "fixed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(_WRITER), str(path)], stdout=subprocess.PIPE,
                            text=True, env=CHILD_ENV)
    try:
        child = json.loads(proc.stdout.readline())["child"]
        end = time.monotonic() + 60 * CEILING_FACTOR
        while scan_records(path).chunks < 2:  # an event read from the file: two complete chunks on disk
            line = proc.stdout.readline()
            assert line and time.monotonic() < end, "the writer never put 2 chunks on disk"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=10 * CEILING_FACTOR)
        proc.stdout.close()
    # the child sees its input end without a finish frame (or its parent gone) and exits at once
    assert _exited_within(child, 5.0 * CEILING_FACTOR), "the writer process outlived its parent"
    bag = open_bag(path)
    assert not bag.complete and "unfinished" in bag.note
    values = [m.msg.data for m in bag.messages(["/value"])]
    assert len(values) >= 2 and values == [float(k) for k in range(len(values))]
    res = subprocess.run([sys.executable, "-m", "prsm_ros.cli.bag", "repair", str(path), str(fixed)],
                         capture_output=True, text=True, timeout=60 * CEILING_FACTOR, env=CHILD_ENV)
    assert res.returncode == 0, res.stderr
    repaired = open_bag(fixed)
    assert repaired.complete and [m.msg.data for m in repaired.messages(["/value"])] == values


@pytest.mark.slow
def test_node_keeps_stepping_when_its_writer_process_is_killed(tmp_path):
    """A realtime prsm-node recording: its writer process SIGKILLed, /diagnostics names it, the node steps on."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock

    env = ros_test_env("recorder_process")
    bag = tmp_path / "node.mcap"
    with NodeProcess(env, {"record_path": str(bag)}, workdir=tmp_path) as node, RosClient(env) as cli:
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        clock = cli.subscribe("/clock", Clock)
        cli.spin_until(lambda: diag and int(diagnostics_of(diag[-1])[2]["record_written"]) > 0, 60.0,
                       "the bag being written")
        (writer,) = _children(node.proc.pid)
        os.kill(writer, signal.SIGKILL)
        cli.spin_until(lambda: diagnostics_of(diag[-1])[2]["record_error"] != "", 30.0, "the recording's error")
        level, _, values = diagnostics_of(diag[-1])
        assert values["record_error"] == f"recording to {bag} stopped: the writer process was killed by SIGKILL"
        assert level >= 1 and int(values["record_dropped"]) > 0
        n = len(clock)
        cli.spin_until(lambda: len(clock) > n + 500, 30.0, "steps after the writer died")
        assert node.stop(signal.SIGINT) == 0, node.stderr  # a lost recording is reported, never fatal
    assert "Traceback" not in node.stderr
    assert not open_bag(bag).complete


def test_an_untrusted_channel_of_a_package_outside_the_interface_is_refused_by_the_writer(tmp_path):
    """The child imports a class to check untrusted bytes by its type name, from the interface's message packages
    only (`schema.message_class`): a channel of another package stops the recording with a line naming it."""
    from rcl_interfaces.msg import Log

    path = tmp_path / "p.mcap"
    rec = McapProcessRecorder(path)
    rec.add_channel("/rosout_in", Log, TOPICS["screw_torque"].qos, untrusted=True)
    rec.write("/rosout_in", Log(), 0)
    _wait_until(lambda: rec.error is not None, 20, "the writer's refusal")
    assert "'rcl_interfaces/msg/Log' is not a message class of builtin_interfaces, diagnostic_msgs" in rec.error
    assert "/rosout_in" in rec.error
    assert not rec.close()
    assert rec.messages_written + rec.messages_dropped + rec.messages_malformed == 1
