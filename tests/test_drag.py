"""The load-independent losses of a real screw (`drag` parameters, models/drag.py, docs/model.md §4.5).

Independent numbers: the seal torque's closed form T_s = n f′ 2π r_S² (a lip's friction per unit of
circumference acting at the screw radius); the idle flanks' friction against the sliding-only efficiency of
docs/model.md §4.2, T = 2 P_i (L/2π)(1/η_f − 1); the preload drag torque against the ball-screw vendors'
published formula T_p = K F_p P_h/(2π), K = 0.05 (tan λ)^−½ (NSK "Precision Machine Components" catalogue,
ball screws, "preload dynamic torque"); the carrier's kinematic ratio (docs/model.md §2); conservation (the
ledger); the needle bearing's coefficient 0.0020 (SKF "Rolling bearings" 2016, table 1); the limit v → 0⁺
of steady running for the torque the drag holds at rest.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from prsm_sim import ParamError, Simulator, preset
from prsm_sim.params import DragParams
from prsm_sim.models import drag
from prsm_sim.models.elastic import sliding_efficiencies
from prsm_sim.scenarios import ScenarioSpec, run_scenario

def s30(overrides=None):
    """The `s30` preset (its drag on; a parameter set's default, like the papers' presets, has it off)."""
    return preset("s30").with_overrides(overrides or {})


QUIET = {"drag.film_area_m2": 0.0, "friction.lubricant_viscosity_m2_s": 0.0}  # no film, no Couette drag


def _no_load(p, model, w, seconds=1.0, load=0.0):
    tr = run_scenario(Simulator(p, model, 1e-3), ScenarioSpec("probe", load, speed_rad_s=w), seconds)
    return tr, float(np.mean(tr["screw_torque_nm"][-100:])), tr["carrier_speed_rad_s"][-1] / tr["screw_speed_rad_s"][-1]


def test_unloaded_screw_needs_a_torque_rising_with_speed_and_drives_its_carrier():
    # s30 with the drag on, fu2018, 1 ms, zero load, the PI speed loop
    p = s30()
    tr10, t10, r10 = _no_load(p, "fu2018", 10.0)
    _, t100, _ = _no_load(p, "fu2018", 100.0)
    _, _, r_loaded = _no_load(p, "fu2018", 100.0, load=5000.0)
    assert t10 > 0.01 and t100 > t10
    assert abs(r10 / r_loaded - 1.0) < 0.05  # the carrier runs at its loaded ratio, not left behind
    # the ledger books the drag as dissipation: the books close
    assert abs(tr10["energy_residual_j"][-1]) <= 1e-4 * tr10["energy_flow_j"][-1]


def test_seal_torque_is_its_closed_form():
    p = s30({**QUIET, "drag.internal_preload_n": 0.0})
    d, r = p.drag, p.geometry.screw_radius_m
    closed = d.n_seals * d.seal_friction_n_per_m * 2 * math.pi * r * r
    assert drag.seal_torque_nm(p) == pytest.approx(closed, rel=1e-12)
    _, t, _ = _no_load(p, "fu2018", 10.0, seconds=0.5)
    assert t == pytest.approx(closed, rel=1e-3)


def test_idle_flank_friction_follows_the_sliding_efficiency():
    # pins and rolling resistance off: what is left is screw–roller sliding on both flank sets
    p = s30({**QUIET, "drag.seal_friction_n_per_m": 0.0, "friction.mu_pin": 0.0,
                                      "friction.mu_nut_roller_rolling": 0.0})
    eta_f = sliding_efficiencies(p.geometry, p.friction.mu_screw_roller)[0]
    closed = 2 * p.drag.internal_preload_n * p.geometry.lead_per_rad_m * (1 / eta_f - 1)
    _, t, _ = _no_load(p, "fu2018", 10.0, seconds=0.5)
    assert t == pytest.approx(closed, rel=0.1)


def test_elastic_preload_torque_rises_with_the_preload_as_the_vendor_formula():
    torques = []
    for f_p in (0.0, 2000.0, 5000.0):
        p = s30({"elastic.preload_n": f_p,
                                          "elastic.preload_kind": "oversize_rollers" if f_p else "none"})
        torques.append(_no_load(p, "elastic", 10.0, seconds=0.4)[1])
    assert torques[0] < torques[1] < torques[2]
    g = s30().geometry
    k = 0.05 / math.sqrt(g.lead_m / (math.pi * 2 * g.screw_radius_m))  # NSK: K = 0.05 (tan λ)^-1/2
    for f_p, t in zip((2000.0, 5000.0), torques[1:]):
        vendor = k * f_p * g.lead_m / (2 * math.pi)
        assert 0.65 < (t - torques[0]) / vendor < 1.35  # a ball screws' rule of thumb: the same size


def test_stick_and_breakaway_at_rest_with_no_load():
    p = s30()
    t_s = drag.seal_torque_nm(p)
    sim = Simulator(p, "fu2018", 1e-3)
    for _ in range(200):
        out = sim.step(0.8 * t_s, 0.0)
    assert out.screw_speed_rad_s == 0.0 and out.screw_angle_rad == 0.0  # held: no creep
    sim = Simulator(p, "fu2018", 1e-3)
    for _ in range(200):
        out = sim.step(1.5 * drag.ideal_no_load_torque_nm(p, 0.9), 0.0)
    assert out.screw_speed_rad_s > 1.0  # broken away
    assert abs(out.energy_residual_j) <= 1e-4 * out.energy_flow_j


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_the_drag_holds_the_screw_at_rest_up_to_the_torque_it_runs_with(direction):
    """All of the drag is Coulomb friction (seals, idle flanks, the pin and rolling friction their forces drive),
    so at rest it holds the screw up to its sliding value, and a screw breaks away at no less than it runs with.
    Oracles: the limit v → 0⁺ of steady running, measured by the speed loop at 10 rad/s with the viscous terms
    off (`QUIET`; the regularised laws within 5e-5 of Coulomb there), which the hold must equal; the seals'
    closed form T_s, all the hold is without the idle flanks; T_s plus the idle flanks' closed form
    2 P_i (L/2π)(1/η_f − 1), a lower bound (the pins and the carrier's drive add to it). Before, only the
    seals held: s30 crept at 0.12 N·m, under half of the 0.26 N·m it runs with."""
    p = s30()
    k = Simulator(p, "fu2018", 1e-3).model.constants
    hold = k.hold_forward if direction > 0 else k.hold_backward
    _, running, _ = _no_load(s30(QUIET), "fu2018", 10.0 * direction, seconds=0.5)
    assert hold == pytest.approx(abs(running), rel=1e-3)
    eta_f = sliding_efficiencies(p.geometry, p.friction.mu_screw_roller)[0]
    assert hold >= drag.ideal_no_load_torque_nm(p, eta_f) > 2.0 * drag.seal_torque_nm(p)
    seals_only = Simulator(s30({"drag.internal_preload_n": 0.0}), "fu2018", 1e-3).model.constants
    for seals_hold in (seals_only.hold_forward, seals_only.hold_backward):
        assert seals_hold == pytest.approx(drag.seal_torque_nm(p), rel=1e-4)
    for frac, held in ((0.98, True), (1.02, False)):
        sim = Simulator(p, "fu2018", 1e-3)
        for _ in range(300):
            out = sim.step(direction * frac * hold, 0.0)
        if held:  # no creep at all
            assert out.screw_speed_rad_s == 0.0 and out.screw_angle_rad == 0.0
        else:
            assert direction * out.screw_speed_rad_s > 0.0 and direction * out.screw_angle_rad > 0.0
            assert abs(out.energy_residual_j) <= 1e-4 * out.energy_flow_j


@pytest.mark.parametrize("model", ["fu2018", "elastic"])
def test_a_nut_preloaded_to_hold_above_the_inertia_probe_still_has_its_inertia_probed(model):
    """The actuator probes the screw's inertia with two torques from rest (`actuator.implicit.probe_inertia`).
    A nut preloaded to 100 kN holds the screw up to 21.7 N·m, above both of the probe's first torques (10 and
    20 N·m), and the probe divided by zero there (envelope seeds 302 and 839); it raises its torques until the
    screw turns. Oracle: the inertia reflected to the screw by the mass matrix (docs/model.md §2), which the
    probe sees up to the friction that grows with the acceleration (pins, 3 % and 8 % here)."""
    from prsm_sim.actuator.implicit import PROBE_TORQUE_NM, probe_inertia
    from prsm_sim.physics.inertia import reflected_inertia
    over = ({"drag.internal_preload_n": 100e3} if model == "fu2018"
            else {"elastic.preload_n": 100e3, "elastic.preload_kind": "oversize_rollers"})
    p = s30(over)
    sim = Simulator(p, model, 1e-3)
    core = getattr(sim.model, "core", sim.model)
    assert core.constants.hold_forward > 2.0 * PROBE_TORQUE_NM
    assert probe_inertia(sim.model, 1e-3) == pytest.approx(reflected_inertia(p), rel=0.1)


def test_ideal_has_the_equivalent_no_load_torque():
    p = s30()
    eta_f = sliding_efficiencies(p.geometry, p.friction.mu_screw_roller)[0]
    t0 = drag.ideal_no_load_torque_nm(p, eta_f)
    assert t0 == pytest.approx(drag.seal_torque_nm(p) + 2 * p.drag.internal_preload_n * p.geometry.lead_per_rad_m
                               * (1 / eta_f - 1), rel=1e-12)
    sim = Simulator(p, "ideal", 1e-3)
    for _ in range(100):
        out = sim.step(0.9 * t0, 0.0)
    assert out.screw_speed_rad_s == 0.0
    _, t, _ = _no_load(p, "ideal", 10.0, seconds=0.5)
    assert t == pytest.approx(t0 + p.ideal.viscous_nm_s_rad * 10.0, rel=1e-3)


def test_drag_off_is_the_papers_screw():
    p = s30()
    off = p.with_overrides({"drag.enabled": False})
    zero = p.with_overrides({"drag.seal_friction_n_per_m": 0.0, "drag.film_area_m2": 0.0,
                             "drag.internal_preload_n": 0.0})
    assert drag.seal_torque_nm(off) == drag.film_traction_n_s_per_m(off) == drag.idle_flank_force_n(off) == 0.0
    # no drag at all: zero load and no torque leave the screw at rest; every magnitude at zero is the same run
    torque = 0.5 * np.sin(2 * math.pi * 1e-3 * np.arange(300)) + 1.0
    a, b = Simulator(off, "fu2018", 1e-3).run(torque, 200.0), Simulator(zero, "fu2018", 1e-3).run(torque, 200.0)
    assert np.array_equal(a["screw_speed_rad_s"], b["screw_speed_rad_s"])
    assert np.array_equal(a["carrier_speed_rad_s"], b["carrier_speed_rad_s"])
    # the papers' preset and a parameter set's defaults carry no drag; the catalogue-sized `s30` is a real screw
    assert not preset("jones2016").drag.enabled and not preset("jones2016_literal").drag.enabled
    assert not DragParams().enabled and preset("s30").drag.enabled


def test_needle_pins_raise_the_efficiency_and_bad_values_are_refused():
    p = s30()
    needle = p.with_overrides({"drag.pin_bearing": "needle"})
    assert drag.pin_friction_coefficient(needle) == 0.0020 and drag.pin_friction_coefficient(p) == p.friction.mu_pin
    eff = [float(np.nanmean(_no_load(q, "fu2018", 100.0, seconds=0.5, load=5000.0)[0]["efficiency"][-100:]))
           for q in (p, needle)]
    assert eff[1] > eff[0]
    with pytest.raises(ParamError, match=r"^drag.pin_bearing = 'ball': must be one of journal, needle$"):
        p.with_overrides({"drag.pin_bearing": "ball"})
    with pytest.raises(ParamError, match=r"^drag.film_thickness_m"):
        p.with_overrides({"drag.film_thickness_m": 0.0})


@pytest.mark.slow
def test_datasheet_no_load_torque_rises_with_the_preload_as_the_vendor_formula():
    # the datasheet's no-load probe (1 rad/s) runs until its tail is steady: at 5 kN the loop's integral action
    # needs about 2 s to build the preload torque, so a fixed 1 s run read a breakaway still under way
    from prsm_sim.datasheet import NO_LOAD_SPEED_RAD_S, _no_load_steady
    g = s30().geometry
    k = 0.05 / math.sqrt(g.lead_m / (math.pi * 2 * g.screw_radius_m))  # NSK: K = 0.05 (tan λ)^-1/2
    torques = []
    for f_p in (0.0, 2000.0, 5000.0):
        p = s30({"elastic.preload_n": f_p, "elastic.preload_kind": "oversize_rollers" if f_p else "none"})
        s, _ = _no_load_steady(p, "elastic", 1e-3)
        assert s["tail_speed_band"] <= 0.01 * NO_LOAD_SPEED_RAD_S  # a steady state, not a breakaway
        torques.append(s["tail_torque_nm"])
    for f_p, t in zip((2000.0, 5000.0), torques[1:], strict=True):
        vendor = k * f_p * g.lead_m / (2 * math.pi)  # T_p, a ball screws' rule: the same size and lead
        assert 0.65 < (t - torques[0]) / vendor < 1.35
    assert torques[2] - torques[0] > 2.0 * (torques[1] - torques[0])  # it keeps rising: 5 kN is 2.5 × 2 kN
