"""`jones2016` against the seed paper (Jones, Velinsky, Lasky 2016) and against closed forms."""

import math

import numpy as np
import pytest

from prsm_sim import Simulator, preset
from prsm_sim.models.jones2016 import Jones2016, input_matrix, mass_matrix, steady_state


def test_steady_ratio_is_the_seeds_2669_with_exact_contact():
    # Jones 2016 eq. (42): ω_S/ω_C = 2.669 for the worked example (preset read as diameters, docs/model.md §1)
    ss = steady_state(preset("jones2016"))
    assert ss["speed_ratio_screw_over_carrier"] == pytest.approx(2.669, abs=0.001)
    assert ss["screw_speed_rad_s"] == 1.0


def test_steady_ratio_is_kinematic_on_the_line_of_centres():
    # docs/model.md §4.1: with line-of-centres slip the steady ratio is exactly the kinematic 2(n−1)/(n−2)
    p = preset("jones2016").with_overrides({"friction.contact_evaluation": "line_of_centres"})
    assert steady_state(p)["speed_ratio_screw_over_carrier"] == pytest.approx(8 / 3, abs=1e-4)


@pytest.mark.parametrize("c,load,torque", [(5.0, 0.0, 0.5), (25.0, 100.0, 0.2), (400.0, 5000.0, 30.0)])
def test_steady_ratio_is_independent_of_c_load_and_torque(c, load, torque):
    # docs/model.md §4.1: the steady state minimises Σ|v_s|² over ω_C; c, F_out and M_in drop out
    p = preset("jones2016").with_overrides({"friction.viscous_n_s_m": c})
    ss = steady_state(p, torque_nm=torque, load_n=load)
    assert ss["speed_ratio_screw_over_carrier"] == pytest.approx(2.669025, abs=1e-6)


@pytest.mark.parametrize("evaluation", ["exact", "line_of_centres"])
def test_closed_form_equals_long_run_simulation(evaluation):
    # seed eqs. (37)–(41): the steady state the dynamics settle to
    p = preset("jones2016").with_overrides({"friction.contact_evaluation": evaluation})
    ss = steady_state(p)
    tr = Simulator(p, "jones2016", 1e-3).run(np.full(8000, ss["torque_nm"]), p.loads.nut_load_n)  # 8 s ≫ τ_S
    assert tr["screw_speed_rad_s"][-1] == pytest.approx(ss["screw_speed_rad_s"], rel=1e-6)
    assert tr["carrier_speed_rad_s"][-1] == pytest.approx(ss["carrier_speed_rad_s"], rel=1e-6)


def test_seed_torque_for_one_rad_per_s():
    # docs/model.md §4.1: the torque that holds the seed example at ω_S = 1 rad/s is 0.0922 N·m at the
    # exact contact (4 digits given), which the rigid-carrier estimate F_out L/2π + c N_R N_T (L/(2π sin β))² ω_S
    # approximates (it leaves out the carrier's share of the slip: measured 4.5e-4 relative)
    p = preset("jones2016")
    g = p.geometry
    ss = steady_state(p)
    assert ss["torque_nm"] == pytest.approx(0.0922, abs=5e-5)
    estimate = 100 * g.lead_per_rad_m + 25 * 400 * (g.lead_per_rad_m / math.sin(g.flank_angle_rad)) ** 2
    assert ss["torque_nm"] == pytest.approx(estimate, rel=1e-3)
    # power balance in the steady state (no kinetic change): M_in ω_S = F_out v_N + c N_R N_T |v_s|²
    dissipated = 25.0 * g.n_rollers * g.n_teeth * ss["slip_speed_m_s"] ** 2
    assert ss["torque_nm"] * ss["screw_speed_rad_s"] == pytest.approx(100 * ss["nut_velocity_m_s"] + dissipated, rel=1e-12)


def test_transient_takes_about_02_s():
    # Jones 2016 Fig. 5 / text: "steady state is reached in approximately 0.2 s"; docs/model.md §4.1 gives the
    # screw time constant τ_S = J_S / (c N_R N_T (L/(2π sin β))²); the simulated 63 % rise time must match it
    p = preset("jones2016")
    g = p.geometry
    ss = steady_state(p)
    tr = Simulator(p, "jones2016", 1e-4).run(np.full(10000, ss["torque_nm"]), 100.0)
    w = tr["screw_speed_rad_s"]
    t63 = tr["time_s"][np.argmax(w >= (1 - math.exp(-1)) * ss["screw_speed_rad_s"])]
    tau_s = mass_matrix(p)[0, 0] / (25 * 400 * (g.lead_per_rad_m / math.sin(g.flank_angle_rad)) ** 2)
    assert t63 == pytest.approx(tau_s, rel=0.02)
    assert 0.13 < t63 < 0.25
    # and the carrier mode is stiff (~10⁻⁵ s), which is why the step is exact ZOH
    m = Jones2016(p, 1e-3)
    tau_c = m.M[1, 1] / m.C[1, 1]
    assert tau_c < 1e-4


def test_energy_balance_over_a_run():
    # docs/model.md §5 item 5: input work = output work + ΔT + dissipated work; the step's dissipated
    # work is integrated in closed form, so the ledger closes to rounding (measured 3.7e-13 of W_in)
    p = preset("jones2016")
    sim = Simulator(p, "jones2016", 1e-3)
    tau = 0.2 * np.sin(np.linspace(0, 20, 4000)) + 0.05
    tr = sim.run(tau, 100.0)
    s = tr.final_state
    u = np.array([s.screw_speed_rad_s, s.carrier_speed_rad_s])
    kinetic = 0.5 * u @ mass_matrix(p) @ u
    residual = (s.work_in_j - s.work_out_j - s.dissipated_j - kinetic) / abs(s.work_in_j)
    print(f"jones2016 energy ledger residual: {residual:.1e} of W_in")
    assert abs(residual) < 1e-11
    # the dissipated work is the friction integral itself, c Σ|v_s|² dt: against the rectangle rule on
    # the step-end slip speeds, whose own error at 1 ms is O(h) (measured 2.5e-5 relative)
    slip = tr["slip_speed_m_s"]
    quad = np.sum(25.0 * 400 * slip**2) * 1e-3
    assert s.dissipated_j == pytest.approx(quad, rel=1e-4)


def modal_zoh_reference(M, C, B, inputs, h):
    """Exact solution of M q̈ + C q̇ = B u with u held over each step of length h, in closed form on
    the modes of the generalised symmetric problem C v = λ M v (scipy.linalg.eigh; Vᵀ M V = I, so
    each mode obeys η̈ + λ η̇ = g with g = Vᵀ B u constant over the step):
        η̇(h) = η̇₀ e^{−λh} + g (1 − e^{−λh})/λ,   η(h) = η₀ + η̇₀ (1 − e^{−λh})/λ + g (λh − (1 − e^{−λh}))/λ².
    A different route from the model's (Van Loan's augmented matrix exponential): the same
    equations, no shared code. Returns the states (q, q̇) after each step, shape (n, 4)."""
    from scipy.linalg import eigh
    lam, V = eigh(C, M)
    one_minus = -np.expm1(-lam * h)  # 1 − e^{−λh}, accurate for the slow screw mode (λh ≈ 7e-3)
    eta, deta, out = np.zeros(2), np.zeros(2), []
    for u in inputs:
        g = V.T @ B @ u
        eta = eta + deta * one_minus / lam + g * (lam * h - one_minus) / lam**2
        deta = deta * np.exp(-lam * h) + g * one_minus / lam
        out.append(np.concatenate([V @ eta, V @ deta]))
    return np.array(out)


def test_zoh_step_matches_an_exact_modal_reference_solution():
    # the model's ZOH step must equal the exact piecewise-constant-input solution (above) to rounding;
    # (2000 steps of a varying torque, the screw and carrier angles and speeds and the nut position)
    p = preset("jones2016")
    m = Jones2016(p, 1e-3)
    torque = 0.3 * np.sin(7 * np.arange(2000) * 1e-3)
    tr = Simulator(p, "jones2016", 1e-3).run(torque, 100.0)
    ref = modal_zoh_reference(mass_matrix(p), m.C, input_matrix(p), [np.array([t, 100.0]) for t in torque], 1e-3)
    worst = 0.0
    for k, name in enumerate(("screw_angle_rad", "carrier_angle_rad", "screw_speed_rad_s", "carrier_speed_rad_s")):
        scale = np.max(np.abs(ref[:, k]))
        worst = max(worst, np.max(np.abs(tr[name] - ref[:, k])) / scale)
    nut = ref[:, 0] * p.geometry.lead_per_rad_m
    worst = max(worst, np.max(np.abs(tr["nut_position_m"] - nut)) / np.max(np.abs(nut)))
    print(f"jones2016 ZOH vs modal reference: worst error {worst:.1e} of each state's range")  # measured 2.7e-13
    assert worst < 1e-11


def test_batch_run_equals_stepping():
    p = preset("jones2016")
    tau = np.linspace(0, 0.3, 200)
    a = Simulator(p, "jones2016", 1e-3).run(tau, 50.0)
    sim = Simulator(p, "jones2016", 1e-3)
    rows = [sim.step(t, 50.0) for t in tau]
    for name in ("screw_angle_rad", "carrier_speed_rad_s", "nut_force_n", "power_dissipated_w", "efficiency"):
        np.testing.assert_allclose(a[name], [getattr(r, name) for r in rows], rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(a.internal, np.array([r.internal for r in rows]), rtol=1e-9, atol=1e-13)
