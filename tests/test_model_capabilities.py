"""Callers ask a model what it has (its class attributes) instead of comparing its name."""

import math

import pytest

from prsm_sim import ParamError, Simulator, preset
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
        out = sim.step(0.2, 100.0)
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
    # forward rolling: τ = F (L/2π)/η_f + b ω (the ideal model's efficiency law)
    tau = 1000.0 * p.geometry.lead_per_rad_m / p.ideal.efficiency_forward + p.ideal.viscous_nm_s_rad * 10.0
    assert math.isclose(ideal["torque_nm"], tau, rel_tol=1e-12)
    assert "torque_nm" in model_class("jones2016").steady_state_inputs
