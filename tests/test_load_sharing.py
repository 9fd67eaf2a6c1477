"""Static load distribution and axial stiffness (prsm_sim.physics.load_sharing), docs/model.md §4.3.

Oracles: the continuous threaded-joint solutions (Sopwith 1948; Stoeckly & Macke 1952) for linear
tooth springs, the two-Hertz-spring preload relations (lift-off at 2^(3/2) P₀, zero-load stiffness
3P₀/δ₀), the Hertz law K ∝ Q^(1/3), EA/ℓ of the shaft, and the catalogue order of nut stiffness.
"""

import math

import numpy as np
import pytest

from prsm_sim.errors import ParamError
from prsm_sim.physics import load_sharing as L
from prsm_sim.presets import preset

N, P = 30, 1e-3
EA1, EA2 = 1.18e8, 3.9e8  # s30-like screw root and nut body sections, N
LAM_L = 2.0  # λ ℓ_e: a clearly non-uniform distribution
ELL = N * P
K_LEN = (LAM_L / ELL) ** 2 / (1 / EA1 + 1 / EA2)  # thread stiffness per unit length, N/m²


def _linear_joint(mounting: str) -> L.Joint:
    row = L.ToothRow(n_rollers=1, hertz_coefficient=0.0, tooth_compliance_m_per_n=1 / (K_LEN * P))
    return L.Joint(row, N, P, EA1, EA2, mounting)


def _cell_loads_closed_form(mounting: str, f: float) -> np.ndarray:
    """∫ q dx over each tooth's pitch cell, q from docs/model.md §4.3 (x from the free end)."""
    lam = LAM_L / ELL
    xa, xb = np.arange(N) * P, np.arange(1, N + 1) * P
    if mounting == "same_end":
        return f * (np.sinh(lam * xb) - np.sinh(lam * xa)) / math.sinh(lam * ELL)
    b = -K_LEN * f / (lam * EA2)  # q'(0) = −k F/(E₂A₂)
    a = (K_LEN * f / (lam * EA1) - b * math.cosh(lam * ELL)) / math.sinh(lam * ELL)  # q'(ℓ) = k F/(E₁A₁)
    return (a * (np.sinh(lam * xb) - np.sinh(lam * xa)) + b * (np.cosh(lam * xb) - np.cosh(lam * xa))) / lam


@pytest.mark.parametrize("mounting", ["same_end", "opposite_end"])
def test_linear_springs_match_continuous_closed_forms(mounting):
    """Sopwith 1948 / Stoeckly & Macke 1952: cosh (same end) and U-shaped (opposite ends) distributions.

    The issue asks for 2 %; the discrete model with N_T = 30 teeth is within 0.02 % of the peak load
    (seen), so the test holds it to 0.2 %.
    """
    f = 20e3
    d = L.solve_distribution(_linear_joint(mounting), f)
    ref = _cell_loads_closed_form(mounting, f)
    assert ref.sum() == pytest.approx(f, rel=1e-12)
    assert d.row_loads_n.sum() == pytest.approx(f, rel=1e-12)
    assert np.max(np.abs(d.row_loads_n - ref)) / ref.max() < 2e-3
    if mounting == "same_end":  # load moves toward the loaded end as cosh λx says
        assert np.all(np.diff(d.row_loads_n) > 0)
        assert d.row_loads_n[-1] / d.row_loads_n[0] == pytest.approx(ref[-1] / ref[0], rel=0.02)
    else:  # U-shape: both ends above the middle
        mid = d.row_loads_n[N // 2]
        assert d.row_loads_n[0] > mid and d.row_loads_n[-1] > mid


def test_linear_joint_stiffness_matches_closed_form():
    """Same-end joint: δ(ℓ) = q(ℓ)/k = F λ coth(λℓ)/k, so K = k tanh(λℓ)/λ (plus the half-pitch end segments)."""
    lam = LAM_L / ELL
    k_cf = K_LEN * math.tanh(LAM_L) / lam
    d = L.solve_distribution(_linear_joint("same_end"), 10e3)
    assert d.stiffness_n_per_m == pytest.approx(k_cf, rel=2e-3)  # seen: 0.06 %
    assert d.approach_m * d.stiffness_n_per_m == pytest.approx(10e3, rel=1e-9)  # linear: δ = F/K


def test_stiff_bodies_share_uniformly_and_shares_sum_to_teeth():
    """docs/model.md §5 item 9: row loads sum to F and ζ_T sums to N_T; with rigid bodies ζ_T = 1."""
    p = preset("s30")
    j = L.joint_from_params(p)
    rigid = L.Joint(j.row, j.n_teeth, j.pitch_m, 1e30, 1e30, "same_end")
    d = L.solve_distribution(rigid, 20e3)
    assert d.shares == pytest.approx(np.ones(j.n_teeth), abs=1e-9)
    real = L.solve_distribution(j, 20e3)
    assert real.shares.sum() == pytest.approx(j.n_teeth, rel=1e-12)
    assert np.all(np.diff(real.shares) > 0)  # the finite shaft pushes load toward the loaded end


def _hertz_side(preload: float) -> L.Side:
    row = L.ToothRow(n_rollers=10, hertz_coefficient=6.6e-7, tooth_compliance_m_per_n=0.0)
    joint = L.Joint(row, 30, 1e-3, 1e30, 1e30, "same_end")
    return L.Side.tabulate(joint, 20 * preload, n=200)


def test_preloaded_hertz_pair_lifts_off_at_2_83_preload():
    """docs/model.md §4.3: two Hertz springs preloaded by P₀ lift off at 2^(3/2) P₀ (within 2 %);
    at zero load the pair's stiffness is 3P₀/δ₀, twice one side's at P₀; at lift-off it is one side's."""
    p0 = 2000.0
    side = _hertz_side(p0)
    lift = 2**1.5 * p0
    assert L.preloaded_pair(side, side, p0, 0.98 * lift).unloaded_side_n > 0
    assert L.preloaded_pair(side, side, p0, 1.02 * lift).unloaded_side_n == 0.0
    # sharper: the unloaded side's load over the bracket extrapolates to zero at 2^(3/2) P₀
    loads = np.linspace(0.9, 0.999, 12) * lift
    qb = np.array([L.preloaded_pair(side, side, p0, f).unloaded_side_n for f in loads])
    # Q_B ∝ (δ₀ − x)^(3/2): Q_B^(2/3) is smooth to zero; fit and find its root
    root = np.roots(np.polyfit(loads, qb ** (2 / 3), 2))
    root = root[np.argmin(np.abs(root - lift))].real
    assert root == pytest.approx(lift, rel=0.02)
    d0 = side.approach_m(p0)
    k0 = L.preloaded_pair(side, side, p0, 0.0).stiffness_n_per_m
    assert k0 == pytest.approx(3 * p0 / d0, rel=1e-6)
    single = L.solve_distribution(side.joint, lift).stiffness_n_per_m
    assert L.preloaded_pair(side, side, p0, 1.001 * lift).stiffness_n_per_m == pytest.approx(single, rel=2e-3)
    ks = [L.preloaded_pair(side, side, p0, f).stiffness_n_per_m for f in np.linspace(0, 0.99 * lift, 8)]
    assert np.all(np.diff(ks) < 0) and ks[-1] < ks[0]  # highest at zero load


def test_unpreloaded_stiffness_rises_no_faster_than_hertz():
    """docs/model.md §4.3: without preload K rises with load, never faster than a contact alone (K ∝ F^(1/3))."""
    ch = L.AxialChain(preset("s30"))
    loads = np.geomspace(200, 60e3, 12)
    k = np.array([ch.at(f).stiffness_n_per_m for f in loads])
    assert np.all(np.diff(k) > 0)
    assert np.all(k[1:] / k[:-1] <= (loads[1:] / loads[:-1]) ** (1 / 3) * (1 + 1e-9))


def test_s30_stiffness_in_catalogue_range():
    """s30 at 20 kN: nut (contacts, teeth, nut body) of order 1 kN/µm (docs/model.md §4.3: contact-only about
    2.9 kN/µm, real nuts 2–3 times softer; catalogue nut stiffnesses of 30 mm roller screws lie between
    about 0.5 and 3 kN/µm); the shaft adds πd²E/(4ℓ) ≈ 0.8 kN/µm at d_root = 27 mm, ℓ = 150 mm."""
    p = preset("s30")
    pt = L.AxialChain(p).at(20e3)
    assert 0.5e9 < pt.nut_stiffness_n_per_m < 3e9
    assert pt.shaft_stiffness_n_per_m == pytest.approx(math.pi * 0.027**2 * 206e9 / (4 * 0.15), rel=1e-12)
    assert pt.shaft_stiffness_n_per_m == pytest.approx(0.8e9, rel=0.03)
    # contacts alone, uniform sharing: per contact K_ax = 3f/(2δ_ax) in series over both sides
    scr, nut = L.thread_contacts(p)
    f = 20e3 / (p.geometry.n_rollers * p.geometry.n_teeth)
    k_contact = 1 / sum(1 / (1.5 * f / float(s.axial_approach_m(f))) for s in (scr, nut))
    assert k_contact * p.geometry.n_rollers * p.geometry.n_teeth == pytest.approx(2.9e9, rel=0.15)


def test_preloaded_s30_chain_lifts_off_and_is_stiffest_at_zero_load():
    """A preloaded s30 (oversize rollers): stiffness highest at zero load, falling to one side's after lift-off."""
    p = preset("s30").with_overrides({"elastic.preload_n": 3000.0, "elastic.preload_kind": "oversize_rollers"})
    ch = L.AxialChain(p)
    k = [ch.at(f).nut_stiffness_n_per_m for f in (0.0, 3000.0, 6000.0)]
    assert k[0] > k[1] > k[2]
    after = ch.at(4 * 3000.0)
    assert after.unloaded_side_n == 0.0
    assert after.nut_stiffness_n_per_m == pytest.approx(L.solve_distribution(ch.joint, 12e3).stiffness_n_per_m, rel=1e-9)


@pytest.mark.parametrize("key,value,field", [
    ("elastic.axial_clearance_m", -1e-6, "elastic.axial_clearance_m"),
    ("elastic.housing_stiffness_n_per_m", 0.0, "elastic.housing_stiffness_n_per_m"),
    ("elastic.housing_stiffness_n_per_m", float("nan"), "elastic.housing_stiffness_n_per_m"),
    ("material.youngs_modulus_pa", 0.0, "material.youngs_modulus_pa"),
    ("elastic.mounting", "sideways", "elastic.mounting"),
])
def test_bad_elastic_parameters_name_the_field(key, value, field):
    with pytest.raises(ParamError, match=field.replace(".", r"\.")):
        preset("s30").with_overrides({key: value})


def test_preload_beyond_static_rating_is_refused():
    p = preset("s30")
    c0 = p.ratings.static_load_rating_n
    with pytest.raises(ParamError, match=r"elastic\.preload_n .*static load rating"):
        p.with_overrides({"elastic.preload_n": 1.1 * c0, "elastic.preload_kind": "double_nut"})


def test_iso76_point_contact_rating_reaches_4_2_gpa():
    """ISO 76 point-contact criterion: at that load, uniformly shared contacts peak at 4.2 GPa (the most
    loaded side). The parameter set's C_0a is the flank-limited line rating (test_ratings.py)."""
    p = preset("s30")
    g = p.geometry
    c0 = L.iso76_static_rating_n(p)
    pk = [float(s.hertz.max_pressure_pa(c0 / (g.n_rollers * g.n_teeth) / s.axial_factor)) for s in L.thread_contacts(p)]
    assert max(pk) == pytest.approx(4.2e9, rel=1e-9)
