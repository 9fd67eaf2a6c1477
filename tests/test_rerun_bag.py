"""bag_to_rrd on real MCAP files: ours (prsm_ros.mcap.offline, the node's message mapping), a
third-party rosbag2 bag written by rosbags with joint states only, an unfinished recording and
bags that cannot be converted. The .rrd files are checked with the `rerun` CLI; the values are
compared with the bag as an independent reader (rosbags) decodes it.
"""

from __future__ import annotations

import numpy as np
import pytest

from prsm_sim import OUTPUT_FIELDS, Simulator, preset

from test_rerun_support import entities, has_blueprint, rrd_component, rrd_rows, rrd_verify
from test_rerun_support import strict_rerun  # noqa: F401  (fixture, used by pytestmark)

import rerun as rr  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)
from prsm_ros.bag.reader import BagError  # noqa: E402
from prsm_ros.mcap.offline import write_trajectory_mcap  # noqa: E402
from prsm_ros.viz.from_bag import bag_to_rrd  # noqa: E402
from prsm_ros.viz.sink import RerunSink  # noqa: E402

N = 1200
RATE_HZ = 30.0


pytestmark = pytest.mark.usefixtures("strict_rerun")


@pytest.fixture(scope="module")
def ours(tmp_path_factory):
    """A fu2018 run written as `prsm-sim run --mcap` writes it, with a controller reference."""
    d = tmp_path_factory.mktemp("bag")
    params = preset("s30")
    tau = np.where(np.arange(N) < N // 2, 3.0, -3.0)
    traj = Simulator(params, "fu2018", 1e-3).run(tau, 2000.0)
    reference = np.linspace(0.0, 0.05, N)
    bag = write_trajectory_mcap(d / "run.mcap", traj, params, "fu2018", preset_name="s30", progress=False,
                                reference_m=reference)
    summary = bag_to_rrd(bag, d / "run.rrd", progress=False, scene_rate_hz=RATE_HZ)
    return bag, d / "run.rrd", summary, traj, params


def test_our_bag_converts_to_a_verified_rrd_with_every_step(ours):
    bag, rrd, summary, traj, params = ours
    res = rrd_verify(rrd)
    assert res.returncode == 0, res.stderr
    assert summary["source"] == "internal_loads" and summary["model"] == "fu2018"
    assert summary["geometry"] == "bag run metadata"
    assert summary["rows"] == N and summary["warnings"] == [] and summary["notes"] == []
    frames = len({round(t * 1000) * int(RATE_HZ) // 1000 for t in traj["time_s"]})
    assert summary["scene_frames"] == frames
    assert summary["duration_s"] == pytest.approx(traj["time_s"][-1] - traj["time_s"][0])
    rows = rrd_rows(rrd)
    for name, _ in OUTPUT_FIELDS[1:]:
        assert rows[(f"/series/{name}", "Scalars:scalars")] == N, name
    for block in ("per_roller", "carrier"):  # (roller, quantity) and (quantity,) blocks are series
        b = next(b for b in traj.layout.blocks if b.name == block)
        for q, _ in b.quantities:
            assert rows[(f"/series/{block}/{q}", "Scalars:scalars")] == N, q
    assert not any(e.startswith("/series/per_tooth") for e in entities(rows))  # heat maps, not series
    assert rows[("/series/inputs/nut_position_reference", "Scalars:scalars")] == N
    assert rows[("/series/inputs/screw_torque", "Scalars:scalars")] == N
    assert rows[("/world/nut/carrier/forces/screw_normal_force", "Arrows3D:vectors")] == frames
    assert rows[("/loads/per_tooth/nut_normal_force_n", "Tensor:data")] == frames
    assert has_blueprint(rrd)


def test_series_match_the_bag_as_rosbags_reads_it(ours):
    """The independent reader's /joint_states nut position and screw effort equal the .rrd series."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    bag, rrd, _, _, _ = ours
    store = get_typestore(Stores.ROS2_HUMBLE)
    t_bag, nut, torque = [], [], []
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == "/joint_states"]
        for c, _, raw in reader.messages(connections=conns):
            msg = store.deserialize_cdr(raw, c.msgtype)
            t_bag.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
            nut.append(msg.position[list(msg.name).index("nut_joint")])
            torque.append(msg.effort[list(msg.name).index("screw_joint")])
    t, vals = rrd_component(rrd, "/series/nut_position_m", "Scalars:scalars")
    np.testing.assert_array_equal(t, t_bag)
    np.testing.assert_array_equal(np.array(vals).ravel(), nut)
    _, vals = rrd_component(rrd, "/series/screw_torque_nm", "Scalars:scalars")
    np.testing.assert_array_equal(np.array(vals).ravel(), torque)


def test_bag_and_live_recordings_have_the_same_entities(ours, tmp_path):
    """bag_to_rrd builds the scene and series RerunSink builds live (inputs are bag-only)."""
    _, rrd, _, traj, params = ours
    live = tmp_path / "live.rrd"
    sink = RerunSink("save", str(live), params, traj.layout, "fu2018", scene_rate_hz=RATE_HZ)
    for k in range(len(traj)):
        sink.submit(traj.row(k))
    sink.close()
    mine = {e for e in entities(rrd_rows(rrd)) if e.startswith(("/series", "/world", "/loads"))
            and not e.startswith("/series/inputs")}
    theirs = {e for e in entities(rrd_rows(live)) if e.startswith(("/series", "/world", "/loads"))}
    assert mine == theirs
    t_bag, v_bag = rrd_component(rrd, "/world/nut/carrier/forces/nut_normal_force", "Arrows3D:vectors")
    t_live, v_live = rrd_component(live, "/world/nut/carrier/forces/nut_normal_force", "Arrows3D:vectors")
    np.testing.assert_array_equal(t_bag, t_live)
    np.testing.assert_array_equal(np.array(v_bag), np.array(v_live))


@pytest.fixture(scope="module")
def joint_states_only(tmp_path_factory):
    """A rosbag2 MCAP bag written by rosbags: /joint_states only, wall-clock stamps, an extra joint."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time = (ts.types[n] for n in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                      "builtin_interfaces/msg/Time"))
    out = tmp_path_factory.mktemp("tp") / "bag"
    t0 = 1_700_000_000_000_000_000
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        js = w.add_connection("/joint_states", JointState.__msgtype__, typestore=ts)
        for k in range(300):  # 100 Hz, 3 s: screw at 10 rad/s, nut 5 mm per revolution
            t = t0 + k * 10_000_000
            msg = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=""),
                             name=["screw_joint", "nut_joint", "wrist"],
                             position=np.array([0.1 * k, 0.005 / (2 * np.pi) * 0.1 * k, 0.3]),
                             velocity=np.array([10.0, 0.05 / (2 * np.pi), 0.0]),
                             effort=np.array([0.5, 2000.0, 1.0]))
            w.write(js, t, ts.serialize_cdr(msg, JointState.__msgtype__))
    return out


def test_joint_states_only_bag_gives_series_and_screw_nut_motion(joint_states_only, tmp_path):
    rrd = tmp_path / "tp.rrd"
    summary = bag_to_rrd(joint_states_only, rrd, progress=False, scene_rate_hz=RATE_HZ)
    assert rrd_verify(rrd).returncode == 0
    assert summary["source"] == "joint_states" and summary["rows"] == 300
    assert summary["geometry"].startswith("schematic")
    assert summary["duration_s"] == pytest.approx(2.99)
    rows = rrd_rows(rrd)
    for name in ("screw_angle_rad", "screw_speed_rad_s", "screw_torque_nm", "nut_position_m",
                 "nut_velocity_m_s", "nut_force_n"):
        assert rows[(f"/series/{name}", "Scalars:scalars")] == 300, name
    assert rows[("/series/inputs/joint_states/wrist/position", "Scalars:scalars")] == 300
    frames = len({k * 10 * int(RATE_HZ) // 1000 for k in range(300)})
    assert rows[("/world/screw", "Transform3D:quaternion")] == frames
    assert rows[("/world/nut", "Transform3D:translation")] == frames
    assert ("/world/nut/carrier", "Transform3D:quaternion") not in rows  # no carrier angle in this bag
    assert not any(e.startswith("/world/nut/carrier/forces") for e in entities(rows))
    t, vals = rrd_component(rrd, "/series/nut_position_m", "Scalars:scalars")
    assert t[0] == 0 and t[-1] == 2_990_000_000  # a foreign bag's sim_time starts at its first message
    np.testing.assert_allclose(np.array(vals).ravel(), 0.005 / (2 * np.pi) * 0.1 * np.arange(300))
    assert has_blueprint(rrd)


def test_unfinished_bag_converts_what_was_recorded(ours, tmp_path):
    bag = ours[0]
    cut = tmp_path / "cut.mcap"
    data = bag.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    summary = bag_to_rrd(cut, tmp_path / "cut.rrd", progress=False)
    assert rrd_verify(tmp_path / "cut.rrd").returncode == 0
    assert 0 < summary["rows"] < N
    assert any("unfinished" in n for n in summary["notes"])


def test_missing_or_unusable_inputs_are_one_clear_error(ours, tmp_path):
    with pytest.raises(BagError, match="no such file"):
        bag_to_rrd(tmp_path / "missing.mcap", tmp_path / "x.rrd", progress=False)
    with pytest.raises(ValueError, match="does not exist"):
        bag_to_rrd(ours[0], tmp_path / "no_dir" / "x.rrd", progress=False)
    with pytest.raises(ValueError, match="overwrite the bag"):
        bag_to_rrd(ours[0], ours[0], progress=False)
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("not a bag")
    with pytest.raises(BagError, match="not an MCAP file"):
        bag_to_rrd(not_mcap, tmp_path / "x.rrd", progress=False)
    assert not (tmp_path / "x.rrd").exists()


def test_bag_without_joint_states_or_internal_loads_is_refused(tmp_path):
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Clock, Time = ts.types["rosgraph_msgs/msg/Clock"], ts.types["builtin_interfaces/msg/Time"]
    out = tmp_path / "clock_only"
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        c = w.add_connection("/clock", Clock.__msgtype__, typestore=ts)
        w.write(c, 1000, ts.serialize_cdr(Clock(clock=Time(sec=0, nanosec=1000)), Clock.__msgtype__))
    with pytest.raises(ValueError, match="nothing to convert.*topics: /clock"):
        bag_to_rrd(out, tmp_path / "x.rrd", progress=False)
    assert not (tmp_path / "x.rrd").exists()


def test_a_bag_that_breaks_half_way_leaves_no_partial_rrd(tmp_path):
    """Labels that do not describe the rows (a jones2016 labels beside fu2018 rows): one clear error, no output."""
    from prsm_ros.messages import TOPICS, MessageMapper, time_ns
    from prsm_ros.mcap.recorder import McapFile

    params = preset("s30")
    traj = Simulator(params, "fu2018", 1e-3).run(np.full(50, 1.0), 100.0)
    wrong = MessageMapper(Simulator(params, "jones2016").layout, "jones2016")
    right = MessageMapper(traj.layout, "fu2018")
    bag = tmp_path / "mismatch.mcap"
    f = McapFile(bag)
    ids = {k: f.add_channel(TOPICS[k].resolved(), TOPICS[k].msg_class, TOPICS[k].qos)
           for k in ("labels", "internal_loads")}
    f.write(ids["labels"], wrong.labels(), 0)
    for k in range(len(traj)):
        out = traj.row(k)
        f.write(ids["internal_loads"], right.internal_loads(out), time_ns(out.time_s))
    f.finish()
    with pytest.raises(ValueError, match="elements, the labels describe"):
        bag_to_rrd(bag, tmp_path / "x.rrd", progress=False)
    assert not (tmp_path / "x.rrd").exists()


def test_rerun_off_in_the_environment_is_refused_not_ignored(ours, tmp_path, monkeypatch):
    """The Rerun SDK honours RERUN=off by writing nothing; an explicit conversion says so instead."""
    monkeypatch.setenv("RERUN", "off")
    with pytest.raises(ValueError, match="RERUN=off"):
        bag_to_rrd(ours[0], tmp_path / "x.rrd", progress=False)
    assert not (tmp_path / "x.rrd").exists()
