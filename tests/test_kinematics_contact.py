"""Kinematics (docs/model.md §2) and exact contact (docs/model.md §3), checked against closed forms."""

import math

import numpy as np
import pytest

from prsm_sim import Simulator, preset
from prsm_sim.physics.contact import contact_for, predicted_screw_offset_rad, solve_contact
from prsm_sim.physics.kinematics import (ideal_carrier_ratio, ideal_speed_ratio, roller_axial_velocity_z, roller_spin,
                                 sliding_velocity)

PRESETS = ("jones2016", "s30")


@pytest.mark.parametrize("name", PRESETS)
def test_lead_is_exact_whatever_the_carrier_does(name):
    # docs/model.md §2: engaging screw and nut gives v_N = −(L/2π) ω_S for any ω_C (Jones & Velinsky 2012)
    geo = preset(name).geometry
    rng = np.random.default_rng(1)
    for w_s, w_c in rng.normal(size=(20, 2)) * 50:
        v_r = roller_axial_velocity_z(geo, w_s, w_c)
        v_n_from_nut_side = v_r - geo.lead_per_rad_m * w_c - geo.pitch_m / (2 * math.pi) * roller_spin(geo, w_c)
        assert v_n_from_nut_side == pytest.approx(-geo.lead_per_rad_m * w_s, rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018"])
def test_simulated_nut_moves_one_lead_per_revolution(model):
    # docs/model.md §5 item 1: Δz_N / Δθ_S = L/2π exactly, any slip
    p = preset("s30")
    sim = Simulator(p, model, 1e-3)
    tr = sim.run(0.8 * np.sin(np.linspace(0, 6, 300)), 500.0)
    dz, dth = np.diff(tr["nut_position_m"]), np.diff(tr["screw_angle_rad"])
    moving = np.abs(dth) > 1e-9
    np.testing.assert_allclose(dz[moving] / dth[moving], p.geometry.lead_per_rad_m, rtol=1e-9)


@pytest.mark.parametrize("name", PRESETS)
def test_kinematic_ratio_is_pure_rolling_at_both_pitch_points(name):
    # docs/model.md §2: ω_S/ω_C = 2(r_S + r_R)/r_S and ω_r = −(r_N/r_R) ω_C make the in-plane velocities of
    # roller and body equal at both pitch points (an independent check by point velocities)
    geo = preset(name).geometry
    assert ideal_speed_ratio(geo) == pytest.approx(2 * (geo.screw_radius_m + geo.roller_radius_m) / geo.screw_radius_m)
    assert ideal_speed_ratio(geo) == pytest.approx(2 * (geo.starts - 1) / (geo.starts - 2))  # standard design
    assert roller_spin(geo, 1.0) == pytest.approx(-geo.nut_radius_m / geo.roller_radius_m)
    w_s, w_c = 1.0, ideal_carrier_ratio(geo)
    for side, r in (("screw", geo.screw_radius_m), ("nut", geo.nut_radius_m)):
        v = sliding_velocity(geo, side, np.array([r, 0.0, 0.0]), w_s, w_c)
        assert abs(v[1]) < 1e-12  # circumferential: no slip at the pitch point


def test_seed_literal_radii_give_2513_not_2667():
    # docs/model.md §1: r_S = 19.5 mm, r_R = 5 mm give an ideal ratio of 2.513
    assert ideal_speed_ratio(preset("jones2016_literal").geometry) == pytest.approx(2.513, abs=5e-4)


@pytest.mark.parametrize("name", PRESETS)
@pytest.mark.parametrize("load_sign", [1, -1])
def test_exact_contact_facts(name, load_sign):
    geo = preset(name).geometry
    cs, cn = solve_contact(geo, "screw", load_sign), solve_contact(geo, "nut", load_sign)
    # docs/model.md §3: screw–roller offset ≈ (λ_S − λ_R)/tan β, toward −φ for this flank pair
    assert cs.body_angle_rad == pytest.approx(-load_sign * predicted_screw_offset_rad(geo), rel=0.01)
    # nut–roller (standard design): on the line of centres at the pitch radii
    assert abs(cn.body_angle_rad) < 1e-9 and cn.body_radius_m == pytest.approx(geo.nut_radius_m, rel=1e-9)
    # contact radii differ from pitch radii by a few µm only
    assert abs(cs.body_radius_m - geo.screw_radius_m) < 3e-5
    # sliding at ideal kinematics: |v_s| = |v_N| / sin β on the screw side, ≈ 0 on the nut side
    u = np.array([1.0, ideal_carrier_ratio(geo)])
    v_n = geo.lead_per_rad_m
    assert np.linalg.norm(cs.sliding_matrix(geo) @ u) == pytest.approx(v_n / math.sin(geo.flank_angle_rad), rel=0.005)
    assert np.linalg.norm(cn.sliding_matrix(geo) @ u) < 1e-9 * v_n


@pytest.mark.parametrize("name", PRESETS)
def test_relative_velocity_is_tangent_at_the_exact_contact_for_any_speeds(name):
    # bodies that stay in contact slide in the common tangent plane: the exact point and normal are
    # one consistent solution (docs/model.md §3: mixing point and normal breaks energy conservation)
    geo = preset(name).geometry
    rng = np.random.default_rng(2)
    for side in ("screw", "nut"):
        c = solve_contact(geo, side, 1)
        for u in rng.normal(size=(10, 2)):
            v = c.sliding_matrix(geo) @ u
            assert abs(v @ c.normal_on_roller) < 1e-12 * max(1.0, np.linalg.norm(v))
    # the line-of-centres point is not a true contact: its relative velocity has a normal part
    lc = contact_for(geo, "screw", "line_of_centres")
    assert abs(lc.sliding_matrix(geo) @ np.array([1.0, 0.3]) @ lc.normal_on_roller) > 1e-6


def test_roller_is_squeezed_between_opposite_flanks():
    # Jones 2016 (loaded surfaces): the screw pushes the roller one way axially, the nut the other,
    # and their radial components oppose (the roller is clamped, the pins carry little)
    geo = preset("s30").geometry
    ns = solve_contact(geo, "screw", 1).normal_on_roller
    nn = solve_contact(geo, "nut", 1).normal_on_roller
    assert ns[2] < 0 < nn[2] and nn[0] < 0 < ns[0]
