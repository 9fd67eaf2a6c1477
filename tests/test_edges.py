"""The plant at its edges: at rest with no torque, against end stops, at the thread ends, started
loaded. Each test names the independent number it checks against."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from prsm_sim import Simulator, build_model, preset
from prsm_sim.models.elastic import sliding_efficiencies
from prsm_sim.stepping.ledger import ENERGY_GUARD_REL

# -- fu2018 at rest with no screw torque ---------------------------------------------------------------
# At rest with τ = 0 the screw's moment balance (Newton–Euler, docs/model.md §4.2, equation 1) reads
# N_R N_S m_s = 0: the static friction turns the screw contact force so that its moment about the screw
# axis vanishes, and N_S must come from the roller's axial and spin balances. The state below (a nut
# load of a few mN, the lagged pin forces of a run that came to rest) is one a PID hold and a load
# pressing the nut into an end stop reach; it divided by that zero moment.
REST = dict(flank_sign=-1, pin_force_n=0.00025122375511249333)
REST_LOAD_N = -0.004163799661455414


@pytest.mark.parametrize("kernel", ["reference", "compiled"])
def test_fu2018_rest_without_torque_is_finite_in_every_path(kernel):
    model = build_model(preset("s30"), "fu2018", 1e-3, kernel)
    s0 = replace(model.initial_state(0.0), **REST)
    s1, out = model.step(s0, 0.0, REST_LOAD_N)
    assert np.all(np.isfinite(out.internal)) and math.isfinite(out.screw_speed_rad_s)
    # the static state itself: zero accelerations and the nut load on the threads (equation 2)
    st, _ = build_model(preset("s30"), "fu2018", 1e-3, "reference").stick_forces(0.0, REST_LOAD_N, -1,
                                                                                  REST["pin_force_n"])
    assert st.acc_s == 0.0 and st.acc_c == 0.0 and st.n_s > 0.0
    assert math.isclose(st.axial, REST_LOAD_N, rel_tol=1e-12)
    # the packed per-step path and the batch run (compiled: the whole loop in the kernel)
    sim = Simulator(preset("s30"), "fu2018", 1e-3, kernel=kernel)
    sim.state = s0
    packed = sim.step(0.0, REST_LOAD_N)
    sim.state = s0
    traj = sim.run(np.zeros(50), REST_LOAD_N)
    assert math.isclose(packed.screw_speed_rad_s, out.screw_speed_rad_s, rel_tol=1e-12, abs_tol=1e-15)
    assert np.all(np.isfinite(traj.columns["screw_speed_rad_s"]))
    assert np.all(np.isfinite(traj.internal))


def test_fu2018_rest_kernels_agree():
    outs = []
    for kernel in ("reference", "compiled"):
        model = build_model(preset("s30"), "fu2018", 1e-3, kernel)
        s = replace(model.initial_state(0.0), **REST)
        row = []
        for _ in range(20):
            s, o = model.step(s, 0.0, REST_LOAD_N)
            row.append([o.screw_speed_rad_s, o.carrier_speed_rad_s, o.nut_force_n, *o.internal])
        outs.append(np.array(row))
    scale = np.maximum(np.abs(outs[0]).max(axis=0), 1e-300)
    assert np.max(np.abs(outs[0] - outs[1]) / scale) <= 1e-12


# -- end stops act where the nut is ----------------------------------------------------------------------
from prsm_sim.actuator import ActuatorParams, MotorParams, StopParams  # noqa: E402

STOP = StopParams(min_position_m=-0.05, max_position_m=0.001)


def _block(sim, out, name):
    return float(sim.layout.view(out.internal, "actuator")[[n for n, _ in
                 __import__("prsm_sim.actuator", fromlist=["ACTUATOR_QUANTITIES"]).ACTUATOR_QUANTITIES].index(name)])


def _drag_hold_n(p):
    """Axial force the screw's load-independent drag can hold at rest, N: its no-load torque T₀ = T_s + 2 P_i
    (L/2π)(1/η_f − 1) (seals and idle flanks, docs/model.md §4.5, η_f the sliding-only efficiency of §4.2) over
    L/2π. Zero for the papers' screw."""
    if not p.drag.enabled:
        return 0.0
    g, d = p.geometry, p.drag
    eta_f = sliding_efficiencies(g, p.friction.mu_screw_roller)[0]
    seals = d.n_seals * d.seal_friction_n_per_m * 2 * math.pi * g.screw_radius_m ** 2
    return (seals + 2 * d.internal_preload_n * g.lead_per_rad_m * (1 / eta_f - 1)) / g.lead_per_rad_m


def _ram(model, dt, load_n=-2000.0, seconds=0.6, kernel="compiled"):
    """A constant load drives the nut from rest at x = 0 into the stop 1 mm away, no screw torque."""
    sim = Simulator(preset("s30"), model, dt, actuator=ActuatorParams(motor=MotorParams(), stops=STOP), kernel=kernel)
    rows = []
    for _ in range(int(round(seconds / dt))):
        o = sim.step(0.0, load_n)
        rows.append((o.nut_position_m, o.screw_speed_rad_s, _block(sim, o, "stop_force_n"),
                     _block(sim, o, "stop_penetration_m"), _block(sim, o, "stop_absorbed_j"),
                     _block(sim, o, "energy_in_j") - _block(sim, o, "load_work_j") - _block(sim, o, "dissipated_j")
                     - _block(sim, o, "stored_j"), -_block(sim, o, "load_work_j")))
    return np.array(rows)


@pytest.mark.parametrize("model,dt", [("ideal", 1e-3), ("jones2016", 1e-3), ("fu2018", 1e-3), ("elastic", 1e-3),
                                      ("elastic", 1e-4), ("fu2018", 1e-4)])
def test_stop_law_at_rest_and_on_impact(model, dt):
    r = _ram(model, dt, seconds=0.6 if dt == 1e-3 else 0.25)
    x, ws, force, depth, absorbed, residual, load_work = r.T
    k, d, f_push = STOP.stiffness_n_m, STOP.max_position_m, 2000.0
    # impact from rest at distance d under a constant force F (docs/model.md, end stop): ½kδ² = F (d + δ)
    # bounds the penetration; friction and the damper only lower it
    assert depth.max() <= (f_push + math.sqrt(f_push**2 + 2 * k * f_push * d)) / k * (1 + 1e-9)
    # penetration is the nut's own position past the stop
    np.testing.assert_allclose(depth, np.maximum(x - d, 0.0), rtol=0, atol=1e-15)
    # the stop only absorbs: its absorbed energy never decreases (to rounding of the work it books)
    assert np.all(np.diff(absorbed) >= -1e-9 * np.maximum(1.0, load_work[1:]))
    # no energy created: the actuator's ledger closes within the energy guard's limit
    assert abs(residual[-1]) <= ENERGY_GUARD_REL * max(1.0, load_work[-1])
    if dt == 1e-3:
        # at rest against the stop its force is its own law k δ (the rate term has died out) and it
        # carries the load the screw does not: with no screw torque, at most the whole load
        assert abs(ws[-1]) < 1e-4
        assert math.isclose(force[-1], -k * depth[-1], rel_tol=1e-6)
        # elastic: the axial mode rings down slowly (ζ = 0.02); the screw's static drag may hold the stop's spring
        # a little deeper than the load alone
        assert 0.0 < -force[-1] <= f_push * (1 + 1e-5) + _drag_hold_n(preset("s30"))
        tail = ws[-int(0.1 / dt):]
        assert np.ptp(tail) < 0.5


# -- thread ends ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018", "elastic"])
def test_the_nut_never_leaves_the_threads(model):
    """No torque and a 500 N load for 3 s once carried the nut metres along a 0.3 m screw. The ends lie at
    ±(screw_length − nut_length)/2 (docs/model.md, thread ends) and hold the nut like a stop: at rest
    there the end's force is the load, give or take what the screw's static drag holds (`s30`'s seals and idle
    flanks, docs/model.md §4.5: T₀/(L/2π) of axial force), and its penetration F/k."""
    p = preset("s30")
    held = _drag_hold_n(p)
    half = 0.5 * (p.geometry.screw_length_m - p.geometry.n_teeth * p.geometry.pitch_m)
    assert p.geometry.travel_m == pytest.approx(2 * half)
    k = 1e8  # the stop law's default stiffness (StopParams)
    for stepped in (True, False):
        sim = Simulator(p, model, 1e-3, nut_position_m=-half + 0.005)
        n = 1500
        x = (np.array([sim.step(0.0, 500.0).nut_position_m for _ in range(n)]) if stepped
             else sim.run(np.zeros(n), 500.0).columns["nut_position_m"])
        # the impact bound ½kδ² = F (d + δ) from rest d = 5 mm away (docs/model.md, end stop)
        assert x.min() >= -half - (500.0 + math.sqrt(500.0**2 + 2 * k * 500.0 * 0.005)) / k
        if stepped:
            f_end = sim.thread_end_force_n
            assert abs(f_end - 500.0) <= held * (1 + 1e-3)
            assert x[-1] == pytest.approx(-half - f_end / k, abs=1e-3 * 500.0 / k + 1e-12)
    # the ends can be removed (an unlimited screw): then the nut runs on
    free = Simulator(p.with_overrides({"geometry.thread_ends": False}), model, 1e-3, nut_position_m=-half + 0.005)
    assert free.run(np.zeros(1500), 500.0).columns["nut_position_m"].min() < -half - 1e-3 or model == "jones2016"


def test_a_start_off_the_threads_is_refused():
    from prsm_sim.errors import InputError
    with pytest.raises(InputError, match="nut_position_m = 0.2: must lie on the threads"):
        Simulator(preset("s30"), "ideal", 1e-3, nut_position_m=0.2)


def test_thread_end_shows_in_the_actuator_block():
    from prsm_sim.actuator import ACTUATOR_QUANTITIES
    p = preset("s30")
    half = 0.5 * p.geometry.travel_m
    sim = Simulator(p, "ideal", 1e-3, nut_position_m=half - 0.001, actuator=ActuatorParams())
    names = [n for n, _ in ACTUATOR_QUANTITIES]
    flags = [sim.layout.view(sim.step(0.0, -500.0).internal, "actuator")[names.index("thread_end")] for _ in range(500)]
    assert flags[0] == 0.0 and flags[-1] == 1.0


# -- equilibrium start ---------------------------------------------------------------------------------
@pytest.mark.parametrize("kernel", ["compiled", "reference"])
@pytest.mark.parametrize("load_n", [2000.0, -5000.0])
def test_elastic_started_in_equilibrium_shows_no_transient(kernel, load_n):
    """Started pre-deflected at F with the frictionless holding torque F L/2π (docs/model.md, equilibrium
    start), the thread force is F from the first step (within 1 %); started undeflected it overshoots
    towards 2 F, the step response of an undamped spring."""
    p = preset("s30")
    tau = p.geometry.lead_per_rad_m * load_n
    sim = Simulator(p, "elastic", 1e-3, kernel=kernel, initial_load_n=load_n)
    f = np.array([sim.step(tau, load_n).nut_force_n for _ in range(100)])
    assert np.max(np.abs(f / load_n - 1.0)) < 0.01
    cold = Simulator(p, "elastic", 1e-3, kernel=kernel)
    f = np.array([cold.step(tau, load_n).nut_force_n for _ in range(100)])
    assert np.max(f / load_n) > 1.5
    sim.reset()  # a reset returns to the loaded equilibrium
    assert sim.step(tau, load_n).nut_force_n == pytest.approx(load_n, rel=0.01)


@pytest.mark.parametrize("mode", ["velocity", "position"])
def test_actuator_drive_holds_the_initial_load(mode):
    from prsm_sim.actuator import DriveParams
    p = preset("s30")
    sim = Simulator(p, "elastic", 1e-3, initial_load_n=2000.0,
                    actuator=ActuatorParams(motor=MotorParams(), drive=DriveParams(mode=mode)))
    outs = [sim.step(0.0, 2000.0) for _ in range(200)]
    f = np.array([o.nut_force_n for o in outs])
    assert np.max(np.abs(f / 2000.0 - 1.0)) < 0.01
    assert abs(outs[-1].nut_position_m) < 1e-6


def _held(s, command: float, load_n: float, n: int = 100) -> tuple[float, float]:
    """The largest relative thread-force error and nut speed (m/s) over `n` steps of a held command."""
    outs = [s.step(command) for _ in range(n)]
    f = np.array([o.nut_force_n for o in outs])
    return float(np.max(np.abs(f / load_n - 1.0))), float(np.max(np.abs([o.nut_velocity_m_s for o in outs])))


@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018", "elastic"])
@pytest.mark.parametrize("interface", ["velocity", "position"])
def test_session_interface_decides_the_drive_that_holds_the_initial_load(model, interface):
    """Oracle: the static equilibrium of the loaded start (docs/model.md, starting in equilibrium): at rest
    under F the threads carry F, so with the drive holding still (speed command 0, or the start's position)
    the thread force stays within 1 % of F over the first 0.1 s and the nut does not move. The actuator's
    parameters keep the library's default drive.mode "effort": the session's interface, not the parameters,
    decides which loop holds the start (it started unheld, back-driven at 11–16 rad/s, the thread force
    6–12 % off F, before the start loaded the drive train in every mode). The same after switching from an
    effort start before the first step, and after a reset from a run under another load."""
    from prsm_sim import Session
    from prsm_sim.actuator import DriveParams
    f0 = 2000.0
    act = ActuatorParams(motor=MotorParams(), drive=DriveParams(mode="effort"))
    hold = 0.0  # the speed command, or the nut's start position
    s = Session(preset("s30"), model, 1e-3, act, interface=interface, initial_load_n=f0)
    err, v = _held(s, hold, f0)
    assert err < 0.01 and v < 1e-6
    for _ in range(50):
        s.step(hold, load_n=-f0)  # away from the start: a reset has something to undo
    s.reset()
    assert s.load_n == f0
    err, v = _held(s, hold, f0)
    assert err < 0.01 and v < 1e-6
    s = Session(preset("s30"), model, 1e-3, act, interface="effort", initial_load_n=f0)
    assert s.set_interface(interface) is None
    err, v = _held(s, hold, f0)
    assert err < 0.01 and v < 1e-6


def test_effort_start_holds_under_the_holding_torque_through_a_compliant_coupling():
    """Effort mode: the command is the torque, so the start is in equilibrium under the holding torque
    F L/2π (static balance of the frictionless screw, docs/model.md, starting in equilibrium): thread
    force within 1 % of F over 0.1 s. The motor current and the coupling's twist start at that torque
    (an untwisted coupling first passed no torque to the screw: 3.9 % off F, the screw back-driven)."""
    from prsm_sim import Session
    p, f0 = preset("s30"), 2000.0
    act = ActuatorParams(motor=MotorParams(coupling_stiffness_nm_rad=2000.0))
    s = Session(p, "jones2016", 1e-3, act, interface="effort", initial_load_n=f0)
    err, v = _held(s, p.geometry.lead_per_rad_m * f0, f0)
    assert err < 0.01 and v < 1e-6


# -- sensors and drive ---------------------------------------------------------------------------------
@pytest.mark.parametrize("dt", [1e-3, 2.5e-4])
def test_load_cell_filter_acts_on_its_noise(dt):
    """White noise of σ per sample through a first-order low-pass f_c sampled at f_s keeps
    σ √((1 − a)/(1 + a)), a = exp(−2π f_c/f_s) (variance of an AR(1) process; ≈ σ √(π f_c/f_s) for
    f_c ≪ f_s, docs/model.md load cell). Noise added after the filter kept all of σ."""
    from prsm_sim.actuator import SensorParams
    sigma, fc = 5.0, 50.0
    sim = Simulator(preset("s30"), "ideal", dt, actuator=ActuatorParams(
        sensors=SensorParams(load_cell_noise_n=sigma, load_cell_bandwidth_hz=fc, seed=3)))
    n = int(round(4.0 / dt)) if dt == 1e-3 else int(round(2.5 / dt))
    f = np.array([sim.model.measured(sim.step(0.0, 0.0)).nut_force_n for _ in range(n)])[200:]
    a = math.exp(-2 * math.pi * fc * dt)
    assert np.std(f) == pytest.approx(sigma * math.sqrt((1 - a) / (1 + a)), rel=0.06)


def _position_step(ff, step_m, model="ideal"):
    from prsm_sim.actuator import ACTUATOR_QUANTITIES, DriveParams
    # the papers' screw (drag off): the shaped reference's budget is set for the mechanism's inertia and load, and
    # `s30`'s no-load torque (docs/model.md §4.5), which neither loop feeds forward, turns a 0.1 mm step into a
    # stick–slip approach that overshoots by 7.5 %
    sim = Simulator(preset("s30").with_overrides({"drag.enabled": False}), model, 1e-3, actuator=ActuatorParams(
        motor=MotorParams(), drive=DriveParams(mode="position", position_feedforward=ff)))
    names = [n for n, _ in ACTUATOR_QUANTITIES]
    for _ in range(50):  # held at 0 first: the command then jumps
        sim.step(0.0, 0.0)
    xs, taus = [], []
    for _ in range(300):
        o = sim.step(step_m, 0.0)
        xs.append(o.nut_position_m)
        taus.append(sim.layout.view(o.internal, "actuator")[names.index("torque_reference_nm")])
    xs = np.array(xs)
    return int(np.argmax(xs >= 0.9 * step_m)), float(np.max(np.abs(taus))), float(xs.max() / step_m - 1)


@pytest.mark.parametrize("step_m", [1e-4, 1e-3, 1e-2])
def test_position_feedforward_neither_kicks_nor_slows_a_step(step_m):
    """A command step: the feed-forward comes from the drive's shaped reference, so the torque stays within
    half the motor's 10 N·m limit (the reference's acceleration budget) plus what the loop adds (the one-step
    rate of a raw step asked for 300 rad/s and hit the limit), the nut reaches 90 % no later than the loop
    alone, and overshoots by less than 3 %."""
    t_ff, tau_ff, over_ff = _position_step(True, step_m)
    t_loop, _, _ = _position_step(False, step_m)
    assert t_ff <= t_loop
    assert tau_ff <= 0.6 * 10.0
    assert over_ff < 0.03


# -- through the session -----------------------------------------------------------------------------
def test_session_starts_in_equilibrium_and_reports_thread_ends():
    """Session(initial_load_n=F) starts the chain carrying F (thread force within 1 % with the holding
    torque), and the nut reaching and leaving a thread end are events (docs/model.md, thread ends)."""
    from prsm_sim import Session
    p = preset("s30")
    tau = p.geometry.lead_per_rad_m * 2000.0
    s = Session(p, "elastic", 1e-3, initial_load_n=2000.0)
    assert s.load_n == 2000.0
    f = np.array([s.step(tau).nut_force_n for _ in range(50)])
    assert np.max(np.abs(f / 2000.0 - 1.0)) < 0.01
    half = 0.5 * p.geometry.travel_m
    s = Session(p, "ideal", 1e-3, nut_position_m=-half + 0.002, load_n=500.0)
    for _ in range(300):
        s.step(0.0)
    ev = s.take_edge_events()
    # reached (it may bounce off once or twice on the way to rest), and at rest on the end at the last
    assert ev[0].what == "reached" and ev[-1].what == "reached" and len(ev) % 2 == 1
    assert abs(s.simulator.thread_end_force_n - 500.0) <= _drag_hold_n(p) * (1 + 1e-3)  # the load ± the static drag
    for _ in range(300):
        s.step(tau)  # drive it off the end again (+x, against the 500 N)
    assert [e.what for e in s.take_edge_events()] == ["left"]


@pytest.mark.parametrize("fitted", [False, True])
def test_session_survives_every_order_of_pause_step_reset(fitted):
    """Pause, step, reset in every order, with and without an actuator, with its brake and faults: no
    request raises, and a reset at any point returns to the start (time zero, the start's position)."""
    import itertools

    from prsm_sim import Session
    from prsm_sim.actuator import BrakeParams, Fault
    act = ActuatorParams(motor=MotorParams(), brake=BrakeParams(holding_torque_nm=5.0)) if fitted else None
    for order in itertools.permutations(("pause", "step", "reset", "brake")):
        s = Session(preset("s30"), "fu2018", 1e-3, act, interface="velocity" if fitted else "effort")
        for op in ("fault",) + order + ("resume",) + order:
            if op == "pause":
                s.pause()
            elif op == "resume":
                s.resume()
            elif op == "step":
                for _ in range(3):
                    s.step(2.0, 300.0)
            elif op == "reset":
                s.reset()
                assert s.time_s == 0.0 and s.last.nut_position_m == 0.0
            elif op == "brake" and fitted:
                # answered: done, or refused in one line (a release while a drive fault holds the torque off)
                reason = s.brake(not s.simulator.state.brake_engaged)
                assert reason is None or reason.startswith("brake release refused")
            elif op == "fault" and fitted:
                assert s.inject(Fault("drive_fault", start_s=s.time_s, duration_s=0.002)) is None
        assert s.fault is None and math.isfinite(s.last.screw_speed_rad_s)
