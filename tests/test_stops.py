"""End stops held against stick/slip: at rest the stop's force is its own law k δ, and the stop only absorbs.

The stop force is solved implicitly on the plant's own step (prsm_sim/actuator/stops.py). Where the
plant's response jumps with the force (a screw that sticks up to its static friction and slips past it),
the solve's residual has no root and one side of the jump must be taken. Checked against independent
numbers: the stop law at rest F = k δ (its rate term gone), the static equilibrium of the nut (the stop
carries the load less what the threads hold; Coulomb: a hold needs |drive − F| ≤ F_s) and the stop's
energy balance (the work the nut does on it less its stored ½ k δ² never falls).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from prsm_sim import Simulator, preset
from prsm_sim.actuator import ACTUATOR_QUANTITIES, ActuatorParams, DriveParams, MotorParams, StopParams
from prsm_sim.actuator.stops import REST_TOL_M, Limit, absorbed_j, penetration, solve
from prsm_sim.models.fu2018 import STEP_BALANCE_TOL

H_S = 1e-3
V_STICK_M_S = 1e-5  # a slide slower than this at the step's end is held where the friction can hold it


class DryFrictionNut:
    """A nut of mass M pushed toward the limit by P (along the limit's sign) against Coulomb friction with a
    static capacity F_s above its kinetic F_k (a Stribeck drop): held while |P − F| ≤ F_s, else sliding
    with the kinetic friction against its motion (semi-implicit Euler: x1 = x0 + h v1) until the slide
    reverses or creeps to a halt where the friction can hold it. From rest, a force just past the
    capacity slides the nut (F_s − F_k) h²/M at once: the step's end position jumps with the force."""

    def __init__(self, limit: Limit, push_n=5000.0, static_n=500.0, kinetic_n=400.0, mass_kg=100.0):
        self.lim, self.p, self.fs, self.fk, self.m = limit, push_n, static_n, kinetic_n, mass_kg

    def advance(self, x0, v0):
        """advance(F): the step from (x0, v0) under the stop's force F (signed along +x), as (x1, v1)."""
        s = self.lim.sign

        def step(f_stop):
            drive = self.p + s * f_stop  # what pushes the nut into the limit, along the limit's sign
            u0 = s * v0
            if u0 == 0.0 and abs(drive) <= self.fs:
                return x0, 0.0  # held
            moving = u0 if u0 != 0.0 else drive
            u1 = u0 + H_S * (drive - math.copysign(self.fk, moving)) / self.m
            if u0 != 0.0 and (u0 * u1 < 0.0 or abs(u1) < V_STICK_M_S) and abs(drive) <= self.fs:
                return x0, 0.0  # the slide stops within the step (or creeps to a halt) and the friction holds it
            return x0 + s * H_S * u1, s * u1
        return step

    def run(self, x0, v0, steps):
        """Steps under the stop alone (the solve on every step): (x, v, stop force along +x, absorbed J) per step."""
        rows = []
        for _ in range(steps):
            step = self.advance(x0, v0)
            free = step(0.0)
            f, (x1, v1) = solve(self.lim, H_S, x0, free, step, lambda r: r[0], H_S * H_S / self.m)
            rows.append((x1, v1, f, absorbed_j(self.lim, -self.lim.sign * f, penetration(self.lim, x0),
                                                penetration(self.lim, x1))))
            x0, v0 = x1, v1
        return np.array(rows)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_nut_at_rest_on_the_stop_law_is_solved_at_the_first_trial_and_stays(sign):
    """Limit case: a nut held at rest in the stop, at δ₀ with k δ₀ inside its static friction's band (push 5 kN,
    static 500 N: any stop force within 4.5-5.5 kN holds it), has the law's own force k δ₀ as its root: held,
    it does not move, so the law at the step's end asks what the step held. The solve's first trial is that
    force (the nut starts at rest), so one plant step solves it, and the nut stays where it was; from the
    compliance's estimate (the nut's speed unknown) the free slide's h²/M misjudges the held nut and the same
    root took more trials. A nut arriving at speed is still tried from the compliance's estimate."""
    k = 1e7
    lim = Limit(0.0, sign, k, 2e5, False, math.inf)
    nut = DryFrictionNut(lim)
    x0 = sign * 4800.0 / k
    for v0, first_trial in ((0.0, True), (math.inf, False), (sign * 0.05, False)):
        trials = []
        step = nut.advance(x0, v0 if math.isfinite(v0) else 0.0)

        def counted(f, step=step, trials=trials):
            trials.append(f)
            return step(f)

        f, (x1, v1) = solve(lim, H_S, x0, step(0.0), counted, lambda r: r[0], H_S * H_S / nut.m, v0)
        if first_trial:
            assert trials == [-sign * 4800.0] and f == -sign * 4800.0  # k δ₀, at the first trial
            assert (x1, v1) == (x0, 0.0)
        elif math.isinf(v0):
            assert len(trials) > 1 and f == pytest.approx(-sign * 4800.0, rel=1e-9)  # the same root, later
        else:
            assert trials[0] != -sign * 4800.0  # moving: the compliance's estimate first


@pytest.mark.parametrize("sign", [1.0, -1.0])
@pytest.mark.parametrize("pressed_by", ["stop", "drive"])
def test_a_hold_off_the_stop_law_gives_way_until_at_rest_f_equals_k_delta(sign, pressed_by):
    """Held at rest δ0 into a stop whose law k δ0 is past what the hold takes (the stop over-presses a drive of
    P plus static friction F_s, or a drive of P presses past k δ0 plus F_s): the nut slides until it is held
    where the stop's force is its law, F = k δ, within the Coulomb band |P − F| ≤ F_s."""
    k, c = 1e7, 2e5
    lim = Limit(0.01 * sign, sign, k, c, False)
    nut = DryFrictionNut(lim)
    # N past the band's edge: less than the slip's own rate term c (F_s − F_k) h/M = 200 N, so the stuck side
    # has the smaller residual (a nearest-side choice would keep the hold off its law)
    over = 24.5
    edge = nut.p + nut.fs if pressed_by == "stop" else nut.p - nut.fs
    d0 = (edge + (over if pressed_by == "stop" else -over)) / k
    rows = nut.run(lim.position_m + sign * d0, 0.0, 150)
    x, v, f, absorbed = rows.T
    # it moved: out of an over-pressed hold, further in under an over-pressing drive
    assert sign * (x[-1] - x[0]) < 0.0 if pressed_by == "stop" else sign * (x[-1] - x[0]) > 0.0
    # at rest at the end, held (Coulomb) where the stop's force is its static law k δ
    assert np.all(v[-5:] == 0.0)
    depth = penetration(lim, x[-1])
    assert depth > 0.0
    assert -sign * f[-1] == pytest.approx(k * depth, rel=1e-9)
    assert abs(nut.p - k * depth) <= nut.fs * (1 + 1e-12)
    # the stop only absorbs, every step
    assert np.all(absorbed >= -1e-15)


def test_a_hold_within_half_the_jump_of_the_stop_law_stays_held_and_the_stop_gives_no_energy():
    """k δ0 just past the band's edge (2 N, less than ½ k of the slip the jump takes: (F_s − F_k) h²/M = 1 µm,
    5 N): sliding out would have the stop push harder than its mean spring force while it relaxes, giving
    out energy; the nut stays held, off the law by less than that half jump."""
    k = 1e7
    lim = Limit(0.01, 1.0, k, 2e5, False)
    nut = DryFrictionNut(lim)
    edge = nut.p + nut.fs
    jump_m = (nut.fs - nut.fk) * H_S**2 / nut.m
    rows = nut.run(lim.position_m + (edge + 2.0) / k, 0.0, 5)
    x, v, f, absorbed = rows.T
    assert np.all(v == 0.0) and np.all(x == x[0])
    assert np.all(absorbed >= 0.0)
    assert 0.0 < k * penetration(lim, x[-1]) - (-f[-1]) <= 0.5 * k * jump_m


Q = {n: i for i, (n, _) in enumerate(ACTUATOR_QUANTITIES)}


def test_fu2018_pressed_into_a_stop_then_pulled_back_rests_at_the_stop_law():
    """fu2018 in effort mode (10 N·m) drives the nut into a 1e7 N/m stop under a load pushing it in (−6449.8 N),
    then the load reverses (+6449.8 N): the stop now presses the nut back harder than the screw's static
    friction can hold. At rest the stop's force is k δ (to the 0.5 µm of k a step ending at rest is refined to:
    the nut creeps out by stick and slip and is held 0.03 µm off, within half a one-step slip of the band's
    edge), and it carries the load less what the threads hold (the nut's static equilibrium). Before, the nut
    stayed 2.5 µm deeper than the force it reported."""
    k = 1e7
    stops = StopParams(min_position_m=-0.05, max_position_m=0.0035, stiffness_n_m=k, damping_n_s_m=2e5)
    # the papers' screw (drag off), whose figures this case was set up with
    sim = Simulator(preset("s30").with_overrides({"drag.enabled": False}), "fu2018", 1e-3,
                    actuator=ActuatorParams(motor=MotorParams(),
                    drive=DriveParams(mode="effort"), stops=stops))
    rows = []
    for i in range(250):
        load = -6449.8 if i < 100 else 6449.8
        o = sim.step(10.0, load)
        blk = sim.layout.view(o.internal, "actuator")
        rows.append((o.screw_speed_rad_s, float(blk[Q["stop_force_n"]]), float(blk[Q["stop_penetration_m"]]),
                     load - o.nut_force_n))
    w, force, depth, net = np.array(rows).T
    assert np.all(w[-20:] == 0.0)  # at rest: the screw is held by its static friction
    assert depth[-1] > 0.0
    assert -force[-1] == pytest.approx(k * depth[-1], abs=k * REST_TOL_M)  # the stop law at rest
    assert force[-1] == pytest.approx(net[-1], rel=1e-9)  # the nut's static equilibrium


@pytest.mark.parametrize("model, dt_s", [("ideal", 0.01), ("jones2016", 0.0357), ("fu2018", 1 / 14)])
def test_a_nut_coming_to_rest_within_a_large_step_rests_on_the_stop_law(model, dt_s):
    """A 200 kN load presses the nut into a soft stop (1e7 N/m, 2e5 N·s/m) against a position hold at steps of
    10-71 ms (the envelope's seed 6437: fu2018 at 1/14 s). The nut bounces and comes to rest within a step. At
    every step that ends with it at rest in the stop, the stop's force is its static law k δ (F = k δ + c δ̇ with
    δ̇ = 0) to 0.5 µm of k δ, and it carries the load less what the threads hold (the nut's static
    equilibrium). Before, the force held over such a step carried the damper's c Δδ/h of the motion that ended
    within it: the nut rested 0.2-17 mm off the law's deflection. First law: the actuator's books close every
    step (energy in = load work + dissipated + Δ stored, to rounding for the linear models, to fu2018's own
    step balance for fu2018), and the stop only absorbs (its absorbed work never falls)."""
    k, load = 1e7, 2e5
    stops = StopParams(min_position_m=-0.006, stiffness_n_m=k, damping_n_s_m=2e5)
    sim = Simulator(preset("s30"), model, dt_s,
                    actuator=ActuatorParams(motor=MotorParams(), drive=DriveParams(mode="position"), stops=stops))
    rows = []
    for _ in range(int(round(0.6 / dt_s))):
        o = sim.step(-0.004, load)
        blk = sim.layout.view(o.internal, "actuator")
        rows.append((o.nut_velocity_m_s, float(blk[Q["stop_force_n"]]), float(blk[Q["stop_penetration_m"]]),
                     load - o.nut_force_n, float(blk[Q["stop_absorbed_j"]]), float(blk[Q["energy_in_j"]]),
                     float(blk[Q["load_work_j"]]), float(blk[Q["dissipated_j"]]), float(blk[Q["stored_j"]])))
    v, force, depth, net, absorbed, e_in, load_work, diss, stored = np.array(rows).T
    rest = (np.abs(v) < 1e-6) & (depth > 0.0)
    assert rest[-1] and np.count_nonzero(rest) >= 2  # it came to rest in the stop and stayed
    assert np.all(np.abs(force[rest] - k * depth[rest]) <= k * 0.5e-6)  # the stop law at rest
    assert np.all(np.abs(force[rest] - net[rest]) <= 1e-6 * np.abs(net[rest]))  # the nut's static equilibrium
    assert np.all(np.diff(absorbed) >= -1e-9 * absorbed.max())
    through = np.abs(e_in) + np.abs(load_work) + np.abs(diss)
    books = STEP_BALANCE_TOL if model == "fu2018" else 1e-12
    assert np.all(np.abs(e_in - load_work - diss - stored) <= books * through)
