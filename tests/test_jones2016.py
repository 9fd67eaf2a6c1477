"""`jones2016` against the seed paper (Jones, Velinsky, Lasky 2016) and against closed forms."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

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
    # docs/model.md §4.1: M_in ≈ F_out L/2π + c N_R N_T (L/(2π sin β))² ω_S ≈ 0.092 N·m
    p = preset("jones2016")
    g = p.geometry
    approx = 100 * g.lead_per_rad_m + 25 * 400 * (g.lead_per_rad_m / math.sin(g.flank_angle_rad)) ** 2
    assert approx == pytest.approx(0.092, abs=5e-4)
    assert steady_state(p)["torque_nm"] == pytest.approx(approx, rel=0.01)


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
    # docs/model.md §5 item 5: input work = output work + ΔT + dissipated work (within 0.1 %; here ~1e-7)
    p = preset("jones2016")
    sim = Simulator(p, "jones2016", 1e-3)
    tau = 0.2 * np.sin(np.linspace(0, 20, 4000)) + 0.05
    tr = sim.run(tau, 100.0)
    s = tr.final_state
    u = np.array([s.screw_speed_rad_s, s.carrier_speed_rad_s])
    kinetic = 0.5 * u @ mass_matrix(p) @ u
    assert s.work_in_j - s.work_out_j - s.dissipated_j - kinetic == pytest.approx(0.0, abs=1e-3 * abs(s.work_in_j))
    # the dissipated work is the friction integral itself, c Σ|v_s|² dt (checked against quadrature)
    slip = tr["slip_speed_m_s"]
    quad = np.sum(25.0 * 400 * slip**2) * 1e-3
    assert s.dissipated_j == pytest.approx(quad, rel=0.01)


def test_zoh_step_matches_a_tight_reference_solution():
    # the same equations integrated by Radau at rtol 1e-11: ≤ 0.1 % error in nut position and carrier speed
    p = preset("jones2016")
    m = Jones2016(p, 1e-3)
    Minv = np.linalg.inv(m.M)
    B = input_matrix(p)

    def torque(t):
        return 0.3 * math.sin(7 * math.floor(t / 1e-3) * 1e-3)

    def rhs(t, x):
        return np.concatenate([x[2:], Minv @ (-m.C @ x[2:] + B @ [torque(t), 100.0])])

    n = 500
    tr = Simulator(p, "jones2016", 1e-3).run([torque(k * 1e-3) for k in range(n)], 100.0)
    x = np.zeros(4)
    ref = []
    for k in range(n):
        x = solve_ivp(rhs, (k * 1e-3, (k + 1) * 1e-3), x, method="Radau", rtol=1e-11, atol=1e-14).y[:, -1]
        ref.append(x.copy())
    ref = np.array(ref)
    np.testing.assert_allclose(tr["nut_position_m"], ref[:, 0] * p.geometry.lead_per_rad_m,
                               rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(tr["carrier_speed_rad_s"], ref[:, 3], rtol=1e-5, atol=1e-9)


def test_batch_run_equals_stepping():
    p = preset("jones2016")
    tau = np.linspace(0, 0.3, 200)
    a = Simulator(p, "jones2016", 1e-3).run(tau, 50.0)
    sim = Simulator(p, "jones2016", 1e-3)
    rows = [sim.step(t, 50.0) for t in tau]
    for name in ("screw_angle_rad", "carrier_speed_rad_s", "nut_force_n", "power_dissipated_w", "efficiency"):
        np.testing.assert_allclose(a[name], [getattr(r, name) for r in rows], rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(a.internal, np.array([r.internal for r in rows]), rtol=1e-9, atol=1e-13)
