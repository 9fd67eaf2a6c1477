"""The packed per-step path (`Simulator.step` for models with `advance_packed`) against the
reference path (`Model.step`, records built field by field; the packed records derive most fields when read):
the same arithmetic up to the order of the sums, so every output, the internal vector and the state agree to 1e-12 (relative to the
quantity's scale; the energy residual relative to the energy that flowed) over a run with
reversals, stops and a self-locking load."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from prsm_sim import OUTPUT_FIELDS, Outputs, Simulator, preset
from prsm_sim.errors import InputError
from prsm_sim.outputs import PackedOutputs, State

CASES = [("ideal", "s30"), ("jones2016", "s30"), ("jones2016", "jones2016"), ("fu2018", "s30"), ("elastic", "s30")]


@pytest.mark.parametrize("model,name", CASES)
def test_packed_step_matches_reference(model, name):
    p = preset(name)
    sim = Simulator(p, model, 1e-3)
    assert sim.model.packed
    ref_model, ref_state = sim.model, sim.state
    rng = np.random.default_rng(7)
    n = 1500
    torque = 0.05 * np.sin(np.arange(n) * 0.02) + 0.01 * rng.standard_normal(n)
    load = np.where(np.arange(n) < n // 2, 50.0, -80.0) + rng.standard_normal(n)
    got, want = [], []
    for k in range(n):
        out = sim.step(float(torque[k]), float(load[k]))
        ref_state, ref_out = ref_model.step(ref_state, torque[k], load[k])
        assert isinstance(out, Outputs)
        got.append([getattr(out, f) for f, _ in OUTPUT_FIELDS] + list(out.internal))
        want.append([getattr(ref_out, f) for f, _ in OUTPUT_FIELDS] + list(ref_out.internal))
        if k % 500 == 0:  # reading the state mid-run and stepping on gives the same run
            assert isinstance(sim.state, State)
    got, want = np.array(got), np.array(want)
    scale = np.maximum(np.nanmax(np.abs(want), axis=0), 1e-300)
    # the energy residual is rounding noise by design (~1e-14 J): judged against the energy that flowed,
    # the guard's own scale (models/base.py energy guard)
    names = [f for f, _ in OUTPUT_FIELDS]
    if "energy_residual_j" in names:
        scale[names.index("energy_residual_j")] = scale[names.index("energy_flow_j")]
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert np.nanmax(np.abs(got - want) / scale) <= 1e-12
    s, r = sim.state, ref_state
    for f in ("time_s", "screw_angle_rad", "screw_speed_rad_s", "carrier_angle_rad", "carrier_speed_rad_s",
              "work_in_j", "work_out_j", "dissipated_j", "energy_flow_j"):
        a, b = getattr(s, f), getattr(r, f)
        assert math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12 * max(1.0, abs(b))), f
    assert sim.nstep == n


@pytest.mark.parametrize("model", ["ideal", "jones2016"])
def test_packed_outputs_behave_as_records(model):
    """The lazy record reads as the eager one: every field, the bulk readers, pickling, immutability."""
    sim = Simulator(preset("s30"), model, 1e-3)
    sim.step(0.01, 10.0)
    out = sim.step(0.02, -5.0)
    assert type(out) is PackedOutputs and isinstance(out, Outputs)
    by_field = tuple(getattr(out, f) for f, _ in OUTPUT_FIELDS)
    assert out.scalar_values() == by_field and tuple(out.scalars().values()) == by_field
    assert out.internal.shape == (sim.layout.size,) and out.internal is out.internal  # built once
    plain = pickle.loads(pickle.dumps(out))  # travels as a plain Outputs record
    assert type(plain) is Outputs and plain.scalar_values() == by_field
    assert np.array_equal(plain.internal, out.internal) and out == plain and out != sim.step(0.0, 0.0)
    for name in ("time_s", "nut_force_n", "internal", "anything"):
        with pytest.raises(AttributeError):
            setattr(out, name, 1.0)
    twin = pickle.loads(pickle.dumps(sim))  # a simulator pickles with its state (its model's steps are closures)
    assert twin.state == sim.state and twin.nstep == sim.nstep and twin.step(0.01, 3.0) == sim.step(0.01, 3.0)


def test_state_assignment_and_refusal_keep_the_packed_state_consistent():
    sim = Simulator(preset("s30"), "ideal", 1e-3)
    sim.step(0.02, 0.0)
    before = sim.state
    with pytest.raises(InputError, match="torque_nm"):
        sim.step(math.nan, 0.0)
    with pytest.raises(InputError, match="load_n"):
        sim.step(0.0, math.inf)
    assert sim.state == before and sim.time_s == before.time_s
    sim.state = State(time_s=5.0, screw_speed_rad_s=1.0)  # what the node does to roll back a step
    out = sim.step(0, 0)  # integers are accepted as numbers
    assert out.time_s == pytest.approx(5.001)


def test_ideal_batch_run_is_the_packed_step_repeated():
    """`Simulator.run` of a packed model without a batch form of its own gives the steps' outputs."""
    p = preset("s30")
    torque = 0.05 * np.sin(np.arange(400) * 0.05)
    traj = Simulator(p, "ideal", 1e-3).run(torque, 30.0)
    sim = Simulator(p, "ideal", 1e-3)
    outs = [sim.step(float(t), 30.0) for t in torque]
    for f, _ in OUTPUT_FIELDS:
        np.testing.assert_array_equal(traj[f], [getattr(o, f) for o in outs])
    assert traj.internal.shape == (400, 0) and traj.final_state == sim.state
