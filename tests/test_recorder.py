"""MCAP recorder: ROS 2 profile as rosbag2 writes it, read back by independent readers, and faults.

Oracles: the values published (a real simulation mapped by `messages.MessageMapper`) must come
back bit for bit through two readers that share no code with ours — mcap_ros2's CDR decoder
(driven by the schema text in the file) and the `rosbags` library (its own ROS 2 type store,
and separately the schema text in the file); `rerun mcap check` must find no issue.
Faults run in real processes: SIGKILL mid-recording, a full disk (a tiny tmpfs in a user
namespace, and /dev/full), an unwritable path.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from prsm_sim import InputError, Simulator, preset
from prsm_ros.mcap import schema as mcap_schema
from prsm_ros.bag.reader import open_bag, scan_records
from prsm_ros.messages import TOPICS, MessageMapper, STEP_TOPICS, time_ns
from prsm_ros.mcap.offline import write_trajectory_mcap
from prsm_ros.mcap.recorder import McapRecorder, run_metadata
from prsm_ros.mcap.recorder_process import McapProcessRecorder

# The caller's contract holds for both: the writer in a thread (offline tools) and in a child process (the node)
RECORDERS = pytest.mark.parametrize("Recorder", [McapRecorder, McapProcessRecorder])

RERUN = shutil.which("rerun") or str(Path(sys.executable).parent / "rerun")
CHILD_ENV = {**os.environ, "RERUN": "off", "PYTHONUNBUFFERED": "1"}


def _run_child(code: str, *args: str, timeout: float = 60.0, prefix: list[str] | None = None):
    return subprocess.run([*(prefix or []), sys.executable, "-c", textwrap.dedent(code), *args],
                          capture_output=True, text=True, timeout=timeout, env=CHILD_ENV)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A recording of 200 jones2016 steps through McapRecorder, with what was published."""
    from std_msgs.msg import Float64

    p = preset("jones2016")
    sim = Simulator(p, "jones2016", 1e-3)
    mapper = MessageMapper(sim.layout, "jones2016")
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    rec = McapRecorder(path, metadata=run_metadata(p, preset="jones2016", model="jones2016", dt_s=1e-3,
                                                   node_parameters={"update_rate": 1000.0}))
    for key in ("labels", "screw_torque", *STEP_TOPICS):
        rec.add_channel(TOPICS[key].resolved(), TOPICS[key].msg_class, TOPICS[key].qos)
    published: list[tuple[str, int, object]] = []
    rec.write(TOPICS["labels"].resolved(), mapper.labels(), 0)
    published.append((TOPICS["labels"].resolved(), 0, mapper.labels()))
    for k in range(200):
        torque = 0.05 + 0.001 * k
        cmd = Float64(data=torque)
        rec.write(TOPICS["screw_torque"].resolved(), cmd, time_ns(sim.time_s))
        published.append((TOPICS["screw_torque"].resolved(), time_ns(sim.time_s), cmd))
        out = sim.step(torque, 100.0)
        for topic, msg in mapper.messages(out):
            rec.write(topic, msg, time_ns(out.time_s))
            published.append((topic, time_ns(out.time_s), msg))
    rec.close()
    assert rec.error is None and rec.messages_dropped == 0
    assert rec.messages_written == len(published)
    return path, published


def _fields_equal(ours, theirs) -> None:
    """Every field of a published rclpy message equals the independently decoded one, bit for bit."""
    for name in ours.get_fields_and_field_types():
        a, b = getattr(ours, name), getattr(theirs, name)
        if hasattr(a, "get_fields_and_field_types"):
            _fields_equal(a, b)
        elif isinstance(a, (list, tuple)) and a and hasattr(a[0], "get_fields_and_field_types"):
            assert len(a) == len(b)
            for x, y in zip(a, b):
                _fields_equal(x, y)
        elif isinstance(a, str) or (isinstance(a, (list, tuple)) and a and isinstance(a[0], str)):
            assert list(a) == list(b) if not isinstance(a, str) else a == b, name
        else:  # bit for bit: a NaN (an undefined efficiency) must come back as the same NaN
            x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
            assert x.shape == y.shape and x.tobytes() == y.tobytes(), name


def test_file_follows_the_ros2_profile(recorded):
    from mcap.reader import make_reader

    path, _ = recorded
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert summary.chunk_indexes and all(ci.compression == "zstd" for ci in summary.chunk_indexes)
    assert all(ci.message_index_offsets for ci in summary.chunk_indexes)
    for ch in summary.channels.values():
        schema = summary.schemas[ch.schema_id]
        assert ch.message_encoding == "cdr" and schema.encoding == "ros2msg"
        pkg, mid, typ = schema.name.split("/")
        assert mid == "msg"
        text = schema.data.decode()
        # the type's own .msg first, then each dependency after 80 '=' and "MSG: pkg/Type"
        assert text.startswith(mcap_schema.msg_text(pkg, typ))
        for dep in mcap_schema.dependencies(mcap_schema.msg_text(pkg, typ), pkg):
            assert f"\n{'=' * 80}\nMSG: {dep}\n" in text
        assert ch.metadata["topic_type_hash"].startswith("RIHS01_")
    qos = {ch.topic: ch.metadata["offered_qos_profiles"] for ch in summary.channels.values()}
    assert "reliability: 1" in qos["/joint_states"] and "durability: 2" in qos["/joint_states"]
    assert "durability: 1" in qos["/prsm_actuator/internal_loads/labels"]  # transient local (latched)
    assert "deadline:\n    sec: 9223372036\n    nsec: 854775807" in qos["/joint_states"]
    run = meta["prsm_run"]
    assert set(run) >= {"package_version", "preset", "model", "dt_s", "parameters_yaml", "node_parameters_yaml"}
    import yaml
    assert preset("jones2016").to_dict() == yaml.safe_load(run["parameters_yaml"])
    assert yaml.safe_load(run["node_parameters_yaml"]) == {"update_rate": 1000.0}
    assert set(meta["rosbag2"]) == {"ROS_DISTRO"}  # the pre-Jazzy record: QoS read as integers


def test_mcap_ros2_decoder_gives_back_exactly_what_was_published(recorded):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    path, published = recorded
    with open(path, "rb") as f:
        got = [(c.topic, m.log_time, m.publish_time, d)
               for _, c, m, d in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                   log_time_order=False)]
    assert len(got) == len(published)
    for (topic, stamp, msg), (t2, log, pub, dec) in zip(published, got):
        assert (topic, stamp, stamp) == (t2, log, pub)
        _fields_equal(msg, dec)


def test_rosbags_reads_the_file_with_its_own_types_and_with_the_file_schemas(recorded):
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    path, published = recorded
    store = get_typestore(Stores.ROS2_KILTED)  # rosbags' own definitions, independent of our schema text
    with Reader(path) as reader:
        rows = [(c.topic, ts, store.deserialize_cdr(raw, c.msgtype)) for c, ts, raw in reader.messages()]
        qos = {c.topic: c.ext.offered_qos_profiles[0] for c in reader.connections}
    assert [(t, s) for t, s, _ in published] == [(t, s) for t, s, _ in rows]
    for (_, _, msg), (_, _, theirs) in zip(published, rows):
        _fields_equal(msg, theirs)
    assert qos["/prsm_actuator/internal_loads/labels"].durability.name == "TRANSIENT_LOCAL"
    assert qos["/joint_states"].reliability.name == "RELIABLE" and qos["/joint_states"].depth == 100
    with AnyReader([path]) as reader:  # types parsed from the concatenated definitions in the file
        first = {}
        for c, _ts, raw in reader.messages():
            first.setdefault(c.topic, reader.deserialize(raw, c.msgtype))
    js = first["/joint_states"]
    assert list(js.name) == ["screw_joint", "nut_joint"]
    assert js.position[1] == published[2][2].position[1]


def test_rerun_mcap_check_finds_no_issue_in_node_and_offline_files(recorded, tmp_path):
    path, _ = recorded
    p = preset("jones2016")
    traj = Simulator(p, "jones2016", 1e-3).run(np.full(300, 0.092), 100.0)
    offline = write_trajectory_mcap(tmp_path / "offline.mcap", traj, p, "jones2016", preset_name="jones2016",
                                    progress=False, reference_m=np.zeros(300))
    for f in (path, offline):
        res = subprocess.run([RERUN, "mcap", "check", str(f)], capture_output=True, text=True, timeout=60)
        assert res.returncode == 0, res.stderr
        rows = [line.split() for line in res.stdout.splitlines() if line.split() and line.split()[0] in ("ok", "warn", "error")]
        assert rows and all(r[0] == "ok" and r[-1] == "—" for r in rows), res.stdout
        assert len(rows) == len(open_bag(f).topics)


def test_offline_bag_carries_the_trajectory_values(tmp_path):
    p = preset("jones2016")
    traj = Simulator(p, "jones2016", 1e-3).run(0.08 + 0.01 * np.sin(np.arange(150) * 0.1), 100.0)
    path = write_trajectory_mcap(tmp_path / "o.mcap", traj, p, "jones2016", preset_name="jones2016", progress=False)
    bag = open_bag(path)
    assert {t: i.count for t, i in bag.topics.items()} == {
        "/prsm_actuator/internal_loads/labels": 1, "/prsm_actuator/screw_torque": 150, "/joint_states": 150,
        "/prsm_actuator/nut/wrench": 150, "/prsm_actuator/internal_loads": 150, "/clock": 150}
    js = list(bag.messages(["/joint_states"]))
    assert [m.log_time_ns for m in js] == [time_ns(t) for t in traj["time_s"]]
    assert np.array_equal([m.msg.position[1] for m in js], traj["nut_position_m"])
    cmd = list(bag.messages(["/prsm_actuator/screw_torque"]))
    assert np.array_equal([m.msg.data for m in cmd], traj["screw_torque_nm"])
    assert cmd[0].log_time_ns == 0  # taken at the start of the step it drives


@RECORDERS
def test_recorder_refuses_caller_mistakes_at_once(tmp_path, Recorder):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    with Recorder(tmp_path / "m.mcap") as rec:
        rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
        with pytest.raises(KeyError, match="not added"):
            rec.write("/b", Float64(), 0)
        with pytest.raises(InputError, match="std_msgs/msg/Float64"):
            rec.write("/a", JointState(), 0)
        with pytest.raises(KeyError, match="not added"):  # a batch is checked as single writes are
            rec.write_many([("/a", Float64(), 0), ("/b", Float64(), 0)])
        with pytest.raises(InputError, match="std_msgs/msg/Float64"):
            rec.write_many([("/a", JointState(), 0)])
        with pytest.raises(ValueError, match="cannot add it again"):
            rec.add_channel("/a", JointState, TOPICS["joint_states"].qos)
    with pytest.raises(ValueError, match="queue_size"):
        Recorder(tmp_path / "q.mcap", queue_size=0)


@RECORDERS
def test_full_queue_drops_and_counts_instead_of_blocking(tmp_path, Recorder):
    from std_msgs.msg import Float64

    rec = Recorder(tmp_path / "q.mcap", queue_size=10)
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    for k in range(1000):
        rec.write("/a", Float64(data=float(k)), k)
    for k in range(1000, 2000, 8):  # batches (the node's per-step hand-over) count the same way
        rec.write_many([("/a", Float64(data=float(j)), j) for j in range(k, min(k + 8, 2000))])
    rec.close()
    assert rec.messages_dropped > 0
    assert rec.messages_written + rec.messages_dropped == 2000
    assert open_bag(tmp_path / "q.mcap").topics["/a"].count == rec.messages_written


@RECORDERS
def test_untrusted_channels_record_only_bytes_that_deserialize(tmp_path, Recorder):
    """A 4-byte ~/screw_torque used to be recorded as received and then broke export and to-rrd.
    Oracle: rclpy's own serializer for the good bytes; the reader's malformed count (0)."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    good = [serialize_message(Float64(data=float(k))) for k in range(5)]
    bad = [b"\x00\x01\x00\x00", b"", b"\x00\x01\x00\x00\x01"]
    with Recorder(tmp_path / "u.mcap") as rec:
        rec.add_channel("/cmd", Float64, TOPICS["screw_torque"].qos, untrusted=True)
        rec.add_channel("/out", Float64, TOPICS["screw_torque"].qos)
        for k, data in enumerate([good[0], bad[0], good[1], bad[1], good[2], bad[2], good[3], good[4]]):
            rec.write("/cmd", data, k)
        rec.write("/out", Float64(data=7.0), 9)
    assert (rec.messages_written, rec.messages_malformed, rec.messages_dropped) == (6, 3, 0)
    bag = open_bag(tmp_path / "u.mcap")
    bag.check()
    assert bag.topics["/cmd"].count == 5 and bag.topics["/cmd"].malformed == 0
    assert [m.data for m in bag.messages(["/cmd"])] == good


def _many_chunks(path, channels: int, chunks: int, pack: bool):
    """A file of `chunks` chunks over `channels` Float64 channels, written by mcap's Writer (ours packed or not)."""
    import tracemalloc

    from mcap.writer import CompressionType, IndexType, Writer

    from prsm_ros.mcap.recorder import pack_chunk_indexes
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=1 << 20, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
        packed = pack_chunk_indexes(w) if pack else None
        assert (packed is not None) == pack
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        ids = [w.register_channel(f"/t{k}", "cdr", sid, {}) for k in range(channels)]
        tracemalloc.start()
        before = tracemalloc.get_traced_memory()[0]
        for c in range(chunks):
            for cid in ids:
                w.add_message(cid, c * 1000 + cid, b"\x00\x01\x00\x00" + bytes(8), c * 1000 + cid)
            w.flush()
        retained = tracemalloc.get_traced_memory()[0] - before
        tracemalloc.stop()
        w.finish()
    return retained / chunks


@pytest.mark.slow
def test_chunk_indexes_are_kept_packed_and_the_file_is_unchanged(tmp_path):
    """Recorder memory per chunk (what grows with realtime recording): the mcap Writer's own
    ChunkIndex objects are the oracle for the bytes, its unpacked memory for the saving."""
    channels, chunks = 15, 2000  # the node's channel count; many chunks, as an hour at 20 chunks/s has 72,000
    plain = _many_chunks(tmp_path / "plain.mcap", channels, chunks, pack=False)
    packed = _many_chunks(tmp_path / "packed.mcap", channels, chunks, pack=True)
    assert (tmp_path / "plain.mcap").read_bytes() == (tmp_path / "packed.mcap").read_bytes()
    record = 9 + 8 * 4 + 4 + 10 * channels + 8 + 4 + len("zstd") + 8 * 2  # a ChunkIndex record (MCAP spec)
    assert packed < 1.5 * record < plain / 3, (packed, record, plain)


@RECORDERS
def test_unwritable_path_sets_error_and_the_caller_keeps_running(tmp_path, Recorder):
    from std_msgs.msg import Float64

    for bad in (tmp_path / "missing_dir" / "x.mcap", tmp_path):  # no such directory; a directory
        rec = Recorder(bad)
        assert rec.error is not None and str(bad) in rec.error
        rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
        for k in range(5):
            rec.write("/a", Float64(data=1.0), k)  # no exception: recording has stopped, the node runs on
        rec.close()
        rec.close()
        assert rec.messages_dropped == 5 and rec.messages_written == 0


@RECORDERS
def test_dev_full_reports_no_space_and_the_caller_keeps_running(Recorder):
    from std_msgs.msg import Float64

    rec = Recorder("/dev/full")  # every write returns ENOSPC, as on a full disk
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    for k in range(3):
        rec.write("/a", Float64(data=1.0), k)
    rec.close()
    assert rec.error is not None and "No space left on device" in rec.error
    assert rec.messages_dropped == 3


class _StallingFile:
    """A real file whose writes block while `stalled` is set: a disk (or NFS mount) that stopped
    answering, as the writer thread sees it (blocked inside write(2), holding no Python lock)."""

    def __init__(self, path, mode):
        import threading
        self._f = open(path, mode)
        self.stalled = threading.Event()
        self.resumed = threading.Event()
        self.blocked = threading.Event()

    def write(self, data):
        if self.stalled.is_set():
            self.blocked.set()
            self.resumed.wait()
        return self._f.write(data)

    def __getattr__(self, name):
        return getattr(self._f, name)


@pytest.fixture
def stalling_files(monkeypatch) -> list[_StallingFile]:
    """The recorder's files, opened as `_StallingFile`s (in the order the recorders open them)."""
    import prsm_ros.mcap.recorder as recorder_module
    files: list[_StallingFile] = []
    monkeypatch.setattr(recorder_module, "open", lambda p, m: files.append(_StallingFile(p, m)) or files[-1],
                        raising=False)
    return files


def test_stalled_disk_cannot_hang_close_and_what_was_lost_is_counted(tmp_path, stalling_files):
    """The disk stalls under the writer thread. close() must give up within its timeout, say so,
    and account for every message offered: written (handed to the MCAP writer) + dropped = offered,
    also for a write after close. When the disk comes back the thread finishes the file on its own,
    and the file (read by the mcap library) holds exactly the messages counted as written."""
    from mcap.reader import make_reader
    from std_msgs.msg import Float64

    path = tmp_path / "stalled.mcap"
    rec = McapRecorder(path, flush_interval_s=0.01)
    disk = stalling_files[0]
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    disk.stalled.set()
    offered = 6_000
    for k in range(1000):
        rec.write("/a", Float64(data=float(k)), k)
    assert disk.blocked.wait(timeout=30), "the writer thread never reached the disk"
    for k in range(1000, offered):  # these queue up behind the stalled write
        rec.write("/a", Float64(data=float(k)), k)
    t0 = time.monotonic()
    assert rec.close(timeout_s=1.0) is False
    waited = time.monotonic() - t0
    assert waited < 1.0 + 10.0, waited  # returned at its timeout (the ceiling only absorbs a busy machine)
    assert "did not finish within 1 s" in rec.error and "no summary" in rec.error
    assert rec.messages_dropped >= offered - 1000  # still queued behind the stalled chunk
    assert rec.messages_written + rec.messages_dropped == offered
    rec.write("/a", Float64(data=0.0), offered)  # after close: counted, never queued
    assert rec.messages_written + rec.messages_dropped == offered + 1

    disk.resumed.set()  # the disk recovers: the thread writes what it holds, the summary and the footer
    rec._thread.join(timeout=30)
    assert not rec._thread.is_alive()
    with open(path, "rb") as f:
        stats = make_reader(f).get_summary().statistics
    assert sum(stats.channel_message_counts.values()) == rec.messages_written
    assert rec.messages_written + rec.messages_dropped == offered + 1


@pytest.mark.slow
@pytest.mark.parametrize("halfway", ["close", "disk_full"])
def test_drop_counts_are_exact_under_concurrent_writers(tmp_path, stalling_files, halfway):
    """Four threads write while, halfway, the main thread closes the recorder or the disk fills up
    under the writer thread (thousands of messages queued). Every message offered is in exactly
    one count (written or dropped); after a clean close the file (read back by our reader) holds
    exactly the written ones. The GIL switch interval is cut to 1 µs so the threads interleave
    inside write() and the writer's drain as often as they can."""
    import errno
    import sys as _sys
    import threading

    from std_msgs.msg import Float64

    path = tmp_path / "concurrent.mcap"
    rec = McapRecorder(path, flush_interval_s=0.01)
    disk = stalling_files[0]
    rec.add_channel("/a", Float64, TOPICS["screw_torque"].qos)
    per_thread, n_threads = 25_000, 4
    middle = threading.Barrier(n_threads + 1)

    def produce(j: int) -> None:
        for k in range(per_thread):
            if k == per_thread // 2:
                middle.wait(timeout=60)
            rec.write("/a", Float64(data=float(k)), j * per_thread + k)

    def full(data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    old = _sys.getswitchinterval()
    _sys.setswitchinterval(1e-6)
    try:
        threads = [threading.Thread(target=produce, args=(j,)) for j in range(n_threads)]
        for t in threads:
            t.start()
        middle.wait(timeout=60)
        if halfway == "close":
            assert rec.close(timeout_s=30.0), rec.error
        else:
            disk.write = full
        for t in threads:
            t.join(timeout=60)
        assert not any(t.is_alive() for t in threads)
        rec.close(timeout_s=30.0)
    finally:
        _sys.setswitchinterval(old)
    offered = n_threads * per_thread
    assert rec.messages_written + rec.messages_dropped == offered
    assert rec.messages_written > 0 and rec.messages_dropped > 0
    if halfway == "close":
        assert open_bag(path).topics["/a"].count == rec.messages_written
    else:
        assert "No space left on device" in rec.error


_WRITER = """
    import json, sys, time
    from std_msgs.msg import Float64
    from sensor_msgs.msg import JointState
    from rclpy.qos import QoSProfile
    from prsm_ros.mcap.recorder import McapRecorder
    path, steps = sys.argv[1], int(sys.argv[2])
    rec = McapRecorder(path, flush_interval_s=0.05, chunk_size=1 << 20)
    rec.add_channel("/value", Float64, QoSProfile(depth=10))
    rec.add_channel("/joint_states", JointState, QoSProfile(depth=10))
    for k in range(steps):
        rec.write("/value", Float64(data=float(k)), k * 1_000_000)
        rec.write("/joint_states", JointState(name=["screw_joint"], position=[k * 0.5]), k * 1_000_000)
        if k % 200 == 0:
            time.sleep(0.01)
            print(json.dumps({"k": k, "written": rec.messages_written, "error": rec.error}), flush=True)
    rec.close()
    print(json.dumps({"done": steps, "written": rec.messages_written, "dropped": rec.messages_dropped,
                      "error": rec.error}), flush=True)
"""


def _assert_exact_prefix(values: list[float], scale: float = 1.0) -> int:
    """The recovered values are 0, 1, 2, … × scale with no gap: nothing flushed was lost."""
    assert values, "nothing recovered"
    assert values == [k * scale for k in range(len(values))]
    return len(values)


@pytest.mark.slow
def test_sigkill_leaves_a_file_readable_up_to_its_last_complete_chunk(tmp_path):
    from mcap.exceptions import McapError
    from mcap.reader import NonSeekingReader
    from zstandard import ZstdError

    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen([sys.executable, "-c", textwrap.dedent(_WRITER), str(path), "100000000"],
                            stdout=subprocess.PIPE, text=True, env=CHILD_ENV)
    try:
        # Kill mid-run once the file holds >= 2 complete chunks with >= 5000 values: an event read
        # from the file itself (our recovery scan), not a size or a time that a busy machine stretches.
        deadline, size, ready = time.monotonic() + 120, 0, False
        while not ready:
            line = proc.stdout.readline()
            assert line and time.monotonic() < deadline, "the writer never put 2 chunks on disk"
            if json.loads(line)["written"] > 10_000 and path.stat().st_size > size:
                size = path.stat().st_size
                seen: list[int] = []
                scan = scan_records(path, lambda s, ch, m: ch.topic == "/value" and seen.append(1))
                ready = scan.chunks >= 2 and len(seen) >= 5_000
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=10)
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL

    # 1) the mcap library's streaming reader reads every message up to the truncation
    streamed: list[float] = []
    with open(path, "rb") as f:
        try:
            for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                if channel.topic == "/value":
                    streamed.append(message.log_time / 1e6)
        except (McapError, ZstdError):  # the cut-off tail: a partial record or chunk
            pass
    n_streamed = _assert_exact_prefix(streamed)

    # 2) our recovery routine: complete chunks only, decoded values exact
    scan = scan_records(path)
    assert not scan.complete and scan.chunks >= 2
    bag = open_bag(path)
    assert not bag.complete and "unfinished" in bag.note
    values = [m.msg.data for m in bag.messages(["/value"])]
    n = _assert_exact_prefix(values)
    assert n >= 5_000 and n <= n_streamed + 1  # thousands of steps recovered, never more than the stream holds
    assert [m.msg.position[0] for m in bag.messages(["/joint_states"])] == [k * 0.5 for k in range(n)]

    # 3) prsm-bag handles it with a note, not a traceback
    res = subprocess.run([sys.executable, "-m", "prsm_ros.cli.bag", "info", str(path)], capture_output=True,
                         text=True, timeout=60, env=CHILD_ENV)
    assert res.returncode == 0 and "UNFINISHED" in res.stdout and "Traceback" not in res.stderr
    assert f"{n} message" in res.stdout or str(bag.topics["/value"].count) in res.stdout


def _unshare_tmpfs_available() -> bool:
    if not shutil.which("unshare"):
        return False
    res = subprocess.run(["unshare", "-rm", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /mnt && echo ok"],
                         capture_output=True, text=True)
    return res.stdout.strip() == "ok"


@pytest.mark.slow
@pytest.mark.skipif(not _unshare_tmpfs_available(), reason="no user namespaces to mount a tiny tmpfs")
def test_disk_filling_up_mid_run_stops_recording_and_keeps_what_was_flushed(tmp_path):
    """A 512 KiB tmpfs (unprivileged, in a user+mount namespace) fills up during the run."""
    mnt, keep = tmp_path / "mnt", tmp_path / "kept.mcap"
    mnt.mkdir()
    script = textwrap.dedent(_WRITER)
    cmd = (f"mount -t tmpfs -o size=512k tmpfs {mnt} && {sys.executable} -c \"$0\" {mnt}/rec.mcap 60000; "
           f"rc=$?; cp {mnt}/rec.mcap {keep}; exit $rc")
    res = subprocess.run(["unshare", "-rm", "sh", "-c", cmd, script], capture_output=True, text=True,
                         timeout=120, env=CHILD_ENV)
    assert res.returncode == 0, res.stderr
    final = json.loads(res.stdout.strip().splitlines()[-1])
    assert final["done"] == 60000  # the caller ran to the end
    assert "No space left on device" in final["error"]
    assert final["dropped"] > 0
    bag = open_bag(keep)
    assert not bag.complete
    n = _assert_exact_prefix([m.msg.data for m in bag.messages(["/value"])])
    assert 1000 < n < 60000


def _fast_or_plain(path, how: str, chunk_size: int) -> None:
    """Messages of varied sizes, times out of order and channels, through mcap's Writer.add_message
    (the oracle), `FastMessages.add` one by one or `FastMessages.add_many` in batches of 1 to 12
    (a batch may close a chunk in its middle); flushed now and then, chunks also closed by size."""
    from mcap.writer import CompressionType, IndexType, Writer

    from prsm_ros.mcap.fast_messages import FastMessages
    rng, batch_sizes = np.random.default_rng(7), np.random.default_rng(8)  # the same messages every way
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=chunk_size, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
        fm = FastMessages.attach(w, chunk_size)
        assert fm is not None
        add = {"plain": w.add_message, "fast": fm.add}.get(how)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        ids = [w.register_channel(f"/t{k}", "cdr", sid, {}) for k in range(5)]
        batch: list = []
        for k in range(3000):
            cid = ids[int(rng.integers(len(ids)))]
            t = 1_000_000 * k + int(rng.integers(-3_000_000, 3_000_000))  # some arrive behind the newest
            message = (cid, t, rng.bytes(int(rng.integers(0, 400))), t + 1, k)
            if add is not None:
                add(*message)
            else:
                batch.append(message)
                if len(batch) >= int(batch_sizes.integers(1, 13)):
                    fm.add_many(batch)
                    batch = []
            if k % 700 == 699:
                fm.add_many(batch)
                batch = []
                w.flush()
        fm.add_many(batch)
        w.finish()


@pytest.mark.parametrize("chunk_size", [1 << 20, 4096])
def test_fast_message_path_writes_the_same_bytes(tmp_path, chunk_size):
    """The recorder's per-message path (`FastMessages`) against mcap's own `Writer.add_message`:
    the same file, byte for byte, whether chunks close by flush or by size, one message or a batch at a time."""
    for how in ("plain", "fast", "batched"):
        _fast_or_plain(tmp_path / f"{how}.mcap", how, chunk_size)
    plain = (tmp_path / "plain.mcap").read_bytes()
    assert (tmp_path / "fast.mcap").read_bytes() == plain
    assert (tmp_path / "batched.mcap").read_bytes() == plain


@RECORDERS
def test_a_deferred_message_is_built_by_the_writer_side_as_the_bytes_it_stands_for(tmp_path, Recorder):
    """A `Deferred` (the node's internal loads when only the bag takes them) is written as `encode(arg)`, built
    by the recorder's emptying thread, never the caller's, and the file is byte for byte the one the same
    bytes handed over at once give. Oracle: the encoder's own bytes, and the file written from them."""
    import threading

    from mcap.reader import make_reader
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    from prsm_ros.mcap.recorder import Deferred
    caller = threading.get_ident()
    built_on = set()

    def encode(value: float) -> bytes:
        built_on.add(threading.get_ident())
        return serialize_message(Float64(data=value))

    for how in ("bytes", "deferred"):
        with Recorder(tmp_path / f"{how}.mcap", deterministic=True) as rec:
            rec.add_channel("/loads", Float64, TOPICS["screw_torque"].qos)
            rec.add_channel("/state", Float64, TOPICS["screw_torque"].qos)
            for k in range(300):
                v = 0.5 * k
                loads = serialize_message(Float64(data=v)) if how == "bytes" else Deferred(encode, v)
                rec.write_many([("/state", serialize_message(Float64(data=-v)), k), ("/loads", loads, k)])
        assert rec.error is None and rec.messages_written == 600 and rec.messages_dropped == 0
    assert built_on and caller not in built_on
    assert (tmp_path / "deferred.mcap").read_bytes() == (tmp_path / "bytes.mcap").read_bytes()
    with open(tmp_path / "deferred.mcap", "rb") as f:
        loads = [m.data for _, c, m in make_reader(f).iter_messages() if c.topic == "/loads"]
    assert loads == [serialize_message(Float64(data=0.5 * k)) for k in range(300)]


def test_steps_queued_around_a_new_channel_are_written_in_order(tmp_path):
    """The writer takes several queued steps as one batch, but never across a channel declared between
    them: every message comes back, in order, on its channel, whatever the writer thread's timing.
    Oracle: what was written, read back by mcap's own reader."""
    from mcap.reader import make_reader
    from std_msgs.msg import Float64

    rec = McapRecorder(tmp_path / "order.mcap")
    a, b = "/a", "/b"
    rec.add_channel(a, Float64, TOPICS["screw_torque"].qos)
    sent = []
    for k in range(40):  # queued faster than the writer wakes (every 10 ms): batches of several steps
        rec.write_many([(a, Float64(data=float(k)), k)])
        sent.append((a, k))
    rec.add_channel(b, Float64, TOPICS["screw_torque"].qos)
    for k in range(40, 80):
        rec.write_many([(a, Float64(data=float(k)), k), (b, Float64(data=-float(k)), k)])
        sent += [(a, k), (b, k)]
    assert rec.close() and rec.messages_written == len(sent) and rec.messages_dropped == 0
    with open(tmp_path / "order.mcap", "rb") as f:
        got = [(c.topic, m.log_time) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    assert got == sent


@pytest.mark.parametrize("steps_per_write", [1, 16])
def test_a_deterministic_file_writes_late_messages_where_their_stamps_put_them(tmp_path, steps_per_write):
    """A lockstep bag holds each message until the log times have moved `REORDER_WINDOW_NS` past it, then writes
    in (log time, channel, sequence) order, whatever order the batches came in. Oracle: Python's sort of what was
    sent by that key, against the file's records in file order as mcap's own reader gives them; a message later
    than the window is still written (never lost), after those already out. Batches of one step, and of 16 (the
    writer process's hand-over: a batch whose references reach back into the messages already held)."""
    from mcap.reader import make_reader
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64

    from prsm_ros.mcap.recorder import REORDER_WINDOW_NS, McapFile
    rng = np.random.default_rng(11)
    path = tmp_path / "late.mcap"
    f = McapFile(path, deterministic=True, chunk_size=16 << 10)  # several chunks closed by size
    topics = ["/state", "/ref", "/cmd"]
    ids = {t: f.add_channel(t, Float64, TOPICS["screw_torque"].qos) for t in topics}
    sent = []  # (log time, channel id, sequence, value)
    seq = dict.fromkeys(ids.values(), 0)
    step_ns = 1_000_000
    items = []
    for k in range(10, 1500):
        batch = [("/state", k * step_ns), ("/cmd", k * step_ns)]
        if k % 3:  # a reference answers the state of one to five steps before
            batch.insert(int(rng.integers(0, 3)), ("/ref", (k - int(rng.integers(1, 6))) * step_ns))
        for topic, t in batch:
            cid = ids[topic]
            seq[cid] += 1
            value = float(len(sent))
            sent.append((t, cid, seq[cid], value))
            items.append((cid, serialize_message(Float64(data=value)), t))
        if k % steps_per_write == 0 or k == 1499:
            f.write_many(items)
            items = []
    too_late = (1499 * step_ns - REORDER_WINDOW_NS - 5 * step_ns, ids["/ref"])
    seq[too_late[1]] += 1
    sent_late = (*too_late, seq[too_late[1]], -1.0)
    f.write_many([(too_late[1], serialize_message(Float64(data=-1.0)), too_late[0])])
    f.finish()
    with open(path, "rb") as fh:
        got = [(m.log_time, m.channel_id, m.sequence, deserialize_message(m.data, Float64).data)
               for _, _, m in make_reader(fh).iter_messages(log_time_order=False)]
    assert len(got) == len(sent) + 1
    # written before the late one: every message whose hold ended by then, in key order
    released = sorted(m for m in sent if m[0] <= 1499 * step_ns - REORDER_WINDOW_NS)
    assert got[:len(released)] == released
    assert got[len(released)] == sent_late  # written as soon as it came: its hold had already ended
    assert got[len(released) + 1:] == sorted(m for m in sent if m[0] > 1499 * step_ns - REORDER_WINDOW_NS)
