"""The compiled kernels (numba, `prsm_sim.models.kernels`) against the same source run uncompiled.

Oracle: the uncompiled run of the same model (`kernel="reference"`: the functions of models/kernels.py under
the Python interpreter), whose physics the other tests validate against closed forms, conservation and
fine-step solutions; this file checks that numba computes what the source says. Every output column, the internal loads and the final
state must agree to 1e-12 relative to each column's magnitude (absolute on columns near zero) over runs that
exercise each branch of the step: forward and back-driving, reversals, stick and breakaway, sub-steps, the
viscous law, nut sliding, exponential load distribution (fu2018); backlash with impacts, oversize and double
nut preload, Stribeck decay, a widened clearance (elastic). Both the batch path (`Model.run`) and the per-step
path (`Model.step`) are compared. Seen: bit-identical on all of these but the summed ledger columns (≤ 1e-15).
"""

from __future__ import annotations

import math
import pickle
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from prsm_sim import ParamError, Simulator, build_model, preset
from prsm_sim import OUTPUT_FIELDS

TOL = 1e-12
F_HEAVY = 20_000.0


def _assert_same(a, b, what):
    """Columns of two runs (mappings of arrays) agree to TOL of each column's largest magnitude (the energy
    residual: of the energy flow, the batch ledger sums it vectorised)."""
    for name in (b.keys() if hasattr(b, "keys") else b):
        x, y = np.asarray(a[name], dtype=float), np.asarray(b[name], dtype=float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), f"{what}: {name} NaN pattern"
        scale = float(np.nanmax(np.abs(y))) if np.any(np.isfinite(y)) else 0.0
        if name == "energy_residual_j":  # a sum of near-cancelling terms: its scale is the energy that flowed
            scale = max(scale, float(np.max(np.abs(b["energy_flow_j"]))))
        np.testing.assert_allclose(x, y, rtol=TOL, atol=TOL * scale, equal_nan=True, err_msg=f"{what}: {name}")


def _fields(s):
    """The state's fields, its model part's flattened in (`State.part`)."""
    d = {f: getattr(s, f) for f in s.__dataclass_fields__ if f != "part"}
    d.update(s.part._asdict() if hasattr(s.part, "_asdict") else {})
    return d


def _assert_state_same(s1, s2, what):
    a, b = _fields(s1), _fields(s2)
    assert a.keys() == b.keys(), what
    for f, x, y in ((f, a[f], b[f]) for f in b):
        scale = float(np.max(np.abs(y))) if np.size(y) else 0.0
        if f == "energy_residual_j":  # as in `_assert_same`
            scale = max(scale, s2.energy_flow_j)
        np.testing.assert_allclose(np.asarray(x, dtype=float), np.asarray(y, dtype=float), rtol=TOL,
                                   atol=TOL * scale, err_msg=f"{what}: state.{f}")


def _both(params, model, torque, load, state=None, step_prefix=150):
    """Batch runs on both kernels, compared column by column, with their internal loads and final states; then
    the per-step path on both kernels over the first `step_prefix` steps."""
    runs = {}
    for kernel in ("compiled", "reference"):
        m = build_model(params, model, 1e-3, kernel=kernel)
        s0 = state or m.initial_state()
        runs[kernel] = (m, s0, m.run(s0, torque, load))
    (mc, s0, tc), (mr, _, tr) = runs["compiled"], runs["reference"]
    _assert_same(tc, tr, f"{model} batch")
    _assert_same({"internal": tc.internal}, {"internal": tr.internal}, f"{model} batch")
    _assert_state_same(tc.final_state, tr.final_state, f"{model} batch")
    loads = np.broadcast_to(np.asarray(load, dtype=float), np.shape(torque))
    sc = sr = s0
    outs_c, outs_r = [], []
    for tau, f in zip(torque[:step_prefix].tolist(), loads[:step_prefix].tolist()):
        sc, oc = mc.step(sc, tau, f)
        sr, o_r = mr.step(sr, tau, f)
        outs_c.append(oc)
        outs_r.append(o_r)
    cols = {n: [getattr(o, n) for o in outs_c] for n, _ in OUTPUT_FIELDS}
    cols_r = {n: [getattr(o, n) for o in outs_r] for n, _ in OUTPUT_FIELDS}
    _assert_same(cols, cols_r, f"{model} per step")
    _assert_same({"internal": [o.internal for o in outs_c]}, {"internal": [o.internal for o in outs_r]},
                 f"{model} per step")
    _assert_state_same(sc, sr, f"{model} per step")
    # the batch and the per-step path of the compiled kernel are one computation
    _assert_same({n: tc[n][:step_prefix] for n, _ in OUTPUT_FIELDS}, cols, f"{model} batch vs per step")
    return tc


def _t(n):
    return 1e-3 * np.arange(n)


# -- fu2018 -------------------------------------------------------------------------------------------
def test_fu2018_forward_back_driving_and_reversals():
    p = preset("jones2016")  # 10 rollers × 40 teeth; the prsm-bench core run
    torque = 0.3 * np.sin(2 * math.pi * _t(1500)) + 0.1
    tr = _both(p, "fu2018", torque, 100.0)
    w = tr["screw_speed_rad_s"]
    assert np.any(w > 1.0) and np.any(w < -1.0)  # driven both ways
    assert np.any(tr["power_out_w"] < 0.0)  # the load back-drives it


def test_fu2018_stick_breakaway_and_sub_steps_at_20kn():
    p = preset("s30")  # pins on: the mechanism sticks between reversals
    torque = F_HEAVY * p.geometry.lead_per_rad_m + 8.0 * np.sin(2 * math.pi * _t(600))
    tr = _both(p, "fu2018", torque, F_HEAVY)
    assert np.sum(tr["screw_speed_rad_s"] == 0.0) > 20  # stuck steps
    assert np.any(np.abs(tr["screw_speed_rad_s"]) > 100.0)


@pytest.mark.parametrize("overrides", [
    {"friction.screw_roller_law": "viscous"},
    {"geometry.gear_ratio": 4.5, "friction.mu_nut_roller_sliding": 0.05},  # the nut contact slides
    {"friction.load_distribution": "exponential", "friction.coulomb_regularisation_m_s": 1e-5,
     "friction.mu_pin": 0.0},
])
def test_fu2018_friction_variants(overrides):
    p = preset("s30").with_overrides(overrides)
    torque = F_HEAVY * p.geometry.lead_per_rad_m + 3.0 * np.sin(2 * math.pi * 2.0 * _t(400))
    _both(p, "fu2018", torque, F_HEAVY, step_prefix=100)


@pytest.mark.parametrize("model", ["fu2018", "elastic"])
def test_drag_at_zero_load_holds_breaks_away_and_reverses(model):
    # the load-independent losses (docs/model.md §4.5): seals held at rest, film traction, idle flanks
    p = preset("s30").with_overrides({"drag.enabled": True})
    torque = 0.4 * np.sin(2 * math.pi * 3.0 * _t(300))  # within and beyond the no-load torque, both ways
    tr = _both(p, model, torque, 0.0, step_prefix=80)
    w = tr["screw_speed_rad_s"]
    assert np.any(w == 0.0) and np.any(w > 1.0) and np.any(w < -1.0)


# -- elastic ------------------------------------------------------------------------------------------
def _elastic_reversals(n):
    t = _t(n)
    ramp = np.clip(t / 0.05, 0, 1)
    return ramp * (4.3 + 3.0 * np.sin(2 * math.pi * 5.0 * t)), 5000.0 * ramp  # prsm-bench elastic, faster


@pytest.mark.slow
@pytest.mark.parametrize("overrides", [
    {},  # Hertz chain, Stribeck decay and breakaway (s30 defaults)
    {"elastic.axial_clearance_m": 50e-6, "elastic.contact_damping_ratio": 0.02},  # backlash, impacts
    {"elastic.preload_n": 2000.0, "elastic.preload_kind": "oversize_rollers"},
    {"elastic.preload_n": 2000.0, "elastic.preload_kind": "double_nut"},  # halves lift off at 2.8 P0
    {"stiction.breakaway_ratio": 1.0},  # fu2018's friction alone (its own stick)
])
def test_elastic_branches(overrides):
    p = preset("s30").with_overrides(overrides)
    torque, load = _elastic_reversals(250)
    _both(p, "elastic", torque, load, step_prefix=80)


def test_elastic_hard_reversals_through_backlash_and_a_widened_clearance():
    # ±2 N·m square torque against a 1 kN load into 50 µm of play, plus 20 µm more carried in the state (the
    # actuator's growing-backlash fault): the nut crosses the play and hits the other flank
    p = preset("s30").with_overrides({"elastic.axial_clearance_m": 50e-6})
    n = 300
    sign = np.where((np.arange(n) // 50) % 2 == 0, 1.0, -1.0)
    model = build_model(p, "elastic", 1e-3, kernel="reference")
    state = replace(model.initial_state(), extra_clearance_m=20e-6)
    tr = _both(p, "elastic", 6.0 * sign, 1000.0 * sign, state=state, step_prefix=120)
    lost = tr.internal_quantity("elastic", "lost_motion_m")
    assert np.any(lost > 0) and np.any(lost < 0)  # crossed the play both ways


# -- the switch ---------------------------------------------------------------------------------------
def test_bad_kernel_is_one_line_naming_field_value_and_allowed():
    for make in (lambda: Simulator(preset("s30"), "fu2018", 1e-3, kernel="fast"),
                 lambda: build_model(preset("s30"), "jones2016", 1e-3, kernel="fast")):
        with pytest.raises(ParamError) as e:
            make()
        msg = str(e.value)
        assert "\n" not in msg and "kernel = 'fast'" in msg and "'compiled'" in msg and "'reference'" in msg


def test_default_is_compiled_and_pickling_keeps_the_choice():
    sim = Simulator(preset("s30"), "elastic", 1e-3)
    assert sim.model.kernel == "compiled" and sim.model.core.kernel == "compiled"
    sim.step(1.0, 100.0)
    twin = pickle.loads(pickle.dumps(sim))
    assert twin.step(1.0, 100.0).screw_angle_rad == sim.step(1.0, 100.0).screw_angle_rad
    for name in ("fu2018", "elastic"):  # a sweep worker gets the path it was given
        ref = pickle.loads(pickle.dumps(build_model(preset("s30"), name, 1e-3, kernel="reference")))
        assert ref.kernel == "reference" and not hasattr(ref._kn.step, "py_func")  # the source, uncompiled


def test_import_prsm_sim_does_not_import_numba():
    code = "import prsm_sim, sys; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "False"


def test_the_compiled_record_step_is_cached_with_the_ledger_it_was_built_from():
    """`kernels.step_record` inlines the energy ledger from `stepping.ledger`; numba keys its disk cache on
    kernels.py alone, so kernels.py names the ledger's fingerprint and `load` skips the cache when they differ.
    Oracle: the fingerprint of the ledger's source and constants as they are now. On a change of the ledger,
    set `kernels.LEDGER_FINGERPRINT` to `kernels.ledger_fingerprint()`."""
    from prsm_sim.models import kernels

    assert kernels.ledger_fingerprint() == kernels.LEDGER_FINGERPRINT
