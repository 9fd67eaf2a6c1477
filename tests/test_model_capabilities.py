"""Callers ask a model what it has (its class attributes) instead of comparing its name."""

import math

import pytest

from prsm_sim import ParamError, Simulator, preset
from prsm_sim.models.elastic import sliding_efficiencies
from prsm_sim.models.registry import MODELS, model_class
from prsm_sim.physics.kinematics import ideal_carrier_ratio


def test_model_class_names_the_field_for_an_unknown_model():
    with pytest.raises(ParamError, match=r"^model = 'nope': known models are"):
        model_class("nope")
    assert all(model_class(n) is c for n, c in MODELS.items())


@pytest.mark.parametrize("name", list(MODELS))
def test_capabilities_match_what_the_model_does(name):
    cls, p = model_class(name), preset("s30")
    sim = Simulator(p, name, 1e-3)
    for _ in range(5):
        out = sim.step(1.0, 100.0)  # above `s30`'s no-load torque (about 0.22 N·m, docs/model.md §4.5)
    assert out.screw_speed_rad_s > 0.0
    # a carrier of its own: it lags the ideal ratio ω_C = k ω_S while it spins up (its own inertia and drive)
    tied = out.carrier_speed_rad_s == pytest.approx(ideal_carrier_ratio(p.geometry) * out.screw_speed_rad_s, rel=1e-9)
    assert tied is not cls.has_carrier
    assert (sim.model.layout.size > 0) is cls.has_internal_forces
    # an axial chain: the nut moves on its own coordinate (elastic's state has the nut's axial position)
    assert ("nut_axial_m" in sim.model.extra_state_fields) is cls.has_axial_chain


def test_closed_form_steady_state_where_a_model_has_one():
    p = preset("s30")
    assert model_class("fu2018").closed_form_steady_state(p) is None
    ideal = model_class("ideal").closed_form_steady_state(p, screw_speed_rad_s=10.0, load_n=1000.0)
    # forward rolling: τ = F (L/2π)/η_f + b ω (the ideal model's efficiency law) + T₀, `s30`'s no-load torque: the
    # seals' n f′ 2π r_S² and both idle flank sets' 2 P_i (L/2π)(1/η_s − 1) at the sliding-only η_s
    # (docs/model.md §4.5, §4.2)
    g, d = p.geometry, p.drag
    eta_s = sliding_efficiencies(g, p.friction.mu_screw_roller)[0]
    t0 = (d.n_seals * d.seal_friction_n_per_m * 2 * math.pi * g.screw_radius_m ** 2
          + 2 * d.internal_preload_n * g.lead_per_rad_m * (1 / eta_s - 1))
    tau = 1000.0 * g.lead_per_rad_m / p.ideal.efficiency_forward + p.ideal.viscous_nm_s_rad * 10.0 + t0
    assert math.isclose(ideal["torque_nm"], tau, rel_tol=1e-12)
    assert "torque_nm" in model_class("jones2016").steady_state_inputs
