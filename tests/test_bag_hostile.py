"""`prsm-bag` on hostile files: damaged, foreign, malformed, oversized, and one naming a module to import.

The corpus is built in the test from a good bag of our own (`hostile_bags`). Every file goes
through info, report, export, to-rrd and play: each ends with exit 0 or 2, at most one error line,
no traceback, and nothing is imported by a name taken from a file. Where the usable part of a file
is known (the messages written around the damage), the tools must recover exactly that part.
Oracles: the message counts written into the corpus, the mcap library's default reader and the
`rerun` CLI (independent readers) for `repair`.
"""

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest

import hostile_bags as hb
from prsm_sim import Simulator, preset
from prsm_ros.cli.bag import EXIT_ERROR, main
from prsm_ros.cli.make_bags import pd_tracking
from prsm_ros.mcap.offline import write_trajectory_mcap
from ros_domains import domain_id

ROOT = Path(__file__).resolve().parent.parent
STEPS = 400  # the base bag: 0.4 s at 1 ms
ENV = {**os.environ, "PYTHONUNBUFFERED": "1", "ROS_DOMAIN_ID": str(domain_id("test_bag_hostile")),
       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
ENV.pop("RERUN", None)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile")
    p = preset("s30")
    traj, ref = pd_tracking(Simulator(p, "ideal", 1e-3), amplitude_m=1e-3, frequency_hz=2.0, load_n=2000.0,
                            duration_s=STEPS * 1e-3)
    base = write_trajectory_mcap(d / "base.mcap", traj, p, "ideal", preset_name="s30", progress=False,
                                 reference_m=ref, chunk_size=32 << 10)  # several chunks to damage one of
    bags = {
        "truncated": hb.truncated(base, d / "truncated.mcap"),
        "bad_crc": hb.bad_crc(base, d / "bad_crc.mcap"),
        "bad_footer": hb.bad_footer(base, d / "bad_footer.mcap"),
        "huge_lengths": hb.huge_lengths(base, d / "huge.mcap"),
        "wrong_schema": hb.wrong_schema(d / "wrong.mcap"),
        "unparseable_schema": hb.unparseable_schema(d / "unparseable.mcap"),
        "foreign_encoding": hb.foreign_encoding(d / "foreign.mcap"),
        "undeclared_channel": hb.undeclared_channel(hb.FLOAT64_CDR, d / "undeclared.mcap"),
        "malformed": hb.malformed_messages(d / "malformed.mcap"),
        "evil": hb.evil_schema(d / "evil.mcap"),
    }
    return d, base, bags


def _cli(capsys, *args):
    rc = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return rc, out, err


def _one_line_at_most(err: str, command: str) -> None:
    errors = [ln for ln in err.splitlines() if ln.startswith(f"prsm-bag {command}: error:")]
    assert len(errors) <= 1 and "Traceback" not in err, err


def _count(capsys, bag, topic) -> int:
    rc, out, err = _cli(capsys, "info", bag, "--json")
    assert rc == 0, err
    return next(t for t in json.loads(out)["topics"] if t["topic"] == topic)["count"]


@pytest.mark.parametrize("name", ["truncated", "bad_crc", "bad_footer", "huge_lengths", "wrong_schema",
                                  "unparseable_schema", "foreign_encoding", "undeclared_channel", "malformed",
                                  "evil"])
def test_every_tool_survives_every_hostile_bag(corpus, name, tmp_path, capsys):
    _, _, bags = corpus
    bag = bags[name]
    rc, out, err = _cli(capsys, "info", bag, "--json")
    assert rc == 0 and "Traceback" not in err, err
    topics = [t["topic"] for t in json.loads(out)["topics"]]
    runs = [("report", bag, "-o", tmp_path / "rep", "--no-plots"), ("to-rrd", bag, "-o", tmp_path / "x.rrd"),
            ("info", bag)]
    runs += [("export", bag, "-t", t, "-o", tmp_path / f"e{i}") for i, t in enumerate(topics)]
    for args in runs:
        rc, _, err = _cli(capsys, *args)
        assert rc in (0, EXIT_ERROR) and EXIT_ERROR == 2, (args, rc, err)
        _one_line_at_most(err, args[0])


def test_a_chunk_with_a_bad_crc_is_skipped_counted_and_noted(corpus, tmp_path, capsys):
    """Was: silently accepted. The other chunks are read, exit 0; a CRC of 0 means "not computed"."""
    _, base, bags = corpus
    topic = "/joint_states"
    rc, out, err = _cli(capsys, "export", bags["bad_crc"], "-t", topic, "-o", tmp_path / "js.csv")
    assert rc == 0 and "CRC mismatch" in err and "skipped 1 damaged chunk" in err, err
    rows = (tmp_path / "js.csv").read_text().count("\n") - 1
    assert 0 < rows < STEPS
    data = bytearray(bags["bad_crc"].read_bytes())
    pos = next(p for p, op, _ in hb.records(bytes(data)) if op == 0x06)
    struct.pack_into("<I", data, pos + 9 + 24, 0)
    zero = tmp_path / "crc0.mcap"
    zero.write_bytes(bytes(data))
    rc, out, err = _cli(capsys, "export", zero, "-t", topic, "-o", tmp_path / "js0.csv")
    assert rc == 0 and "damaged" not in err, err
    assert (tmp_path / "js0.csv").read_text().count("\n") - 1 == STEPS


def test_a_damaged_footer_falls_back_to_scanning(corpus, capsys):
    """Was: "cannot read (Invalid argument)", exit 1. Now every message is recovered by scanning."""
    _, base, bags = corpus
    rc, out, err = _cli(capsys, "info", bags["bad_footer"], "--json")
    assert rc == 0, err
    d = json.loads(out)
    assert "damaged footer" in d["note"]
    assert d["messages"] == _count_all(capsys, base)


def _count_all(capsys, bag) -> int:
    rc, out, _ = _cli(capsys, "info", bag, "--json", "--no-check")
    return json.loads(out)["messages"]


def test_malformed_messages_are_skipped_and_counted(corpus, tmp_path, capsys):
    """Was: a 4-byte ~/screw_torque failed export and to-rrd (exit 1). Corpus: 2 bad JointState, 1 bad Float64."""
    _, _, bags = corpus
    bag = bags["malformed"]
    rc, out, err = _cli(capsys, "info", bag, "--json")
    assert rc == 0, err
    malformed = {t["topic"]: t["malformed"] for t in json.loads(out)["topics"]}
    assert malformed == {"/joint_states": 2, hb.SCREW_TORQUE: 1}
    rc, out, err = _cli(capsys, "export", bag, "-t", hb.SCREW_TORQUE, "-o", tmp_path / "tq.csv")
    assert rc == 0 and f"skipped 1 malformed message(s) on {hb.SCREW_TORQUE}" in err, err
    assert (tmp_path / "tq.csv").read_text().count("\n") - 1 == 19
    rc, out, err = _cli(capsys, "report", bag, "-o", tmp_path / "rep", "--json", "--no-plots")
    assert rc == 0 and json.loads(out)["samples"] == 18, err
    rc, out, err = _cli(capsys, "to-rrd", bag, "-o", tmp_path / "m.rrd")
    # every subcommand's notes on stderr, from one place (prsm-bag's `_reading_notes`), once
    assert rc == 0 and err.count("skipped 2 malformed message(s) on /joint_states") == 1, (out, err)


@pytest.mark.parametrize("name, problem", [("wrong_schema", "not the standard one"),
                                           ("unparseable_schema", "does not parse"),
                                           ("foreign_encoding", "message encoding 'protobuf'")])
def test_a_foreign_schema_on_joint_states_gives_one_line_and_other_topics_stay_usable(corpus, name, problem,
                                                                                       tmp_path, capsys):
    """Was: AttributeError tracebacks from report and to-rrd."""
    _, _, bags = corpus
    bag = bags[name]
    rc, out, err = _cli(capsys, "report", bag, "-o", tmp_path / "rep", "--no-plots")
    assert rc == EXIT_ERROR and problem in err and "no joint states" in err, err
    rc, _, err = _cli(capsys, "export", bag, "-t", "/joint_states", "-o", tmp_path / "js.csv")
    assert rc == EXIT_ERROR and problem in err.splitlines()[-1], err
    if name != "foreign_encoding":
        rc, _, err = _cli(capsys, "export", bag, "-t", hb.SCREW_TORQUE, "-o", tmp_path / "tq.csv")
        assert rc == 0 and (tmp_path / "tq.csv").read_text().count("\n") - 1 == 20, err


def test_messages_on_an_undeclared_channel_are_skipped_with_a_note(corpus, tmp_path, capsys):
    """Was: KeyError: 99 from report, export and play."""
    _, _, bags = corpus
    rc, out, err = _cli(capsys, "export", bags["undeclared_channel"], "-t", hb.SCREW_TORQUE, "-o", tmp_path / "t.csv")
    assert rc == 0 and "10 message(s) on channel(s) 99" in err, err
    assert (tmp_path / "t.csv").read_text().count("\n") - 1 == 10


def test_huge_declared_lengths_are_refused_not_allocated(corpus, capsys):
    _, _, bags = corpus
    rc, out, err = _cli(capsys, "info", bags["huge_lengths"], "--json")
    assert rc == 0, err
    note = json.loads(out)["note"]
    from prsm_ros.bag.reader import MAX_CHUNK_BYTES
    assert f"more than the {MAX_CHUNK_BYTES >> 20} MiB a chunk may hold" in note and "unfinished" in note


def test_repair_makes_a_killed_bag_readable_by_rerun_and_the_mcap_library(corpus, tmp_path, capsys):
    """Was: `rerun mcap` and mcap's make_reader refuse a bag without summary. After repair both read
    every message prsm-bag recovered."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader
    _, _, bags = corpus
    cut = bags["truncated"]
    with open(cut, "rb") as f, pytest.raises(McapError):
        list(make_reader(f).iter_messages())
    recovered = _count_all(capsys, cut)
    fixed = tmp_path / "fixed.mcap"
    rc, out, err = _cli(capsys, "repair", cut, fixed)
    assert rc == 0 and "unfinished" in err, err
    with open(fixed, "rb") as f:
        reader = make_reader(f)
        assert sum(1 for _ in reader.iter_messages()) == reader.get_summary().statistics.message_count == recovered
        assert {m.name for m in reader.iter_metadata()} >= {"prsm_run", "rosbag2"}
    rerun = Path(sys.executable).parent / "rerun"
    res = subprocess.run([str(rerun), "mcap", "convert", str(fixed), "-o", str(tmp_path / "f.rrd")],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and "Failed to load" not in res.stderr, res.stderr[-2000:]
    res = subprocess.run([str(rerun), "mcap", "convert", str(cut), "-o", str(tmp_path / "c.rrd")],
                         capture_output=True, text=True, timeout=120)
    assert "Failed to load MCAP file" in res.stderr  # the unrepaired file: what repair is for
    rc, _, err = _cli(capsys, "repair", fixed, fixed)
    assert rc == EXIT_ERROR and "overwrite" in err


@pytest.mark.slow
def test_no_module_named_by_a_bag_is_imported_and_play_survives_the_corpus(corpus, tmp_path):
    """Was: play imported `evilmod.msg`, running evilmod.py from the working folder.

    Real processes with the folder holding evilmod.py as their working directory (on sys.path,
    as for a user running the tools there); play over DDS on this test's domain."""
    _, _, bags = corpus
    marker = hb.evil_module(tmp_path)
    script = "\n".join([
        "import sys",
        "from prsm_ros.cli.bag import main",
        "rc = []",
        *[f"rc.append(main({args!r}))" for args in (
            ["info", str(bags["evil"])], ["export", str(bags["evil"]), "-t", "/evil", "-o", "evil.csv"],
            ["report", str(bags["evil"]), "-o", "rep", "--no-plots"], ["to-rrd", str(bags["evil"]), "-o", "e.rrd"],
            *(["play", str(b), "--delay", "0", "--rate", "1000"] for b in bags.values()))],
        "print('RC', rc)",
    ])
    res = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, capture_output=True, text=True,
                         timeout=300, env={**ENV, "PYTHONPATH": f"{tmp_path}{os.pathsep}{ROOT}"})
    assert "Traceback" not in res.stderr and res.returncode == 0, res.stderr[-3000:]
    rcs = json.loads(res.stdout.split("RC ")[-1])
    assert all(rc in (0, EXIT_ERROR) for rc in rcs), (rcs, res.stderr[-3000:])
    assert "skipped /evil (evilmod/msg/Evil: play publishes only the types of" in res.stderr
    assert f"skipped 1 malformed message(s) on {hb.SCREW_TORQUE}" in res.stderr  # never handed to subscribers
    assert "skipped 2 malformed message(s) on /joint_states" in res.stderr
    assert not marker.exists(), "a module named by the bag was imported"


def test_a_damaged_metadata_number_leaves_the_report_of_the_messages():
    """The bag fuzzer's case `flip 208`: one flipped byte turned the run metadata's dt_s "0.001" into
    "0/001", and `prsm-bag report` ended in a ValueError traceback. The report reads such a value as
    not recorded."""
    from prsm_ros.bag.report import _metadata_number
    assert _metadata_number({"dt_s": "0.001"}, "dt_s") == 0.001
    assert _metadata_number({"dt_s": "0/001"}, "dt_s") is None
    assert _metadata_number({"dt_s": "nan"}, "dt_s") is None and _metadata_number({}, "dt_s") is None
