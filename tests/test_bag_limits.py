"""`prsm-bag` on inputs that once cost a traceback, a hang, unbounded memory or lost messages.

Every input is generated here (`hostile_bags`), small. Oracles: the messages written, the mcap
library's stream reader (what a scan of the data section reads), and the figures each limit states.
"""

import csv
import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

import hostile_bags as hb
from prsm_ros.cli import bag_fuzz as fuzz
from prsm_ros.bag.reader import MAX_CHUNK_BYTES, ChunkSkipped, chunk_data, open_bag
from prsm_ros.cli.bag import EXIT_ERROR, main
from ros_domains import domain_id

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "ROS_DOMAIN_ID": str(domain_id("test_bag_limits")),
       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "PYTHONPATH": f"{ROOT}{os.pathsep}{ROOT / 'tests'}"}


def _cli(capsys, *args):
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def _one_error(rc, err, command):
    lines = [ln for ln in err.splitlines() if ln.startswith(f"prsm-bag {command}: error:")]
    assert rc == EXIT_ERROR and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


class _Chunk:
    def __init__(self, data: bytes, compression: str, size: int, crc: int = 0):
        self.data, self.compression, self.uncompressed_size, self.uncompressed_crc = data, compression, size, crc


# ---- decompression ---------------------------------------------------------------------------

def test_lz4_and_zstd_output_is_bounded_whatever_the_chunk_declares():
    """Was: lz4 decompressed without a bound (the 256 MiB cap checked only the declared size): a 6.6 MB
    bag took info to 3.2 GB. The cap now bounds what the codec produces."""
    import lz4.frame
    import zstandard
    zeros = bytes(4 << 20)
    cap = 1 << 20
    for comp, data in (("lz4", lz4.frame.compress(zeros)),
                       ("zstd", zstandard.ZstdCompressor().compress(zeros)),
                       ("zstd", zstandard.ZstdCompressor(write_content_size=False).compress(zeros))):
        with pytest.raises(ChunkSkipped, match="more than the 1 MiB"):
            chunk_data(_Chunk(data, comp, size=100), cap=cap)
    assert chunk_data(_Chunk(lz4.frame.compress(zeros[:cap]), "lz4", cap, zlib.crc32(zeros[:cap])), cap=cap) == zeros[:cap]
    assert MAX_CHUNK_BYTES == 64 << 20


def test_a_damaged_lz4_chunk_is_skipped_not_a_traceback(tmp_path, capsys):
    """Was: one flipped byte in an lz4 chunk raised `RuntimeError: LZ4F_decompress failed` out of every
    verb, repair included. Now the chunk is skipped and the rest kept."""
    from mcap.opcode import Opcode
    from mcap.writer import CompressionType
    bag = hb.joint_states_bag(tmp_path / "lz4.mcap", 40, compression=CompressionType.LZ4)
    data = bytearray(bag.read_bytes())
    chunk = next(p for p, op, _ in hb.records(bytes(data)) if op == Opcode.CHUNK)
    for k in range(60, 90):  # inside the compressed data, past the chunk's header fields
        data[chunk + k] ^= 0xFF
    bag.write_bytes(bytes(data))
    rc, out, err = _cli(capsys, "info", bag, "--json", "--check")
    assert rc == 0 and "Traceback" not in err
    assert "damaged chunk" in json.loads(out)["note"]
    rc, out, err = _cli(capsys, "repair", bag, tmp_path / "fixed.mcap")
    assert rc == 0, err


# ---- damaged summaries: scan the data section ----------------------------------------------------

def _chunk_index_offsets(data: bytes):
    from mcap.opcode import Opcode
    return [p for p, op, _ in hb.records(data) if op == Opcode.CHUNK_INDEX]


@pytest.mark.parametrize("keep_crc", [True, False])
def test_a_damaged_chunk_index_falls_back_to_scanning_and_repair_keeps_every_message(tmp_path, capsys, keep_crc):
    """Was: a chunk index pointing elsewhere made every reader skip that chunk (the worst fuzzed file kept
    1,781 of the 2,501 messages mcap's stream reader reads). With the summary's CRC the damage is seen
    at once; without one, the walk of the data section finds the chunk no index points at."""
    bag = ROOT / "bags" / "heavy_load.mcap"
    data = bytearray(bag.read_bytes())
    ci = _chunk_index_offsets(bytes(data))[1]
    struct.pack_into("<Q", data, ci + 9 + 16, 12)  # chunk_start_offset (after start and end time)
    if not keep_crc:
        struct.pack_into("<I", data, len(data) - 8 - 4, 0)  # the footer's summary CRC: "not computed"
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    floor = fuzz.stream_count(damaged)
    assert floor == 2501
    rc, out, err = _cli(capsys, "repair", damaged, tmp_path / "fixed.mcap")
    assert rc == 0, err
    assert fuzz.repaired_count(tmp_path / "fixed.mcap") == floor
    assert "summary could not be used" in err
    assert open_bag(damaged).message_count == floor


# ---- parsing depth -------------------------------------------------------------------------------

def test_a_recursive_custom_schema_is_undecodable_not_a_recursion_error(tmp_path, capsys):
    """Was: RecursionError from every verb that decoded /tree (its type contains a sequence of itself)."""
    bag = hb.recursive_schema(tmp_path / "tree.mcap")
    rc, out, err = _cli(capsys, "info", bag, "--json", "--check")
    assert rc == 0, err
    tree = next(t for t in json.loads(out)["topics"] if t["topic"] == "/tree")
    assert "treepkg/msg/Node contains itself" in tree["problem"]
    line = _one_error(*_cli(capsys, "export", bag, "-t", "/tree", "-o", tmp_path / "t.csv")[::2], "export")
    assert "contains itself" in line


def _labels_bag(tmp_path, labels: str, events: str = '{"code": "x"}') -> Path:
    return hb.joint_states_bag(tmp_path / "lab.mcap", 20, strings={
        "/prsm_actuator/internal_loads/labels": [labels], "/prsm_actuator/events": [events]})


@pytest.mark.parametrize("labels", [
    "[" * 100_000,                                                       # RecursionError in json.loads
    json.dumps({"format": "prsm_internal_loads/1", "model": "m", "elements": 3, "segments": [], "layout": {}}),
    json.dumps({"format": "prsm_internal_loads/1", "model": "m", "elements": [], "layout": {"blocks": []},
                "segments": [{"name": "b", "offset": 0, "size": 4, "dims": ["r"], "quantities": []}]}),  # no shape
])
def test_hostile_labels_and_events_are_ignored_with_the_rest_reported(tmp_path, capsys, labels):
    """Was: RecursionError, TypeError and KeyError: 'shape' from report and export."""
    bag = _labels_bag(tmp_path, labels, events="[" * 100_000)
    rc, out, err = _cli(capsys, "report", bag, "-o", tmp_path / "rep", "--no-plots", "--json")
    assert rc == 0 and "Traceback" not in err, err
    r = json.loads(out)
    assert r["samples"] == 20 and r["slip"] is None and r["events"][0]["code"] == "unparsed"
    rc, out, err = _cli(capsys, "export", bag, "-t", "/joint_states", "-o", tmp_path / "js.csv")
    assert rc == 0, err


def test_a_topic_recorded_with_two_types_is_named_not_an_attribute_error(tmp_path, capsys):
    bag = hb.two_types(tmp_path / "two.mcap")
    rc, out, err = _cli(capsys, "info", bag, "--json")
    assert rc == 0, err
    problem = json.loads(out)["topics"][0]["problem"]
    assert "two types" in problem and "std_msgs/msg/Float64" in problem
    line = _one_error(*_cli(capsys, "report", bag, "-o", tmp_path / "rep", "--no-plots")[::2], "report")
    assert "no joint states" in line


def test_report_names_the_bag_when_log_times_decrease(tmp_path, capsys):
    """Was: `InputError: time_s must not decrease` (the L10 life) from a file read in its own order."""
    bag = hb.joint_states_bag(tmp_path / "back.mcap", times_ns=[k * 10_000_000 for k in (0, 1, 2, 5, 3, 4, 6)])
    damaged = hb.bad_footer(bag, tmp_path / "back_scanned.mcap")  # scanned: file order
    line = _one_error(*_cli(capsys, "report", damaged, "-o", tmp_path / "rep", "--no-plots")[::2], "report")
    assert "back_scanned.mcap: the log times of /joint_states decrease at message 4" in line


def test_report_plots_values_of_1e308_as_missing(tmp_path, capsys):
    """Was: `ValueError: arange` drawing ±1e308 (the axis range overflows)."""
    bag = hb.joint_states_bag(tmp_path / "huge.mcap", 20, position=[1e308, -1e308, 0.001])
    rc, out, err = _cli(capsys, "report", bag, "-o", tmp_path / "rep", "--json")
    assert rc == 0, err
    r = json.loads(out)
    assert (tmp_path / "rep" / "motion.png").exists()
    assert "28 value(s) on /joint_states beyond ±1e+100 read as missing" in r["note"]
    assert r["kinematics"]["nut_travel_m"] == 0.0


# ---- play ----------------------------------------------------------------------------------------

def test_qos_numbers_out_of_range_give_the_default():
    """Was: ValueError from int('1e400') and an out-of-range depth reaching rclpy."""
    pytest.importorskip("rclpy")
    from prsm_ros.mcap.schema import MAX_QOS_DEPTH, qos_from_yaml
    for text in ("- depth: '1e400'", "- depth: 1e400", f"- depth: {MAX_QOS_DEPTH + 1}", "- depth: -3",
                 "- {depth: 4, deadline: {sec: '1e400', nsec: 0}}", "[" * 10_000):
        q = qos_from_yaml(text)
        assert q.depth in (4, 10), text
    assert qos_from_yaml("- depth: 7").depth == 7


def test_play_skips_long_topic_names_and_refuses_a_span_it_would_sleep_through(tmp_path):
    """Was: RCLError from a 300-character topic name, and days of sleep for log times spanning 3e8 s at
    --rate 1000. Now the topic is skipped with its reason, and the span refused up front with the rate
    that would do."""
    pytest.importorskip("rclpy")
    long_topic = "/" + "t" * 300
    named = hb.joint_states_bag(tmp_path / "long.mcap", 5, strings={long_topic: ["a", "b"]})
    spread = hb.joint_states_bag(tmp_path / "spread.mcap", times_ns=[0, 10**9, 3 * 10**17])
    script = ("import sys\nfrom prsm_ros.cli.bag import main\n"
              f"print('RC', main(['play', {str(named)!r}, '--delay', '0', '--rate', '1000']))\n"
              f"print('RC', main(['play', {str(spread)!r}, '--delay', '0', '--rate', '1000']))\n")
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=ENV)
    assert "Traceback" not in res.stderr, res.stderr
    assert [ln for ln in res.stdout.splitlines() if ln.startswith("RC")] == ["RC 0", "RC 2"], res.stdout + res.stderr
    assert f"skipped {long_topic} (not a valid ROS topic name" in res.stderr
    assert "spread.mcap: its log times span 3e+08 s, 3e+05 s of playback at --rate 1000" in res.stderr


# ---- export --------------------------------------------------------------------------------------

def _wide_bag(path: Path, n_msgs: int, n_joints: int) -> Path:
    """/joint_states of `n_joints` joints, in small chunks (what a reader holds at once stays small)."""
    import numpy as np
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    names = [f"j{k}" for k in range(n_joints)]
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD, chunk_size=16 << 10)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("sensor_msgs/msg/JointState", "ros2msg",
                                ts.generate_msgdef("sensor_msgs/msg/JointState", ros_version=2)[0].encode())
        cid = w.register_channel("/joint_states", "cdr", sid, {})
        for k in range(n_msgs):
            hdr = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=k), frame_id="")
            arr = np.full(n_joints, float(k))
            msg = T["sensor_msgs/msg/JointState"](header=hdr, name=names, position=arr, velocity=arr, effort=arr)
            w.add_message(cid, k * 1000, bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/JointState")), k * 1000)
        w.finish()
    return path


@pytest.mark.slow
def test_export_streams_a_wide_table_to_disk(tmp_path, capsys):
    """Was: the whole table held in memory (a 137 KB bag of wide JointStates took 1.27 GB). Now rows go
    to disk as they are decoded: exporting four times the messages takes no more memory at its peak."""
    import tracemalloc
    n_joints, peaks = 40, []
    for n_msgs in (10, 40, 160):  # the first run warms the caches (decoders, imports) and is not counted
        bag = _wide_bag(tmp_path / f"wide{n_msgs}.mcap", n_msgs, n_joints)
        tracemalloc.start()
        rc, out, err = _cli(capsys, "export", bag, "-t", "/joint_states", "-o", tmp_path / f"wide{n_msgs}.csv")
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        assert rc == 0, err
        with open(tmp_path / f"wide{n_msgs}.csv", newline="") as f:
            rows = list(csv.reader(f))
        assert len(rows) == n_msgs + 1 and len(rows[0]) == 3 * n_joints + 3
        assert rows[-1][-1] == str(float(n_msgs - 1))
    assert peaks[2] < 1.5 * peaks[1], peaks  # a held table grows with the rows: 4× the rows, > 2× the peak


def test_export_file_names_never_collide_and_formula_text_is_neutralised(tmp_path, capsys):
    """Was: topics `/` and `` both written to `.csv` (one lost); text cells kept `=HYPERLINK(…)`."""
    from mcap.writer import Writer
    bag = tmp_path / "names.mcap"
    with open(bag, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data")
        for topic, text in (("/", '=HYPERLINK("http://x","y")'), ("", "@SUM(A1)"), ("/a b", "-2+3"), ("/a_b", "plain")):
            w.add_message(w.register_channel(topic, "cdr", sid, {}), 1, hb.string_cdr(text), 1)
        fid = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
        w.add_message(w.register_channel("/neg", "cdr", fid, {}), 1, b"\x00\x01\x00\x00" + struct.pack("<d", -1.5), 1)
        w.finish()
    rc, out, err = _cli(capsys, "export", bag, "-t", "/", "-t", "", "-t", "/a b", "-t", "/a_b", "-t", "/neg",
                        "-o", tmp_path / "out")
    assert rc == 0, err
    files = out.split()
    assert len(set(files)) == 5 and all(Path(p).exists() for p in files)
    cells = {p: list(csv.reader(open(p, newline="")))[1][1] for p in files}
    assert sorted(cells.values()) == sorted(["'=HYPERLINK(\"http://x\",\"y\")", "'@SUM(A1)", "'-2+3", "plain", "-1.5"])


# ---- the fuzzer's own cases ----------------------------------------------------------------------

def test_apply_folds_every_mutation_into_the_file():
    data = bytes(range(256)) * 4
    assert fuzz.apply(data, [("truncate", 10, 0)]) == data[:10]
    assert fuzz.apply(data, [("flip", 3, 0)])[3] == data[3] ^ 1
    assert len(fuzz.apply(data, [("dup", 0, 9)])) == len(data) + 10
    assert fuzz.apply(data, [("set64", 0, 2**64 - 1)])[:8] == b"\xff" * 8


def test_a_record_longer_than_a_chunk_may_be_is_skipped_unread(tmp_path, capsys, monkeypatch):
    """A record is read whole: one declaring more than MAX_RECORD_BYTES is passed over by its length
    (scanned) or skipped (indexed), never read into memory; the records beside it are kept."""
    from prsm_ros.bag import reader
    bag = hb.joint_states_bag(tmp_path / "js.mcap", 20)
    monkeypatch.setattr(reader, "MAX_RECORD_BYTES", 64)
    for path in (bag, hb.bad_footer(bag, tmp_path / "scanned.mcap")):
        rc, out, err = _cli(capsys, "info", path, "--json", "--check")
        assert rc == 0, err
        assert "more than the 0 MiB a record may hold here" in json.loads(out)["note"]


def test_the_repair_floor_counts_messages_on_declared_channels_only(tmp_path):
    """A damaged Channel record leaves its messages without a topic: mcap's non-seeking reader stops at
    the first of them, `repair` cannot write them under any topic, so the fuzz floor does not count them
    (found by the fuzzer: a truncated bag whose channel opcode was flipped)."""
    bag = hb.undeclared_channel(hb.FLOAT64_CDR, tmp_path / "undeclared.mcap")
    assert fuzz.stream_count(bag) == 10  # the 10 on ~/screw_torque, not the 10 on channel 99


@pytest.mark.parametrize("damage", ["chunk_length", "schema_length"])
def test_a_damaged_record_length_is_read_past(tmp_path, capsys, damage):
    """Was: a chunk whose record length was damaged lost its messages (the reader framed by the length;
    mcap's stream reader reads the chunk by its own fields: 1,781 of 2,501 kept), and a damaged record
    ended the scan. Now a chunk is read by its own fields when its CRC holds, and past any other
    damaged record the scan reads on from the next record that frames."""
    from mcap.opcode import Opcode
    data = bytearray((ROOT / "bags" / "heavy_load.mcap").read_bytes())
    if damage == "chunk_length":
        pos = [p for p, op, _ in hb.records(bytes(data)) if op == Opcode.CHUNK][1]
        struct.pack_into("<Q", data, pos + 1, 0)
    else:
        pos = next(p for p, op, _ in hb.records(bytes(data)) if op == Opcode.SCHEMA)
        struct.pack_into("<Q", data, pos + 1, 1)  # one byte: its body does not parse as a Schema
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    rc, out, err = _cli(capsys, "repair", damaged, tmp_path / "fixed.mcap")
    assert rc == 0, err
    assert "read past 1 damaged byte range(s)" in err
    kept = fuzz.repaired_count(tmp_path / "fixed.mcap")
    assert kept >= fuzz.stream_count(damaged)
    assert kept == 2501  # a topic whose schema was lost is copied undecoded
