"""What the Rerun recording shows beside the 3D scene, read back with the `rerun` CLI (`rrd verify`,
`rrd print`) and the SDK's chunk reader: the heat map's colour range, the bars of the load along the
nut (their values: the mean over the rollers of the per-tooth forces the model output), lengths in
mm as `prsm-bag report` prints them, and the controller's reference in a live recording as in a
converted bag (at the stamp of the state it answers)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rerun")

from prsm_sim import Simulator, preset  # noqa: E402
from prsm_ros.viz.scene import heat_map_range  # noqa: E402
from prsm_ros.viz.sink import RerunSink  # noqa: E402
from test_rerun_support import rrd_component, rrd_rows, rrd_verify, strict_rerun  # noqa: E402,F401

pytestmark = pytest.mark.usefixtures("strict_rerun")


def test_heat_map_range_spans_each_frame_and_puts_equal_shares_mid_scale():
    varying = np.array([[[1.0, 2.0, 4.0], [1.5, 2.0, 3.0]]])
    np.testing.assert_array_equal(heat_map_range(varying), [[1.0, 4.0]])
    flat = np.full((1, 2, 3), 99.25)  # fu2018's equal shares: one colour, in the middle of [0, 2 v]
    np.testing.assert_array_equal(heat_map_range(flat), [[0.0, 2 * 99.25]])
    np.testing.assert_array_equal(heat_map_range(np.zeros((1, 2, 3))), [[0.0, 1.0]])


def _joint_state_cdr(stamp_ns: int, nut_m: float) -> bytes:
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time = (ts.types[n] for n in ("sensor_msgs/msg/JointState", "std_msgs/msg/Header",
                                                      "builtin_interfaces/msg/Time"))
    msg = JointState(header=Header(stamp=Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9), frame_id=""),
                     name=["screw_joint", "nut_joint"], position=np.array([0.0, nut_m]), velocity=np.array([]),
                     effort=np.array([]))
    return bytes(ts.serialize_cdr(msg, JointState.__msgtype__))


def test_live_recording_has_the_reference_in_mm_and_the_load_along_the_nut(tmp_path):
    pytest.importorskip("rosbags")
    p = preset("s30")
    sim = Simulator(p, "elastic", 1e-3)
    path = tmp_path / "live.rrd"
    sink = RerunSink("save", str(path), p, sim.layout, "elastic", scene_rate_hz=100.0)
    outs = []
    for k in range(40):
        out = sim.step(20.0, 20_000.0)
        outs.append(out)
        sink.submit(out)
        sink.submit_reference(_joint_state_cdr(round(out.time_s * 1e9), 1e-4 * k), "nut_joint")
    assert sink.close() and sink.stats()["error"] is None
    res = rrd_verify(path)
    assert res.returncode == 0, res.stderr
    rows = rrd_rows(path)
    assert rows[("/series/inputs/nut_position_reference", "Scalars:scalars")] == 40
    t, ref = rrd_component(path, "/series/inputs/nut_position_reference", "Scalars:scalars")
    np.testing.assert_array_equal(t, [round(o.time_s * 1e9) for o in outs])
    np.testing.assert_allclose(np.array(ref).ravel(), 1e-4 * np.arange(40) * 1e3, rtol=1e-12)  # mm
    # the bars: the mean over the rollers of each tooth's screw-side normal force, at the drawn frames
    t_bar, bars = rrd_component(path, "/loads/along_nut/per_tooth/screw_normal_force_n", "BarChart:values")
    assert len(t_bar) == rows[("/loads/per_tooth/screw_normal_force_n", "Tensor:data")] > 1
    by_time = {round(o.time_s * 1e9): o for o in outs}
    layout = sim.layout
    for t_ns, bar in zip(t_bar.tolist(), bars, strict=True):
        teeth = layout.view(by_time[t_ns].internal, "per_tooth")[..., 0]  # roller × tooth
        (tensor,) = bar  # one TensorData a row: shape, names, buffer
        assert tensor["shape"] == [p.geometry.n_teeth] and tensor["names"] == ["tooth"]
        got = np.array(tensor["buffer"], dtype=float)
        np.testing.assert_allclose(got, teeth.mean(axis=0), rtol=1e-12)
        assert np.ptp(got) > 0.05 * got.mean()  # the elastic nut shares the load unevenly
