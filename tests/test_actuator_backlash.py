"""Growing backlash (issue 14) and the actuator around the `elastic` model.

Each test names its oracle: the clearance schedule itself (the dead zone's width is the lost
motion a reversal shows), the fault schedule, conservation of energy, an encoder's resolution.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from prsm_sim import ParamError, preset
from prsm_sim.actuator import (ACTUATOR_QUANTITIES, Actuator, ActuatorParams, DriveParams, Fault, MotorParams,
                               SensorParams)
from prsm_sim.models.elastic import AxialLaw
from prsm_sim.simulator import build_model

DT = 1e-3


def elastic_params(clearance_m: float, zeta: float = 0.02, **more):
    return preset("s30").with_overrides({"elastic.axial_clearance_m": clearance_m,
                                         "elastic.contact_damping_ratio": zeta, **more})


def velocity_actuator(p, faults=()):
    return Actuator(p, DT, "elastic", ActuatorParams(motor=MotorParams(), drive=DriveParams(mode="velocity"),
                                                      faults=faults))


def reversals(act, steps, speed_rad_s, load_n, half_period_s):
    """Square-wave screw speed ±speed with a load of ±load_n always opposing the commanded motion,
    so the nut rests on the leading flank and crosses the gap at each reversal. Yields (state, out)."""
    st = act.initial_state(0.0)
    n_half = round(half_period_s / DT)
    for k in range(steps):
        sgn = 1.0 if (k // n_half) % 2 == 0 else -1.0
        st, out = act.step(st, sgn * speed_rad_s, sgn * load_n)
        yield st, out


def test_lost_motion_at_each_reversal_is_the_clearance_of_that_time():
    """Oracle: the dead zone's width. On each flank at rest under a light load F the chain's deflection
    δ = (L/2π) θ_S − x_N sits at ±(c/2 + d(F)), so the jump of δ across a reversal (lost motion, read
    from the trajectory's screw angle and nut position) is the clearance: c0 before the fault,
    c0 + rate (t − start) while it grows (the mean of the two flanks' times: the growth is linear),
    c0 again once cleared and the nut has crossed the gap. d(20 N) ≈ 0.14 µm per flank (0.3 % of
    c0 = 100 µm) is inside the 1 % tolerance. Damping ratio 0.7 so the 50 kg nut settles on a
    flank within a half period instead of bouncing.
    """
    c0, rate, start, dur, half = 100e-6, 1e-4, 0.2, 0.6, 0.1
    f = Fault("backlash", start_s=start, duration_s=dur, value=rate)
    act = velocity_actuator(elastic_params(c0, zeta=0.7), (f,))
    n_half, avg = round(half / DT), 10
    rows = []
    for st, _ in reversals(act, 1200, 2.0, 20.0, half):
        s = st.screw
        t_begin = s.time_s - DT  # the step held the clearance of its start
        c = c0 + (rate * (t_begin - start) if f.active(t_begin) else 0.0)
        rows.append((act.p * s.screw_angle_rad - s.nut_axial_m, c))
    r = np.array(rows)
    plateau = [r[k - avg:k].mean(axis=0) for k in range(n_half, len(r) + 1, n_half)]  # (δ, c) at each half's end
    lost = [(abs(a[0] - b[0]), 0.5 * (a[1] + b[1])) for a, b in zip(plateau, plateau[1:])]
    before = lost[0]  # the reversal at 0.1 s
    assert before[1] == pytest.approx(c0, rel=1e-12)  # no growth yet
    assert before[0] == pytest.approx(c0, rel=0.01)
    growing = lost[2:7]  # flanks at 0.3 … 0.8 s, all inside the fault
    for measured, expected in growing:
        assert measured == pytest.approx(expected, rel=0.01)
    assert growing[-1][0] > 1.5 * c0  # it did grow: 100 → ~155 µm
    assert lost[-1][0] == pytest.approx(c0, rel=0.01)  # cleared at 0.8 s: back to c0 after crossings
    assert st.screw.extra_clearance_m == 0.0


def test_backlash_start_and_clear_are_events_and_other_models_refuse_it():
    """Oracle: the fault schedule (a step starting at t uses the faults active at t), as for every fault."""
    f = Fault("backlash", start_s=0.02, duration_s=0.03, value=1e-4)
    act = Actuator(elastic_params(20e-6), DT, "elastic", ActuatorParams(motor=MotorParams(), faults=(f,)))
    st = act.initial_state(0.0)
    seen = []
    for k in range(70):
        nxt, out = act.step(st, 0.3 if k < 35 else -0.3, 50.0)  # effort mode, N·m
        seen += [(round(e.time_s, 9), e.what, e.fault.kind) for e in act.events(st, nxt)]
        st = nxt
        assert math.isfinite(out.nut_position_m)
    assert seen == [(0.02, "start", "backlash"), (0.05, "clear", "backlash")]
    for model in ("ideal", "jones2016", "fu2018"):
        with pytest.raises(ParamError, match="fault.kind = 'backlash'.*'elastic'"):
            Actuator(preset("s30"), DT, model, ActuatorParams(faults=(f,)))
    preloaded = preset("s30").with_overrides({"elastic.preload_n": 500.0, "elastic.preload_kind": "double_nut"})
    with pytest.raises(ParamError, match="preload_n"):
        Actuator(preloaded, DT, "elastic", ActuatorParams(faults=(f,)))
    with pytest.raises(ParamError, match="fault.value"):
        Fault("backlash", value=0.0)


def test_energy_ledger_closes_through_growing_backlash_with_reversals():
    """Oracle: conservation. Electrical energy in = load work + dissipated (copper, screw friction,
    contact damping, the flank energy a widening gap releases) + stored (the elastic model's kinetic
    and elastic energy, docs/model.md §4.3, plus ½ L i²). The actuator adds nothing to the screw
    model's own balance (difference < 1e-9 of the energy in), and that balance stays inside the
    energy guard (|residual| ≤ 1e-3 of the flow, stepping/ledger.py): the guard never trips.
    """
    f = Fault("backlash", start_s=0.1, duration_s=0.6, value=1e-4)
    act = velocity_actuator(elastic_params(50e-6, zeta=0.05), (f,))
    trips = 0
    for st, out in reversals(act, 800, 10.0, 200.0, 0.1):  # noqa: B007  (the last state is read below)
        trips += int(out.energy_fault)
    led, s = st.ledger, st.screw
    bare = build_model(act.screw_params, "elastic", DT)  # the screw model alone (the rotor's inertia in)
    stored = bare.total_stored_energy_j(s) + 0.5 * act.actuator.motor.inductance_h * st.current_a ** 2
    dissipated = s.dissipated_j + led.copper_j + led.backlash_j
    residual = led.energy_in_j - (led.load_work_j + dissipated + stored)
    assert s.energy_flow_j > 1.0  # the guard judges this run
    assert trips == 0
    assert abs(residual - s.energy_residual_j) < 1e-9 * led.energy_in_j
    assert abs(s.energy_residual_j) < 1e-3 * s.energy_flow_j
    assert led.backlash_j > 0.0  # a widening gap only ever releases flank energy
    # the actuator's own block reports the same balance
    q = dict(zip((n for n, _ in ACTUATOR_QUANTITIES), act.layout.view(out.internal, "actuator")))
    assert q["stored_j"] + q["dissipated_j"] + q["load_work_j"] + s.energy_residual_j == pytest.approx(
        q["energy_in_j"], rel=1e-9)


def test_position_mode_around_elastic_holds_the_nut_against_a_load():
    """Oracles: the chain's law and the loop's own constants. The nut is commanded to 5 mm and held
    against 2 kN across a 50 µm clearance and the chain's compliance: the thread stands off by c/2 + d(2 kN)
    (from the chain's law), and the nut is still over the last 0.3 s (within the linear encoder's resolution,
    1 µm, the loop closes on). It comes to rest past the command: it crosses it creeping at v (fu2018's
    regularised Coulomb friction creeps below its break-away), the encoder reads the overshoot one resolution
    later, and the position loop (kp), with the speed loop and the friction band behind it, stops the nut within
    two of its time constants: at most one resolution plus v·2/kp past the command (seen: 4.65 µm of a bound of
    5.79), where the screw's friction holds it while the speed loop's integrator slowly unwinds.
    """
    # breakaway = running friction: with a Stribeck breakaway above it the loop sticks where the static band
    # stops it (0.7 µm past the command here), which the stiction tests cover; this oracle is the loop's
    # and so is the papers' screw: `s30`'s seals (docs/model.md §4.5) hold the nut where the overshoot leaves it
    # (seen 15 µm past the command)
    p = elastic_params(50e-6, zeta=0.3, **{"stiction.breakaway_ratio": 1.0, "drag.enabled": False})
    # the loop alone (no shaped reference): where a quantised loop comes to rest depends on how it arrived, and
    # this oracle is the loop's own stand-still (the shaped approach ends in a 2 µm two-count cycle instead)
    a = ActuatorParams(motor=MotorParams(), sensors=SensorParams(linear_encoder_resolution_m=1e-6),
                       drive=DriveParams(mode="position", speed_bandwidth_hz=20.0, position_kp_1_s=20.0,
                                         position_feedforward=False))
    act = Actuator(p, DT, "elastic", a)
    st = act.initial_state(0.0)
    xs, vs, threads = [], [], []
    for _ in range(1500):
        st, out = act.step(st, 0.005, 2000.0)
        xs.append(out.nut_position_m)
        vs.append(out.nut_velocity_m_s)
        threads.append(act.p * st.screw.screw_angle_rad)
    x = np.array(xs[-300:])
    assert np.ptp(x) <= 1e-6
    cross = int(np.argmax(np.array(xs) >= 0.005 + 1e-6))  # the first step the encoder reads past the command
    kp = a.drive.position_kp_1_s
    assert 0.0 < x[-1] - 0.005 <= 1e-6 + vs[cross] * 2.0 / kp
    law = AxialLaw(p)
    stand_off = 25e-6 + law.side.approach(2000.0) + 2000.0 * law.external_compliance(0.005)[0]
    assert threads[-1] - xs[-1] == pytest.approx(stand_off, rel=0.02)
