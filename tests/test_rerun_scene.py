"""The scene's pure parts: which forces a layout yields, thread handedness, decimation, scales,
and the blueprint for layouts with and without per-tooth loads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prsm_sim import InternalBlock, InternalLayout, Simulator, preset

from test_rerun_support import entities, rrd_rows, rrd_verify
from test_rerun_support import strict_rerun  # noqa: F401  (fixture, used by pytestmark)

import rerun as rr  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)
from prsm_ros.viz.blueprint import default_blueprint  # noqa: E402
from prsm_ros.viz.scene import (FORCE_REF_N, arrow_length_m, color_by_magnitude, force_families,  # noqa: E402
                                  helix, scene_frame_indices, tooth_quantities)
from prsm_ros.viz.sink import RerunSink  # noqa: E402

pytestmark = pytest.mark.usefixtures("strict_rerun")


def test_jones2016_layout_gives_one_friction_vector_at_the_screw_contact():
    fams = force_families(Simulator(preset("jones2016"), "jones2016").layout)
    assert [(f.name, f.site, f.columns) for f in fams] == [("screw_friction", "screw", (3, 4, 5))]
    assert tooth_quantities(Simulator(preset("jones2016"), "jones2016").layout) == []


def test_fu2018_layout_gives_normals_friction_gear_pin_and_tooth_loads():
    layout = Simulator(preset("s30"), "fu2018").layout
    q = {name: k for k, (name, _) in enumerate(layout.blocks[0].quantities)}
    fams = {f.name: f for f in force_families(layout)}
    assert fams["screw_normal_force"].columns == (q["screw_normal_force_n"],)
    assert fams["nut_normal_force"].site == "nut"
    assert fams["screw_friction"].columns == (q["screw_friction_radial_n"], q["screw_friction_tangential_n"],
                                              q["screw_friction_axial_n"])
    assert fams["gear_force"].site == "gear" and fams["gear_force"].columns[2] is None  # no axial gear force
    assert fams["pin_force"].site == "axis"
    # nut friction (sliding off the standard design) and the two pin end reactions (issue 12) join generically
    assert set(fams) == {"screw_normal_force", "nut_normal_force", "screw_friction", "gear_force", "pin_force",
                         "nut_friction", "pin_1_force", "pin_2_force"}
    assert fams["nut_friction"].site == "nut" and fams["pin_1_force"].site == fams["pin_2_force"].site == "axis"
    assert [(b, q, side) for b, _, q, side in tooth_quantities(layout)] == [
        ("per_tooth", "screw_normal_force_n", "screw"), ("per_tooth", "nut_normal_force_n", "nut")]


def test_layout_families_ignore_slips_moments_and_lone_components():
    """Only newton quantities with a direction (≥ 2 components) or a named normal become arrows."""
    layout = InternalLayout(blocks=(
        InternalBlock("per_roller", ("roller", "quantity"), (4, 5), (
            ("screw_slip_radial_m_s", "m/s"), ("screw_slip_axial_m_s", "m/s"), ("pin_friction_moment_nm", "N·m"),
            ("gear_radial_force_n", "N"), ("nut_normal_force_n", "N"))),
        InternalBlock("carrier", ("quantity",), (1,), (("axial_force_n", "N"),)),
    ))
    assert [(f.name, f.site) for f in force_families(layout)] == [("nut_normal_force", "nut")]


def test_threads_are_right_handed():
    """A right-hand helix climbs (+z) while turning positively about +z: (r × dr/dφ)·ẑ > 0 with dz/dφ > 0."""
    pts = helix(0.01, 0.005, -0.02, 0.02)
    d = np.diff(pts, axis=0)
    turn = pts[:-1, 0] * d[:, 1] - pts[:-1, 1] * d[:, 0]
    assert np.all(turn > 0) and np.all(d[:, 2] > 0)
    # one lead of climb per turn
    phi = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))
    assert (pts[-1, 2] - pts[0, 2]) / (phi[-1] - phi[0]) == pytest.approx(0.005 / (2 * math.pi))


def test_decimation_is_the_same_however_the_stream_is_cut():
    t = np.arange(1, 5001) * 1e-3
    whole, _ = scene_frame_indices(t, 30.0, -1)
    assert len(whole) == len({k * 30 // 1000 for k in range(1, 5001)})
    for cut in ([1], [7, 400, 401, 2999], [100 * k for k in range(1, 50)]):
        got, slot = [], -1
        for lo, hi in zip([0, *cut], [*cut, len(t)]):
            idx, slot = scene_frame_indices(t[lo:hi], 30.0, slot)
            got += (idx + lo).tolist()
        assert got == whole.tolist()


def test_decimation_restarts_after_a_reset():
    t = np.r_[np.arange(1, 101) * 1e-3, np.arange(1, 101) * 1e-3]  # the simulator was reset at step 100
    idx, _ = scene_frame_indices(t, 30.0, -1)
    assert 100 in idx.tolist()
    assert len(idx) == 2 * len({k * 30 // 1000 for k in range(1, 101)})


def test_arrow_scale_and_colour_are_monotonic_in_the_force():
    f = np.array([0.0, 0.5, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5])
    length = arrow_length_m(f, 0.005)
    assert length[0] == 0 and np.all(np.diff(length) > 0)
    assert arrow_length_m(99.0 * FORCE_REF_N, 0.005) == pytest.approx(0.010)  # 2 r_R at 99 N
    rgba = color_by_magnitude(f).astype(int)
    assert rgba.shape == (8, 4) and np.all(rgba[:, 3] == 255)
    assert tuple(rgba[-1, :3]) == (220, 40, 30) and tuple(rgba[0, :3]) == (40, 80, 220)
    # log scale from 0.1 N to 10 kN: the geometric middle, 10^1.5 N, is the middle stop (green)
    assert tuple(color_by_magnitude(np.array([10 ** 1.5]))[0, :3]) == (60, 200, 60)


def _views(bp) -> list[tuple[str, str]]:
    """(view class, name) of every view in a blueprint, depth first."""
    out = []

    def walk(node):
        for child in getattr(node, "contents", None) or []:
            walk(child)
        if hasattr(node, "class_identifier"):
            out.append((node.class_identifier, str(node.name)))

    walk(bp.root_container)
    return out


def test_blueprint_has_heat_maps_only_for_per_tooth_layouts_and_no_empty_plots():
    fu = Simulator(preset("s30"), "fu2018").layout
    jones = Simulator(preset("s30"), "jones2016").layout
    all_scalars = ["time_s", "nut_position_m", "nut_force_n", "load_force_n", "screw_speed_rad_s",
                   "screw_torque_nm", "speed_ratio", "efficiency", "slip_speed_m_s", "power_in_w"]
    fu_views = _views(default_blueprint(all_scalars, fu, eye_distance_m=0.1))
    assert sum(c == "Tensor" for c, _ in fu_views) == 2
    assert ("3D", "PRSM") in fu_views
    assert sum(c == "Tensor" for c, _ in _views(default_blueprint(all_scalars, jones))) == 0
    few = _views(default_blueprint(["time_s", "nut_position_m", "screw_torque_nm"], InternalLayout(blocks=()),
                                   scene=False))
    assert [name for c, name in few if c == "TimeSeries"] == ["Nut position [m]", "Screw torque [N·m]"]
    assert not any(c == "3D" for c, _ in few)


def test_ideal_model_draws_motion_without_forces(tmp_path):
    """The ideal model has no internal loads: screw, nut, carrier and rollers move; nothing else is drawn."""
    path = tmp_path / "ideal.rrd"
    params = preset("s30")
    sim = Simulator(params, "ideal")
    sink = RerunSink("save", str(path), params, sim.layout, "ideal")
    for _ in range(200):
        sink.submit(sim.step(1.0, 100.0))
    sink.close()
    assert rrd_verify(path).returncode == 0
    rows = rrd_rows(path)
    assert rows[("/world/nut/carrier", "Transform3D:quaternion")] == 7
    ents = entities(rows)
    assert not any(e.startswith(("/world/nut/carrier/forces", "/loads", "/series/per_roller")) for e in ents)
