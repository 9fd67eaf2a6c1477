"""Hertz point contact (prsm_sim.physics.hertz) against closed forms and an independent elasticity integral.

Oracles: Johnson, *Contact Mechanics* (1985) §4.2 (sphere on sphere, crossed cylinders) and §3.6
(the surface displacement of a half-space under a Hertz ellipsoidal pressure, integrated here
numerically from Boussinesq's point-load solution, Johnson eq. 3.20: u = (1 − ν²)/(πE) ∫∫ p/s dA);
Harris & Kotzalas ch. 6 (the F(ρ)–κ relation, its limits); Hamrock & Brewe 1983 (their stated
accuracy of the simplified κ, 𝓔, 𝓕); the published table of Hertz coefficients against
cos τ = F(ρ) after Brändlein et al., *Die Wälzlagerpraxis* (1998); docs/model.md §4.3
(K(2Q)/K(Q) = 2^(1/3)).
"""

import math

import numpy as np
import pytest

from prsm_sim.physics import hertz as H
from prsm_sim.presets import preset

E, NU = 206e9, 0.3  # docs/model.md §1 steel
CE = H.elastic_constant(E, NU)


def _displacement_at(c: H.HertzContact, q: float, x0: float, y0: float, n_theta: int = 2000) -> float:
    """Combined normal displacement at (x0, y0) under the Hertz pressure p0 √(1 − x²/a² − y²/b²).

    u = (C_E/π) ∫∫ p/s dA in polar coordinates about the point: the radial integral of the
    semi-ellipse-shaped pressure along each ray is done in closed form, the angle by the trapezoid
    rule (periodic, smooth integrand: exponential convergence).
    """
    a, b = (float(v) for v in c.semi_axes_m(q))
    p0 = 3 * q / (2 * math.pi * a * b)
    th = np.linspace(0, 2 * math.pi, n_theta, endpoint=False)
    cs, sn = np.cos(th), np.sin(th)
    qa = cs**2 / a**2 + sn**2 / b**2
    qb = 2 * (x0 * cs / a**2 + y0 * sn / b**2)
    qc = 1 - x0**2 / a**2 - y0**2 / b**2
    disc = np.sqrt(qb**2 + 4 * qa * qc)
    r1, r2 = (-qb - disc) / (2 * qa), (-qb + disc) / (2 * qa)
    m, h = (r1 + r2) / 2, (r2 - r1) / 2
    # ∫_0^{r2} √(qa (r2 − r)(r − r1)) dr = √qa [F(h) − F(−m)], F(t) = t√(h²−t²)/2 + h² asin(t/h)/2
    prim = lambda t: t * np.sqrt(np.maximum(h**2 - t**2, 0)) / 2 + h**2 * np.arcsin(np.clip(t / h, -1, 1)) / 2
    radial = np.sqrt(qa) * (prim(h) - prim(-m))
    return c.elastic_constant_per_pa / math.pi * p0 * radial.mean() * 2 * math.pi


def test_two_equal_spheres_match_johnson():
    """Johnson §4.2: equal spheres of radius r, R = r/2: a = (3QR/4E*)^(1/3), δ = a²/R, p0 = 3Q/(2πa²)."""
    r, q = 5e-3, 200.0
    c = H.point_contact(4 / r, 0.0, CE)
    e_star, r_eff = 1 / CE, r / 2
    a = (3 * q * r_eff / (4 * e_star)) ** (1 / 3)
    aa, bb = c.semi_axes_m(q)
    assert aa == pytest.approx(a, rel=1e-12) and bb == pytest.approx(a, rel=1e-12)
    assert c.approach_m(q) == pytest.approx((9 * q**2 / (8 * r * e_star**2)) ** (1 / 3), rel=1e-12)  # docs/model.md §4.3
    assert c.approach_m(q) == pytest.approx(a**2 / r_eff, rel=1e-12)
    assert c.max_pressure_pa(q) == pytest.approx(3 * q / (2 * math.pi * a**2), rel=1e-12)


def test_crossed_equal_cylinders_are_a_sphere_on_a_plane():
    """Johnson §4.2: two equal cylinders crossed at 90° touch like a sphere of the same radius on a plane.

    Curvatures from the parametrisations (second fundamental form), not typed in.
    """
    r, q = 4e-3, 50.0
    cyl1 = lambda u, v: np.array([r * math.sin(u), v, r * math.cos(u) - r])      # axis along y, top at 0
    cyl2 = lambda u, v: np.array([v, r * math.sin(u), -r * math.cos(u) + r])     # axis along x, bottom at 0
    k1, basis = H.curvature_tensor(cyl1, 0.0, 0.0, np.array([0, 0, 1.0]), 1e-3, 1e-3 * r)
    k2, _ = H.curvature_tensor(cyl2, 0.0, 0.0, np.array([0, 0, -1.0]), 1e-3, 1e-3 * r, basis)
    assert sorted(np.linalg.eigvalsh(k1)) == pytest.approx([0.0, 1 / r], abs=1e-6 / r)
    s, f, _ = H.relative_curvature(k1, k2)
    assert s == pytest.approx(2 / r, rel=1e-9) and f == pytest.approx(0.0, abs=1e-9)
    c = H.point_contact(s, f, CE)
    # a sphere of radius r on a plane: two principal curvatures 1/r, Σρ = 2/r
    sphere_on_plane = H.point_contact(2 / r, 0.0, CE)
    assert c.approach_m(q) == pytest.approx(sphere_on_plane.approach_m(q), rel=1e-9)
    a = (3 * q * r / (4 / CE)) ** (1 / 3)  # Johnson: R = r, a = (3QR/4E*)^(1/3)
    assert c.semi_axes_m(q)[0] == pytest.approx(a, rel=1e-9)


def test_curvature_of_a_sphere_against_a_plane():
    """Second fundamental form on a sphere of radius R: both principal curvatures 1/R (convex); a plane: 0."""
    rad = 7e-3
    sphere = lambda th, ph: rad * np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    th, ph = 0.7, 0.3
    k, basis = H.curvature_tensor(sphere, th, ph, sphere(th, ph), 1e-3, 1e-3)
    assert np.linalg.eigvalsh(k) == pytest.approx([1 / rad, 1 / rad], rel=1e-8)
    plane = lambda u, v: np.array([u, v, 0.0])
    kp, _ = H.curvature_tensor(plane, 0.2, 0.1, np.array([0, 0, -1.0]), 1e-3, 1e-3)
    assert np.abs(kp).max() < 1e-6
    # a concave surface seen from inside (the outward normal points to the centre) is negative
    kc, _ = H.curvature_tensor(sphere, th, ph, -sphere(th, ph), 1e-3, 1e-3)
    assert np.linalg.eigvalsh(kc) == pytest.approx([-1 / rad, -1 / rad], rel=1e-8)


@pytest.mark.parametrize("f_rho", [0.0, 0.15, 0.5, 0.8, 0.95])
def test_exact_solution_satisfies_elasticity(f_rho):
    """The Hertz formulas against an independent integral of the half-space response (Johnson §3.6, eq. 3.20).

    Integrating Boussinesq's kernel over the ellipsoidal pressure with the computed a, b, p0 must give
    the computed approach δ at the centre, and the gap profile A x², B y² (A, B the relative
    curvatures from Σρ and F(ρ)) inside the ellipse. The issue asks for 0.5 %; achieved ~1e-15, held to 1e-9.
    """
    s, q = 300.0, 94.0
    c = H.point_contact(s, f_rho, CE)
    u0 = _displacement_at(c, q, 0.0, 0.0)
    assert u0 == pytest.approx(float(c.approach_m(q)), rel=1e-9)
    a, b = (float(v) for v in c.semi_axes_m(q))
    A, B = s * (1 - f_rho) / 4, s * (1 + f_rho) / 4
    assert (u0 - _displacement_at(c, q, 0.6 * a, 0.0)) / (0.6 * a) ** 2 == pytest.approx(A, rel=1e-9)
    assert (u0 - _displacement_at(c, q, 0.0, 0.6 * b)) / (0.6 * b) ** 2 == pytest.approx(B, rel=1e-9)
    # and the pressure integrates to the load: ∫∫ p0 √(…) dA = (2/3) π a b p0
    assert 2 / 3 * math.pi * a * b * float(c.max_pressure_pa(q)) == pytest.approx(q, rel=1e-12)


def test_ellipticity_limits_and_inverse():
    """Harris ch. 6: F(ρ) = 0 ↔ κ = 1, 𝓔 = 𝓕 = π/2; F(ρ) → 1 as κ → ∞; the solver inverts the relation."""
    assert H.ellipticity(0.0) == pytest.approx((1.0, math.pi / 2, math.pi / 2))
    for f in (0.01, 0.3, 0.7, 0.9, 0.99, 0.999):
        k, _, _ = H.ellipticity(f)
        assert H.curvature_difference(k) == pytest.approx(f, abs=1e-13)
    assert H.curvature_difference(1e3) > 0.9999
    ks = [H.ellipticity(f)[0] for f in np.linspace(0, 0.99, 30)]
    assert np.all(np.diff(ks) > 0)
    with pytest.raises(ValueError, match="F\\(rho\\)"):
        H.ellipticity(1.0)


# Tabelle A.2 "Koeffizienten zur Hertz'schen Theorie (nach Brändlein et al. [1998])", p. 660 of
# Springer's appendix A "Erweiterungen der elementaren Festigkeitslehre": cos τ, ξ_H, χ_H, ς_H,
# all 38 rows as printed (ξ_H to 2 decimals, χ_H and ς_H to 3; decimal commas made points).
_BRAENDLEIN_TABLE = (
    (0.9990, 18.53, 0.185, 0.207), (0.9975, 13.15, 0.220, 0.266), (0.9950, 10.15, 0.251, 0.320),
    (0.9925, 8.68, 0.271, 0.356), (0.9900, 7.76, 0.287, 0.384), (0.9875, 7.13, 0.299, 0.407),
    (0.9850, 6.64, 0.310, 0.427), (0.9825, 6.26, 0.319, 0.444), (0.9800, 5.94, 0.328, 0.459),
    (0.9775, 5.67, 0.336, 0.473), (0.9750, 5.44, 0.343, 0.486), (0.9700, 5.05, 0.357, 0.509),
    (0.9600, 4.51, 0.378, 0.546), (0.9500, 4.12, 0.396, 0.577), (0.9400, 3.83, 0.412, 0.603),
    (0.9300, 3.59, 0.426, 0.626), (0.9200, 3.40, 0.438, 0.646), (0.9100, 3.23, 0.450, 0.664),
    (0.9000, 3.09, 0.461, 0.680), (0.875, 2.82, 0.485, 0.715), (0.850, 2.60, 0.507, 0.745),
    (0.800, 2.30, 0.544, 0.792), (0.750, 2.07, 0.577, 0.829), (0.700, 1.91, 0.607, 0.859),
    (0.650, 1.77, 0.637, 0.884), (0.600, 1.66, 0.664, 0.904), (0.550, 1.57, 0.690, 0.922),
    (0.500, 1.48, 0.718, 0.938), (0.450, 1.41, 0.745, 0.951), (0.400, 1.35, 0.771, 0.962),
    (0.350, 1.29, 0.796, 0.971), (0.300, 1.24, 0.824, 0.979), (0.250, 1.19, 0.850, 0.986),
    (0.200, 1.15, 0.879, 0.991), (0.150, 1.11, 0.908, 0.994), (0.100, 1.07, 0.938, 0.997),
    (0.050, 1.03, 0.969, 0.999), (0.000, 1.00, 1.000, 1.000),
)


def test_exact_solution_matches_braendlein_table():
    """The exact κ, 𝓔, 𝓕 against the published Hertz coefficients (Brändlein et al. 1998, as Tabelle A.2).

    The table gives, against cos τ = F(ρ) (its eq. A.1 is our curvature difference), Hertz's
    dimensionless semi-axes ξ_H = a/X, χ_H = b/X and approach ς_H = δ/(X² Σρ/2), scaled by the
    circular contact of the same curvature sum, X = (3 Q C_E / (2 Σρ))^(1/3): that is the scale
    its cos τ = 0 row (1 / 1 / 1, Johnson's sphere, tested above) fixes. They are Harris's a*, b*, δ*:
    (2κ²𝓔/π)^(1/3), (2𝓔/(πκ))^(1/3), (2𝓕/π)(π/(2κ²𝓔))^(1/3), so κ = ξ_H/χ_H, 𝓔 = πξ_Hχ_H²/2,
    𝓕 = πξ_Hς_H/2. Checked through the contact itself (semi_axes_m, approach_m) at every row.

    Tolerance: 0.5 % plus half a unit in the table's last printed digit (its rounding). Seen over
    the 114 entries: ξ_H ≤ 0.41 %, χ_H ≤ 0.25 %, ς_H ≤ 0.53 % (the one entry past 0.5 % is
    ς_H = 0.207 at cos τ = 0.999, exact 0.2059: 1.1 units of its last digit); up to 1.8 units of
    the last digit elsewhere, so the table is not rounded from exact values everywhere.
    """
    sum_rho, q = 400.0, 100.0  # 1/m, N: any values, the coefficients are dimensionless
    x = (1.5 * q * CE / sum_rho) ** (1 / 3)
    last_digit = (0.01, 0.001, 0.001)  # ξ_H, χ_H, ς_H as printed
    for cos_tau, *printed in _BRAENDLEIN_TABLE:
        c = H.point_contact(sum_rho, cos_tau, CE)
        a, b = (float(v) for v in c.semi_axes_m(q))
        exact = (a / x, b / x, float(c.approach_m(q)) / (x**2 * sum_rho / 2))
        for got, want, unit in zip(exact, printed, last_digit):
            assert abs(got - want) <= 0.005 * want + 0.5 * unit, (cos_tau, got, want)


def test_hamrock_brewe_within_its_stated_accuracy():
    """Hamrock & Brewe 1983: the simplified κ, 𝓔, 𝓕 agree with the exact ones within a few per cent.

    Seen: κ ≤ 3.4 %, 𝓔 ≤ 1.7 %, 𝓕 ≤ 2.8 % over F(ρ) ∈ [0, 0.95]; the approach δ at thread-contact
    curvature ratios is 3.1–3.5 % off, which is why the hot path uses the exact coefficient (computed
    once per geometry) and not this form.
    """
    for f in np.linspace(0, 0.95, 40):
        ex, hb = np.array(H.ellipticity(f)), np.array(H.hamrock_brewe(f))
        err = np.abs(hb / ex - 1)
        assert err[0] < 0.035 and err[1] < 0.018 and err[2] < 0.029


def test_stiffness_scales_with_cube_root_of_load():
    """docs/model.md §4.3: δ ∝ Q^(2/3) ⇒ K = dQ/dδ = 3Q/(2δ) and K(2Q)/K(Q) = 2^(1/3)."""
    c = H.point_contact(330.0, 0.15, CE)
    q = 94.0
    assert c.stiffness_n_per_m(2 * q) / c.stiffness_n_per_m(q) == pytest.approx(2 ** (1 / 3), rel=1e-12)
    dq = 1e-4 * q
    k_fd = 2 * dq / (c.approach_m(q + dq) - c.approach_m(q - dq))
    assert c.stiffness_n_per_m(q) == pytest.approx(k_fd, rel=1e-7)
    assert c.load_n(c.approach_m(q)) == pytest.approx(q, rel=1e-12)
    assert c.load_n(-1e-6) == 0.0


def test_s30_thread_contacts_reference_magnitudes():
    """docs/model.md §4.3: s30 at 20 kN shared uniformly is ~94 N per contact and a peak pressure ~1.8 GPa.

    Principal curvatures at the solved contact: the screw flank's circumferential curvature is
    about sin β / r_S and the nut's about −sin β / r_N (concave), the roller's both about
    sin β / r_R (arc radius R_p = r_R / sin β about the roller axis), split slightly by the helix.
    """
    p = preset("s30")
    g = p.geometry
    sb = math.sin(g.flank_angle_rad)
    scr = H.thread_contact(g, "screw", CE)
    nut = H.thread_contact(g, "nut", CE)
    q_ax = 20e3 / (g.n_rollers * g.n_teeth)
    q = q_ax / scr.axial_factor
    assert q == pytest.approx(94.0, rel=0.01)
    assert float(scr.hertz.max_pressure_pa(q)) == pytest.approx(1.8e9, rel=0.05)
    assert max(scr.principal_curvatures_body_per_m) == pytest.approx(sb / g.screw_radius_m, rel=0.01)
    assert min(nut.principal_curvatures_body_per_m) == pytest.approx(-sb / g.nut_radius_m, rel=0.01)
    for k in scr.principal_curvatures_roller_per_m + nut.principal_curvatures_roller_per_m:
        assert k == pytest.approx(sb / g.roller_radius_m, rel=0.1)
    # the axial approach of a contact: δ/c_z with Q = f/c_z
    assert float(scr.axial_approach_m(q_ax)) == pytest.approx(float(scr.hertz.approach_m(q)) / scr.axial_factor, rel=1e-12)
