"""The packed per-step path (`Simulator.step`: the model's `step_packed`, state kept as the packed record,
outputs derived when read) against `Model.step` (the same step, its State unpacked and its Outputs built field
by field): every output, the internal vector and the state agree to 1e-12 (relative to the quantity's scale;
the energy residual relative to the energy that flowed) over runs with reversals, stops, stick, flank
switches, a self-locking load, backlash and preload, and through state reads, assignments and pickling."""

from __future__ import annotations

import math
import pickle
from dataclasses import replace

import numpy as np
import pytest

from prsm_sim import OUTPUT_FIELDS, Outputs, Simulator, preset
from prsm_sim.errors import InputError
from prsm_sim import State
from prsm_sim.stepping.packed import PackedOutputs

CASES = [("ideal", "s30"), ("jones2016", "s30"), ("jones2016", "jones2016")]
STATE_FIELDS = ("time_s", "screw_angle_rad", "screw_speed_rad_s", "carrier_angle_rad", "carrier_speed_rad_s",
                "work_in_j", "work_out_j", "dissipated_j", "energy_flow_j")


def _rows(out: Outputs) -> list[float]:
    return [getattr(out, f) for f, _ in OUTPUT_FIELDS] + list(out.internal)


def _assert_close(got, want, sim, ref_state):
    """Every output and internal element to 1e-12 of its column's scale (the energy residual: of the energy
    that flowed, the guard's own scale), and the state's fields to 1e-12."""
    got, want = np.array(got), np.array(want)
    scale = np.maximum(np.nanmax(np.abs(want), axis=0), 1e-300)
    # the energy residual is rounding noise by design (~1e-14 J): judged against the energy that flowed,
    # the guard's own scale (stepping/ledger.py energy guard)
    names = [f for f, _ in OUTPUT_FIELDS]
    scale[names.index("energy_residual_j")] = scale[names.index("energy_flow_j")]
    assert np.array_equal(np.isnan(got), np.isnan(want))
    assert np.nanmax(np.abs(got - want) / scale) <= 1e-12
    s, r = sim.state, ref_state
    for f in STATE_FIELDS:
        a, b = getattr(s, f), getattr(r, f)
        assert math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12 * max(1.0, abs(b))), f
    # the model's own memory (fu2018's lagged forces and solver memory, elastic's nut and chain state)
    for f in sim.model.extra_state_fields:
        np.testing.assert_allclose(getattr(s, f), getattr(r, f), rtol=1e-12, atol=1e-300, err_msg=f)


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
        got.append(_rows(out))
        want.append(_rows(ref_out))
        if k % 500 == 0:  # reading the state mid-run and stepping on gives the same run
            assert isinstance(sim.state, State)
    _assert_close(got, want, sim, ref_state)
    assert sim.nstep == n


# fu2018 and elastic through what changes their friction state: a speed loop driving a resisting load at
# +20 rad/s, braking to rest and held there by friction (stick) under the torque that balances the load
# without friction, the reverse stroke with the load reversed (the loaded flanks switch), braking and
# holding. Options: fu2018's nut sliding (g ≠ r_N/r_R) and heavy load with pin and rolling friction;
# elastic's backlash, preload (oversize rollers, double nut), Stribeck breakaway (the preset's) and the
# growing-backlash fault (extra clearance set in the state mid-run, as the actuator does); every run's energy
# books are opened mid-run so that the guard's verdict trips on both paths. `drive`: the
# loop's feed-forward torque over p F (the heavy load needs more than the loop's integral builds up in a
# stroke to break away).
RICH_CASES = [
    ("fu2018", {}, 1000.0, 1.0),
    ("fu2018", {"geometry.gear_ratio": 4.5, "friction.mu_nut_roller_sliding": 0.05}, 1000.0, 1.0),
    ("fu2018", {"friction.mu_pin": 0.1, "friction.mu_nut_roller_rolling": 0.005}, 20_000.0, 1.4),
    ("elastic", {}, 1000.0, 1.0),
    ("elastic", {"elastic.axial_clearance_m": 50e-6}, 1000.0, 1.0),
    ("elastic", {"elastic.preload_n": 3000.0, "elastic.preload_kind": "oversize_rollers"}, 1000.0, 1.0),
    ("elastic", {"elastic.preload_n": 1000.0, "elastic.preload_kind": "double_nut"}, 4000.0, 1.0),
]


@pytest.mark.parametrize("model,overrides,load_n,drive", RICH_CASES)
def test_packed_step_matches_reference_through_stick_reversals_and_contact(model, overrides, load_n, drive):
    p = preset("s30").with_overrides(overrides)
    sim = Simulator(p, model, 1e-3)
    assert sim.model.packed
    ref_model, ref_state = sim.model, sim.state
    lead = p.geometry.lead_per_rad_m
    n = 600 if model == "fu2018" else 240
    got, want, speeds, flanks, stuck = [], [], [], set(), 0
    integ = 0.0
    for k in range(n):
        phase = (k * 4 // n) % 4
        if k % (n // 4) == 0:
            integ = 0.0
        if phase in (0, 2):  # speed loop (inputs from the reference state, the same for both paths)
            target = 20.0 if phase == 0 else -20.0
            err = target - ref_state.screw_speed_rad_s
            integ += err * 1e-3
            load = math.copysign(load_n, target)
            torque = drive * lead * load + 0.05 * err + 2.0 * integ
        else:  # the torque that balances the load without friction: friction brakes the screw and holds it
            load = load_n if phase == 1 else -load_n
            torque = lead * load
        if k == n // 2:
            # books that do not close (a residual of 1 % of the flow): the energy guard's verdict from here on;
            # elastic: the growing-backlash fault widens the clearance
            fault = {"energy_residual_j": 0.01 * ref_state.energy_flow_j + 1e-3,
                     **({"extra_clearance_m": 20e-6} if model == "elastic" else {})}
            sim.state = replace(sim.state, **fault)
            ref_state = replace(ref_state, **fault)
        out = sim.step(torque, load)
        ref_state, ref_out = ref_model.step(ref_state, torque, load)
        got.append(_rows(out))
        want.append(_rows(ref_out))
        speeds.append(ref_state.screw_speed_rad_s)
        flanks.add(ref_state.flank_sign)
        stuck += ref_state.screw_speed_rad_s == 0.0 and ref_state.carrier_speed_rad_s == 0.0 and k > 0
    speeds = np.array(speeds)
    fault = np.array(want)[:, [f for f, _ in OUTPUT_FIELDS].index("energy_fault")]
    assert not fault[: n // 2].any() and fault[-1] == 1.0  # the guard tripped on the books, not before
    assert speeds.max() > 15.0 and speeds.min() < -15.0 and flanks == {1, -1} and stuck > 10  # the run did all that
    if model == "elastic" and overrides.get("elastic.axial_clearance_m"):
        lost = np.array(want)[:, len(OUTPUT_FIELDS) + sim.layout.offsets()["elastic"] + 1]
        assert np.any(lost > 0) and np.any(lost < 0)  # crossed the play both ways
    _assert_close(got, want, sim, ref_state)
    assert sim.state == sim.model.unpack_state(sim.model.pack_state(sim.state))


@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018", "elastic"])
def test_packed_outputs_behave_as_records(model):
    """The lazy record reads as the eager one: every field, the bulk readers, pickling, immutability."""
    sim = Simulator(preset("s30"), model, 1e-3)
    sim.step(0.01, 10.0)
    out = sim.step(0.02, -5.0)
    assert type(out) is PackedOutputs and isinstance(out, Outputs)
    by_field = tuple(getattr(out, f) for f, _ in OUTPUT_FIELDS)

    def same(a, b):  # NaN (an undefined efficiency at start-up) reads as NaN on both
        return np.array_equal(np.array(a, dtype=float), np.array(b, dtype=float), equal_nan=True)
    assert same(out.scalar_values(), by_field) and same(tuple(out.scalars().values()), by_field)
    assert out.internal.shape == (sim.layout.size,) and out.internal is out.internal  # built once
    plain = pickle.loads(pickle.dumps(out))  # travels as a plain Outputs record
    assert type(plain) is Outputs and same(plain.scalar_values(), by_field)
    assert np.array_equal(plain.internal, out.internal) and out != sim.step(0.0, 0.0)
    if not math.isnan(out.efficiency) and not math.isnan(out.speed_ratio):
        assert out == plain
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


@pytest.mark.parametrize("kernel,n", [("compiled", 400), ("reference", 150)])
def test_fu2018_per_step_path_adds_no_rounding_to_its_kernel(kernel, n):
    """`Simulator.step` on fu2018 is `kernels.step` plus the ledger, bit for bit: the speeds, the angles summed
    from the kernel's increments, the dissipation, the nut force and the friction state (kept in the packed
    state in the kernel's own form) equal a bare loop over the kernel, through stick and break-away under
    5 kN (the closed form to compare with is the kernel itself: the wrapper must add nothing to it)."""
    from prsm_sim.models import kernels

    sim = Simulator(preset("s30"), "fu2018", 1e-3, kernel=kernel)
    m = sim.model
    k_arr, s_arr = m.kernel_constants
    load = 5000.0
    hold = m.geo.lead_per_rad_m * load  # the frictionless holding torque: friction alone decides stick
    ws = wc = th_s = th_c = 0.0
    sign, pin_abs, gear, mem = 1.0, 0.0, 0.0, kernels.NO_MEMORY
    for k in range(n):
        tau = hold + 0.6 * math.sin(0.03 * k)
        out = sim.step(tau, load)
        ws, wc, dth_s, dth_c, diss, f1, sign, pin_abs, gear, mem = m._kn.step(
            ws, wc, sign, pin_abs, gear, mem, tau, load, k_arr, s_arr)
        th_s, th_c = th_s + dth_s, th_c + dth_c
        assert (out.screw_speed_rad_s, out.carrier_speed_rad_s, out.screw_angle_rad, out.carrier_angle_rad,
                out.nut_force_n) == (ws, wc, th_s, th_c, f1[27])
        assert out.power_dissipated_w == diss / 1e-3
    part = sim.state.part
    assert part == (int(sign), pin_abs, gear, kernels.memory_from_kernel(mem))
    assert type(part.flank_sign) is int


@pytest.mark.parametrize("kernel,n", [("compiled", 600), ("reference", 150)])
def test_fu2018_compiled_record_is_the_generic_ledgers_bit_for_bit(kernel, n):
    """fu2018 makes its per-step record in one compiled call (`kernels.step_record`: the step, the books and the
    rigid nut); every other model makes it with the ledger's generic form (`Model.finisher`). Oracle: that
    generic form fed the same kernel step gives the same record, every item and the end forces, bit for bit,
    through stick, break-away, reversals and back-driving under ±5 kN."""
    sim = Simulator(preset("s30"), "fu2018", 1e-3, kernel=kernel)
    m = sim.model
    k_arr, s_arr = m.kernel_constants
    finish = m.finisher(lambda w_s, w_c, aux: 0.0, lambda w_s, w_c, aux: ())
    hold = m.geo.lead_per_rad_m * 5000.0
    x = sim._packed
    for k in range(n):
        load = 5000.0 if k < n // 2 else -5000.0
        tau = math.copysign(hold, load) + 0.6 * math.sin(0.03 * k)
        rec = m.step_packed(x, tau, load)
        sign, pin_abs, gear, mem = x[11]
        ws1, wc1, dth_s, dth_c, diss, f1, sign, pin_abs, gear, mem = m._kn.step(
            x[2], x[4], sign, pin_abs, gear, mem, tau, load, k_arr, s_arr)
        want = finish(x, x[1] + dth_s, ws1, x[3] + dth_c, wc1, tau, load, diss, m.stored_energy_j(ws1, wc1),
                      (sign, pin_abs, gear, mem), f1, f1[27])
        assert rec[:21] == want[:21] and rec[22] == want[22], k
        x = rec


@pytest.mark.parametrize("model", ["fu2018", "elastic"])
def test_plain_state_round_trip_keeps_the_kernel_form_of_the_part(model):
    """get_state writes the part as `State` holds it (int flank sign, ``()`` for no solver memory); set_state
    takes it back into the kernel's form, and the run continues bit for bit."""
    import json

    a = Simulator(preset("s30"), model, 1e-3)
    for k in range(200):
        a.step(0.4 * math.cos(0.02 * k), 100.0)
    data = json.loads(json.dumps(a.get_state()))
    b = Simulator(preset("s30"), model, 1e-3)
    b.set_state(data)
    assert b.state == a.state
    for k in range(200):
        oa, ob = a.step(0.4 * math.sin(0.02 * k), -50.0), b.step(0.4 * math.sin(0.02 * k), -50.0)
        assert oa.scalar_values() == ob.scalar_values()
    assert a.state == b.state
