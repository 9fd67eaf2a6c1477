"""`prsm-bag` on real MCAP files: ours (offline closed loop, the example bags), one written by a
third-party writer (rosbags), broken ones, and playback over DDS to a subscriber process.

Oracles: the trajectory the bag was written from (values, the model's own energy ledger, the
analytic reference), closed forms for the third-party bag's constant signals, and the
independent rosbags writer.
"""

import csv
import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from prsm_sim import Simulator, preset
from ros_domains import domain_id
from prsm_sim.scenarios import default_spec, run_scenario
from prsm_ros.cli.bag import main
from prsm_ros.bag.reader import open_bag
from prsm_ros.cli.make_bags import pd_tracking
from prsm_ros.mcap.offline import write_trajectory_mcap

MODEL = "fu2018"  # a rename must fail here, not quietly test another model
ROOT = Path(__file__).resolve().parent.parent
DOMAIN_ID = str(domain_id("test_bag_cli"))
ENV = {**os.environ, "RERUN": "off", "PYTHONUNBUFFERED": "1", "ROS_DOMAIN_ID": DOMAIN_ID,
       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


@pytest.fixture(scope="module")
def tracking(tmp_path_factory):
    """Offline closed-loop PD tracking (s30, 2 kN) with its reference, and the trajectory itself."""
    p = preset("s30")
    traj, ref = pd_tracking(Simulator(p, MODEL, 1e-3), amplitude_m=1e-3, frequency_hz=2.0, load_n=2000.0,
                            duration_s=0.4)
    path = write_trajectory_mcap(tmp_path_factory.mktemp("bags") / "track.mcap", traj, p, MODEL,
                                 preset_name="s30", progress=False, reference_m=ref)
    return path, traj, ref


@pytest.fixture(scope="module")
def heavy(tmp_path_factory):
    p = preset("s30")
    traj = run_scenario(Simulator(p, MODEL, 1e-3), default_spec(p, "heavy"), 0.3)
    path = write_trajectory_mcap(tmp_path_factory.mktemp("bags") / "heavy.mcap", traj, p, MODEL,
                                 preset_name="s30", progress=False)
    return path, traj


# Constant signals of the third-party bag: screw 0.5 N·m at 10 rad/s (5 W in), nut 2 kN at
# 2 mm/s (4 W out): efficiency 0.8; F_m = 2 kN, so L10 = (C / 2 kN)³ · 10⁶ revolutions.
TP_TAU, TP_W, TP_F, TP_V, TP_N = 0.5, 10.0, 2000.0, 0.002, 200


@pytest.fixture(scope="module")
def third_party(tmp_path_factory):
    """A rosbag2 MCAP bag written by rosbags (no prsm metadata, QoS in the v9 enum-name form)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time = ts.types["sensor_msgs/msg/JointState"], ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    Wrench, WrenchStamped, Vector3 = ts.types["geometry_msgs/msg/Wrench"], ts.types["geometry_msgs/msg/WrenchStamped"], ts.types["geometry_msgs/msg/Vector3"]
    out = tmp_path_factory.mktemp("tp") / "bag"
    t0 = 1_700_000_000_000_000_000  # wall-clock epoch stamps, as a real recorder writes
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        js = w.add_connection("/joint_states", JointState.__msgtype__, typestore=ts)
        wr = w.add_connection("/ft_sensor/wrench", WrenchStamped.__msgtype__, typestore=ts)
        for k in range(TP_N):
            t = t0 + k * 10_000_000  # 100 Hz
            hdr = Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base")
            msg = JointState(header=hdr, name=["screw_joint", "nut_joint", "other"],
                             position=np.array([TP_W * k * 0.01, TP_V * k * 0.01, 7.0]),
                             velocity=np.array([TP_W, TP_V, 0.0]), effort=np.array([TP_TAU, TP_F, 0.0]))
            w.write(js, t, ts.serialize_cdr(msg, JointState.__msgtype__))
            wmsg = WrenchStamped(header=hdr, wrench=Wrench(force=Vector3(x=0.0, y=0.0, z=TP_F),
                                                           torque=Vector3(x=0.0, y=0.0, z=0.0)))
            w.write(wr, t, ts.serialize_cdr(wmsg, WrenchStamped.__msgtype__))
    return out


def _cli(capsys, *args) -> tuple[int, str, str]:
    rc = main([str(a) for a in args])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_info_lists_topics_counts_rates_and_run_metadata(tracking, capsys):
    path, traj, _ = tracking
    rc, out, _ = _cli(capsys, "info", path, "--json")
    assert rc == 0
    d = json.loads(out)
    topics = {t["topic"]: t for t in d["topics"]}
    assert topics["/joint_states"]["count"] == len(traj)
    assert topics["/joint_states"]["rate_hz"] == pytest.approx(1000.0, rel=1e-9)
    assert topics["/prsm_actuator/nut_position_reference"]["count"] == len(traj)
    assert d["run"]["model"] == MODEL and d["run"]["preset"] == "s30" and d["complete"]
    assert d["duration_s"] == pytest.approx(traj["time_s"][-1], abs=1e-9)  # labels at 0 to the last step
    rc, out, _ = _cli(capsys, "info", path, "--parameters")
    assert rc == 0 and "/prsm_actuator/internal_loads" in out and "1000.0 Hz" in out and "geometry:" in out


def test_export_writes_the_recorded_values_per_field(tracking, tmp_path, capsys):
    path, traj, ref = tracking
    rc, out, _ = _cli(capsys, "export", path, "-t", "/joint_states", "-t", "/prsm_actuator/internal_loads",
                      "-o", tmp_path / "csv", "--start", "0.1", "--end", "0.2")
    assert rc == 0
    with open(tmp_path / "csv" / "joint_states.csv") as f:
        rows = list(csv.DictReader(f))
    sel = (traj["time_s"] >= 0.1 - 1e-9) & (traj["time_s"] <= 0.2 + 1e-9)
    assert len(rows) == sel.sum() == 101
    assert np.array_equal([float(r["time_s"]) for r in rows], [round(t * 1e9) * 1e-9 for t in traj["time_s"][sel]])
    assert np.array_equal([float(r["nut_joint.position"]) for r in rows], traj["nut_position_m"][sel])
    assert np.array_equal([float(r["screw_joint.effort"]) for r in rows], traj["screw_torque_nm"][sel])
    with open(tmp_path / "csv" / "prsm_actuator__internal_loads.csv") as f:
        reader = csv.DictReader(f)
        rows = list(reader)
    assert "per_roller[0].screw_friction_axial_n" in reader.fieldnames  # named by the labels topic
    assert np.array_equal([float(r["efficiency"]) for r in rows], traj["efficiency"][sel], equal_nan=True)
    # resampled, merged, zero-order hold: the reference held between its messages
    rc, _, _ = _cli(capsys, "export", path, "-t", "/prsm_actuator/nut_position_reference", "-t", "/joint_states",
                    "-o", tmp_path / "m.csv", "--merge", "--resample", "100", "--method", "hold")
    assert rc == 0
    with open(tmp_path / "m.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 41  # 0 … 0.4 s at 100 Hz
    k = 25  # t = 0.25 s: the reference sent at the start of the step beginning at 0.25 s
    assert float(rows[k]["time_s"]) == pytest.approx(0.25)
    assert float(rows[k]["/prsm_actuator/nut_position_reference:nut_joint.position"]) == ref[250]


@pytest.mark.slow
def test_report_metrics_agree_with_the_trajectory(tracking, tmp_path, capsys):
    path, traj, ref = tracking
    rc, out, _ = _cli(capsys, "report", path, "-o", tmp_path / "rep", "--json", "--dynamic-load-rating-n", "50000")
    assert rc == 0
    r = json.loads(out)
    assert json.loads((tmp_path / "rep" / "report.json").read_text()) == r
    # tracking: the reference stamped t (sent at the start of the step from t) answers the state at t,
    # which the bag holds as the previous row; the unrecorded initial state has none
    x = traj["nut_position_m"]
    assert r["tracking"]["rms_error_m"] == pytest.approx(float(np.sqrt(np.mean((ref[1:] - x[:-1]) ** 2))), rel=1e-12)
    t = traj["time_s"][:-1]
    analytic = 1e-3 * np.sin(2 * math.pi * 2.0 * t)
    assert np.allclose(ref[1:], analytic, rtol=0, atol=1e-15)  # the recorded reference is x_ref(t)
    # peak tooth load: the largest |screw normal force| in the trajectory's per-tooth block
    layout = traj.layout
    if "per_tooth" in layout.offsets():
        teeth = np.array([layout.view(row, "per_tooth") for row in traj.internal])
        peak = r["peak_loads"]["per_tooth.screw_normal_force_n"]
        assert peak["peak_abs"] == float(np.max(np.abs(teeth[..., 0])))
        at = peak["at"]
        assert abs(teeth[:, at["roller"], at["tooth"], 0]).max() == peak["peak_abs"]
    # L10: cubic mean of |nut force| over the revolutions of each held sample
    f, w = np.abs(traj["nut_force_n"][:-1]), np.abs(traj["screw_speed_rad_s"][:-1])
    n = w * np.diff(traj["time_s"]) / (2 * math.pi)
    fm = (np.sum(f**3 * n) / np.sum(n)) ** (1 / 3)
    assert r["life"]["mean_load_n"] == pytest.approx(fm, rel=1e-12)
    assert r["life"]["l10_revolutions"] == pytest.approx((50000 / fm) ** 3 * 1e6, rel=1e-12)
    plots = [Path(p) for p in r["plots"]]
    assert {p.name for p in plots} >= {"motion.png", "loads.png", "power.png", "internal_loads.png"}
    for p in plots:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000


def test_report_efficiency_matches_the_models_energy_ledger(heavy, tmp_path, capsys):
    """Forward efficiency from the recorded powers = work out / work in of the model's own ledger."""
    path, traj = heavy
    rc, out, _ = _cli(capsys, "report", path, "-o", tmp_path, "--json", "--no-plots")
    assert rc == 0
    r = json.loads(out)
    ledger = traj.final_state.work_out_j / traj.final_state.work_in_j
    assert r["efficiency"]["forward"] == pytest.approx(ledger, rel=5e-3)
    assert r["efficiency"]["backward"] is None  # the load never drove the screw (beyond round-off at rest)
    assert r["plots"] == []


def test_prsm_bag_works_on_a_third_party_bag(third_party, tmp_path, capsys):
    rc, out, _ = _cli(capsys, "info", third_party, "--json")
    assert rc == 0
    d = json.loads(out)
    assert {t["topic"]: t["count"] for t in d["topics"]} == {"/joint_states": TP_N, "/ft_sensor/wrench": TP_N}
    assert d["run"] == {} and "rosbag2" in d["metadata_records"]
    rc, out, _ = _cli(capsys, "report", third_party, "-o", tmp_path / "rep", "--json", "--dynamic-load-rating-n", "40000")
    assert rc == 0
    r = json.loads(out)
    assert r["topics"]["wrench"] == "/ft_sensor/wrench"  # found by type alone
    assert r["efficiency"]["forward"] == pytest.approx(TP_F * TP_V / (TP_TAU * TP_W), rel=1e-12)
    assert r["life"]["mean_load_n"] == pytest.approx(TP_F, rel=1e-12)
    assert r["life"]["l10_revolutions"] == pytest.approx((40000 / TP_F) ** 3 * 1e6, rel=1e-9)
    assert r["tracking"] is None and r["slip"] is None and r["peak_loads"] is None
    rc, out, _ = _cli(capsys, "export", third_party, "-t", "/joint_states", "-o", tmp_path / "js.csv")
    assert rc == 0
    with open(tmp_path / "js.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == TP_N and float(rows[3]["screw_joint.position"]) == TP_W * 3 * 0.01
    assert float(rows[3]["other.position"]) == 7.0
    assert float(rows[3]["time_s"]) == pytest.approx(1_700_000_000.03, abs=1e-6)


def test_bad_files_and_arguments_get_one_clear_line_and_exit_2(tracking, tmp_path, capsys):
    path, _, _ = tracking
    (tmp_path / "text.mcap").write_text("not a bag\n")
    (tmp_path / "empty.mcap").write_bytes(b"")
    clock_only = tmp_path / "clock.mcap"
    from rclpy.qos import QoSProfile
    from rosgraph_msgs.msg import Clock

    from prsm_ros.mcap.recorder import McapRecorder
    with McapRecorder(clock_only) as rec:
        rec.add_channel("/clock", Clock, QoSProfile(depth=1))
        rec.write("/clock", Clock(), 0)
    cases = [
        (("info", tmp_path / "text.mcap"), "not an MCAP file"),
        (("info", tmp_path / "empty.mcap"), "not an MCAP file"),
        (("info", tmp_path / "missing.mcap"), "no such file"),
        (("report", clock_only, "-o", tmp_path / "r"), "no joint states"),
        (("export", path, "-t", "/nope", "-o", tmp_path / "x.csv"), "no topic '/nope'"),
        (("export", path, "-t", "/joint_states", "-t", "/clock", "-o", tmp_path / "x.csv"), "one .csv file holds one topic"),
        (("report", path, "-o", tmp_path / "r", "--dynamic-load-rating-n", "-5"), "must be a force"),
        (("report", path, "-o", tmp_path / "r", "--screw-joint", "motor"), "'motor'"),
        (("play", path, "--rate", "0"), "must be a number > 0"),
    ]
    for args, expected in cases:
        rc, _, err = _cli(capsys, *args)
        assert rc == 2, args
        lines = err.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0], (args, err)
    # the installed entry point, in a real process: no traceback
    res = subprocess.run([str(Path(sys.executable).parent / "prsm-bag"), "report", str(tmp_path / "text.mcap"),
                          "-o", str(tmp_path / "r")], capture_output=True, text=True, env=ENV, timeout=60)
    assert res.returncode == 2 and "Traceback" not in res.stderr and "not an MCAP file" in res.stderr


def test_truncated_bag_is_reported_with_a_note(tracking, tmp_path, capsys):
    path, traj, _ = tracking
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    rc, out, err = _cli(capsys, "report", cut, "-o", tmp_path / "rep", "--json", "--no-plots")
    assert rc == 0 and "unfinished MCAP file" in err
    r = json.loads(out)
    assert r["complete"] is False and 0 < r["samples"] < len(traj)


def test_to_rrd_subcommand_writes_a_recording(tracking, tmp_path, capsys):
    from test_rerun_support import rrd_component, rrd_verify
    path, traj, _ = tracking
    rrd = tmp_path / "t.rrd"
    rc, out, err = _cli(capsys, "to-rrd", path, "-o", rrd)
    assert rc == 0, err
    res = rrd_verify(rrd)  # the rerun CLI accepts the file
    assert res.returncode == 0, res.stderr
    # oracle: the simulated trajectory in the bag, every step, on simulation time, bit for bit
    t, vals = rrd_component(rrd, "/series/nut_position_mm", "Scalars:scalars")  # in mm, as the report shows it
    np.testing.assert_array_equal(t, np.round(traj["time_s"] * 1e9).astype(np.int64))
    np.testing.assert_array_equal(np.ravel(vals), traj["nut_position_m"] * 1e3)
    rc, _, err = _cli(capsys, "to-rrd", tmp_path / "t.rrd", "-o", tmp_path / "u.rrd")
    assert rc == 2 and "not an MCAP file" in err


_SUBSCRIBER = """
    import json, sys, time
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    rclpy.init()
    node = rclpy.create_node("bag_play_listener")
    got = {"js": [], "clock": [], "labels": 0}
    node.create_subscription(JointState, "/joint_states", lambda m: got["js"].append([m.header.stamp.sec, m.header.stamp.nanosec, m.position[1]]), 1000)
    node.create_subscription(Clock, "/clock", lambda m: got["clock"].append(m.clock.sec * 10**9 + m.clock.nanosec), 1000)
    node.create_subscription(String, "/prsm_actuator/internal_loads/labels",
                             lambda m: got.__setitem__("labels", got["labels"] + 1),
                             QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    print("ready", flush=True)
    want, end = int(sys.argv[1]), time.monotonic() + 40
    while time.monotonic() < end and len(got["js"]) < want:
        rclpy.spin_once(node, timeout_sec=0.05)
    t = time.monotonic() + 0.5
    while time.monotonic() < t:
        rclpy.spin_once(node, timeout_sec=0.05)
    print(json.dumps(got), flush=True)
"""


@pytest.mark.slow
def test_play_republishes_the_bag_over_dds_with_clock(tracking):
    path, traj, _ = tracking
    n = int(np.sum(traj["time_s"] <= 0.2 + 1e-9))
    sub = subprocess.Popen([sys.executable, "-c", textwrap.dedent(_SUBSCRIBER), str(n)], stdout=subprocess.PIPE,
                           text=True, env=ENV)
    try:
        assert sub.stdout.readline().strip() == "ready"
        res = subprocess.run([sys.executable, "-m", "prsm_ros.cli.bag", "play", str(path), "--rate", "2",
                              "--end", "0.2", "--delay", "0.5", "--wait-for-subscribers", "-t", "/joint_states",
                              "-t", "/prsm_actuator/internal_loads/labels"],
                             capture_output=True, text=True, env=ENV, timeout=60)
        assert res.returncode == 0, res.stderr
        assert f"/joint_states: {n}" in res.stdout
        got = json.loads(sub.stdout.readline())
    finally:
        sub.kill()
        sub.wait()
        sub.stdout.close()
    assert [p for _, _, p in got["js"]] == list(traj["nut_position_m"][:n])
    stamps = [s * 10**9 + ns for s, ns, _ in got["js"]]
    assert stamps == [round(t * 1e9) for t in traj["time_s"][:n]]
    # /clock made from the bag time (the recorded /clock was not selected): 0 (labels), then every step
    assert got["clock"] == [0] + [round(t * 1e9) for t in traj["time_s"][:n]]
    assert got["labels"] == 1


def test_example_bags_are_readable_and_current(tmp_path):
    """bags/ hold the four examples; the step response regenerates to the same values (golden data)."""
    from prsm_ros.cli.make_bags import make
    bags = {p.stem: open_bag(p) for p in sorted((ROOT / "bags").glob("*.mcap"))}
    assert set(bags) == {"step_response", "sine_tracking", "heavy_load", "light_load"}
    assert sum(b.path.stat().st_size for b in bags.values()) < 8e6
    for bag in bags.values():
        assert bag.complete and bag.topics["/joint_states"].count >= 500
        if "prsm_example" in bag.metadata:  # written offline
            assert bag.metadata["prsm_example"]["made_by"] == "python -m prsm_ros.cli.make_bags"
        else:  # recorded by the node in a prsm-demo run
            assert "time_mode: lockstep" in bag.run_metadata["node_parameters_yaml"]
    assert bags["sine_tracking"].topics["/prsm_actuator/nut_position_reference"].count > 0
    fresh = open_bag(make(tmp_path, bags["step_response"].run_metadata["model"], progress=False, only=("step_response",))[0])
    old = [m.msg.position[1] for m in bags["step_response"].messages(["/joint_states"])]
    new = [m.msg.position[1] for m in fresh.messages(["/joint_states"])]
    assert np.allclose(old, new, rtol=1e-9, atol=0), "bags/ are stale: regenerate with python -m prsm_ros.cli.make_bags"
