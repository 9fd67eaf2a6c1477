"""`ideal`: the Simscape Leadscrew / Modelica LossyGear parameter set returns what it is given."""

import numpy as np
import pytest

from prsm_sim import Simulator, preset


def _params(**ideal):
    # closed forms of an unlimited screw: these runs go past the threaded length, so without thread ends; and of
    # the lossy gear alone, without `s30`'s equivalent no-load torque (drag off, docs/model.md §4.5)
    return preset("s30").with_overrides({"geometry.thread_ends": False, "drag.enabled": False,
                                         **{f"ideal.{k}": v for k, v in ideal.items()}})


def test_forward_efficiency_is_returned_when_the_screw_drives():
    # screw drives against a resisting load at constant speed: P_out / P_in = η_f (plus the viscous loss)
    b = 2e-3  # bearing loss: sets the speed, J/b ≈ 0.1 s
    p = _params(efficiency_forward=0.8, efficiency_backward=0.6, viscous_nm_s_rad=b, power_threshold_w=0.1)
    f = 2000.0
    tau = f * p.geometry.lead_per_rad_m / 0.8 + b * 100.0  # the torque that holds 100 rad/s
    sim = Simulator(p, "ideal", 1e-3)
    tr = sim.run(np.full(3000, tau), f)
    assert tr["screw_speed_rad_s"][-1] == pytest.approx(100.0, rel=1e-3)
    mech = tr["power_out_w"][-1] / (tr["power_in_w"][-1] - b * tr["screw_speed_rad_s"][-1] ** 2)
    assert mech == pytest.approx(0.8, rel=1e-4)


def test_backward_efficiency_is_returned_when_the_load_drives():
    # an assisting load back-drives the screw against a braking torque: P_in / P_out = η_b
    p = _params(efficiency_forward=0.8, efficiency_backward=0.6, power_threshold_w=0.1)
    f = -2000.0  # pushes the nut the positive way
    tau_l = f * p.geometry.lead_per_rad_m
    sim = Simulator(p, "ideal", 1e-3)
    sim.run(np.full(200, 0.0), f)  # let it start moving
    tr = sim.run(np.full(2000, tau_l * 0.6), f)  # brake with what backward rolling delivers: constant speed
    assert tr["efficiency"][-1] == pytest.approx(0.6, rel=1e-4)
    assert tr["power_in_w"][-1] < 0 and tr["power_out_w"][-1] < 0


def test_self_locking_screw_holds_a_back_driving_load():
    # η_b ≤ 0: a load alone cannot turn the screw (docs/model.md §4 `ideal`)
    p = _params(efficiency_forward=0.4, efficiency_backward=-0.2)
    sim = Simulator(p, "ideal", 1e-3)
    tr = sim.run(np.zeros(2000), 5000.0)
    assert np.all(tr["screw_speed_rad_s"] == 0.0) and np.all(tr["nut_position_m"] == 0.0)
    # ...but the motor can still drive it either way
    tr = sim.run(np.full(500, -5.0), 5000.0)
    assert tr["screw_speed_rad_s"][-1] < 0


@pytest.mark.parametrize("eta_b", [0.8, 0.3])
def test_backdrivable_screw_runs_back_under_load(eta_b):
    # closed form (docs/model.md §4 `ideal`, LossyGear backward mode): with no motor torque the load
    # torque τ_L = F L/2π drives the screw back against the loss τ_L (1 − η_b), so J ω' = −η_b τ_L;
    # with the power threshold far below the power, constant acceleration, which the implicit
    # velocity step and the trapezoidal angle integrate exactly: ω_n = −η_b τ_L t_n / J, θ_n = ω_n t_n / 2.
    p = _params(efficiency_forward=0.9, efficiency_backward=eta_b, power_threshold_w=1e-9)
    sim = Simulator(p, "ideal", 1e-3)
    tr = sim.run(np.zeros(500), 5000.0)
    t = tr["time_s"]
    w = -eta_b * 5000.0 * p.geometry.lead_per_rad_m * t / sim.model.J
    err = max(np.max(np.abs(tr["screw_speed_rad_s"] / w - 1)), np.max(np.abs(tr["screw_angle_rad"] / (w * t / 2) - 1)))
    print(f"ideal back-drive η_b = {eta_b}: worst relative error {err:.1e}")  # measured 2e-14
    assert err < 1e-12


def test_energy_balance():
    # input work = output work + ΔT + dissipated, exactly for this integrator (trapezoidal angles)
    p = _params(efficiency_forward=0.85, efficiency_backward=0.7, viscous_nm_s_rad=1e-4)
    sim = Simulator(p, "ideal", 1e-3)
    tr = sim.run(2.0 * np.sin(np.linspace(0, 30, 5000)), 1000.0)
    s = tr.final_state
    kinetic = 0.5 * sim.model.J * s.screw_speed_rad_s**2
    assert s.work_in_j == pytest.approx(s.work_out_j + s.dissipated_j + kinetic, rel=1e-9)
    assert s.dissipated_j > 0


@pytest.mark.parametrize("torque_over_t0, rests", [(0.5, True), (2.0, False)])
def test_a_screw_stopped_within_a_step_by_a_reversing_torque_books_the_event_located_stop(torque_over_t0, rests):
    # closed form of a constant deceleration to rest: a screw at ω₀ under a torque −T against its own
    # Coulomb loss T₀ (the no-load torque, drag on; no load, so no mesh loss and no fading) decelerates by
    # T + T₀ (the loss opposes the motion it has, not the way the torque points) and rests at
    # t* = J ω₀/(T + T₀), having turned ½ ω₀ t*. Then a torque below T₀ holds it (T = T₀/2), and one above
    # turns it back from rest for the rest of the step r = h − t* (T = 2 T₀): ω₁ = −r (T − T₀)/J, turning
    # ½ ω₁ r more. The step's dissipation is −T Δθ + ½ J (ω₀² − ω₁²) ≥ 0 (second law). A trapezoid over the
    # whole step turned ½ (ω₀ + ω₁) h against T and booked negative dissipation here.
    import dataclasses
    p = preset("s30").with_overrides({"geometry.thread_ends": False})
    h = 0.05
    sim = Simulator(p, "ideal", h)
    m = sim.model
    t0, j = m.no_load_torque_nm, m.J
    assert t0 > 0.0 and p.ideal.viscous_nm_s_rad == 0.0
    torque = -torque_over_t0 * t0
    w0 = 0.4 * h * (t0 - torque) / j  # stops at t* = 0.4 h
    s0 = dataclasses.replace(m.initial_state(0.0), screw_speed_rad_s=w0)
    s1, out = m.step(s0, torque, 0.0)
    t_stop, r = 0.4 * h, 0.6 * h
    w1 = 0.0 if rests else -r * (-torque - t0) / j
    assert (w1 == 0.0) == rests
    assert s1.screw_speed_rad_s == pytest.approx(w1, rel=1e-12, abs=0.0)
    turn = 0.5 * w0 * t_stop + 0.5 * w1 * r
    assert s1.screw_angle_rad == pytest.approx(turn, rel=1e-12)
    dissipated = s1.dissipated_j - s0.dissipated_j
    assert dissipated == pytest.approx(torque * turn + 0.5 * j * (w0**2 - w1**2), rel=1e-12)
    assert dissipated > 0.0
    assert s1.work_in_j == pytest.approx(s1.work_out_j + s1.dissipated_j + 0.5 * j * (w1**2 - w0**2), rel=1e-12)


def test_a_coasting_screw_turns_continuously_in_its_speed_across_the_edge_of_stopping():
    # limit case: a screw coasting at ω₀ against its loss (500 N of load, no torque) either slides on (the
    # trapezoid ½ h (ω₀ + ω₁)) or stops within the step; at the edge ω₁ → 0 and both turn ½ ω₀ h, so Δθ is
    # continuous in ω₀ with a slope of at most h (∂Δθ/∂ω₀ = ½ h (1 + ∂ω₁/∂ω₀) ≤ h). A fit differentiates
    # the motion with respect to the moved mass through such steps.
    import dataclasses
    import numpy as np
    p = preset("s30").with_overrides({"geometry.thread_ends": False})
    m = Simulator(p, "ideal", 1e-3).model
    speeds = np.linspace(1e-3, 3.0, 3001)
    turns = []
    for w0 in speeds:
        s1, _ = m.step(dataclasses.replace(m.initial_state(0.0), screw_speed_rad_s=float(w0)), 0.0, 500.0)
        turns.append(s1.screw_angle_rad)
    stops = [m.step(dataclasses.replace(m.initial_state(0.0), screw_speed_rad_s=float(w)), 0.0, 500.0)[0]
             .screw_speed_rad_s <= 0.0 for w in speeds]  # stopped within the step (and turned back)
    assert any(stops) and not all(stops)  # the scan crosses the edge
    slope = np.abs(np.diff(turns)) / np.diff(speeds)
    assert slope.max() <= 1e-3 * (1 + 1e-9), slope.max()
