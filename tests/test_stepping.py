"""The stepping layer (prsm_sim/stepping): one ledger in three forms, the State's model part, the named
kernel constants, the step's input names and the import rules that keep the layer at the bottom.

Oracles: the energy balance W_in − W_out − ΔE − W_diss (docs/model.md §4, "The energy ledger") computed by
hand; the parameters a model was built from; the module sources themselves (import graph).
"""

from __future__ import annotations

import ast
import math
import re
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from prsm_sim import InputError, Simulator, State, preset
from prsm_sim.models import kernels
from prsm_sim.models.elastic import ElasticPart
from prsm_sim.models.fu2018 import Fu2018Part
from prsm_sim.stepping.ledger import efficiency, efficiency_columns, energy_fault, ledger_columns, ledger_step
from prsm_sim.stepping.records import OUTPUT_FIELDS

ROOT = Path(__file__).resolve().parent.parent


def test_ledger_scalar_and_column_forms_are_one_rule():
    rng = np.random.default_rng(3)
    n = 50
    tau, dth, w_out, diss = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n), rng.random(n)
    stored = rng.random(n)
    w_in, flow, residual, fault = ledger_columns(2.0, 0.5, 0.25, tau, dth, w_out, diss, stored)
    f, r, e0 = 2.0, 0.5, 0.25
    for k in range(n):
        wi, f_next, r_next, verdict = ledger_step(f, r, tau[k], dth[k], w_out[k], diss[k], e0, stored[k])
        assert wi == tau[k] * dth[k]
        assert f_next == pytest.approx(f + max(abs(wi), abs(w_out[k])), rel=1e-15)  # the larger port work
        # the balance by hand: input work less output work, the change of stored energy and the dissipation
        miss = tau[k] * dth[k] - w_out[k] - (stored[k] - e0) - diss[k]
        assert r_next - r == pytest.approx(miss, rel=1e-12, abs=1e-12)
        assert verdict == (f_next > 1.0 and abs(r_next) > 1e-3 * f_next)
        f, r, e0 = f_next, r_next, stored[k]
        assert (flow[k], residual[k], w_in[k], fault[k]) == (f, r, wi, verdict)  # the same sums: the same bits
    assert bool(energy_fault(2.0, 0.003)) and not energy_fault(2.0, 0.001) and not energy_fault(0.5, 0.4)
    np.testing.assert_array_equal(energy_fault(np.array([2.0, 2.0]), np.array([0.003, 0.001])), [True, False])
    # steady forward, steady backward, a self-locking screw driven back (no power through), accelerating (the
    # stored energy takes 1.5 W of 3 W), friction giving power back, standstill
    p_in = np.array([3.0, -1.0, 1.0, 3.0, 2.0, 0.0])
    p_out = np.array([2.0, -2.0, -1.0, 1.0, 2.1, 0.0])
    p_d = np.array([1.0, 1.0, 2.0, 0.5, -0.1, 0.0])
    cols = efficiency_columns(p_in, p_out, p_d)
    np.testing.assert_array_equal(cols, [efficiency(a, b, c) for a, b, c in zip(p_in, p_out, p_d)])
    assert cols[:2].tolist() == [2.0 / 3.0, 0.5] and np.isnan(cols[2:]).all()


def test_state_holds_the_models_own_part_and_reads_its_fields_by_name():
    p = preset("s30")
    fu = Simulator(p, "fu2018").state
    el = Simulator(p, "elastic").state
    ideal = Simulator(p, "ideal").state
    assert type(fu.part) is Fu2018Part and type(el.part) is ElasticPart and ideal.part == ()
    assert fu.flank_sign == 1 and el.nut_speed_m_s == 0.0 and ideal.flank_sign == 1  # a part's default
    wider = replace(el, extra_clearance_m=2e-5)
    assert wider.part.extra_clearance_m == 2e-5 and wider.extra_clearance_m == 2e-5 and el.extra_clearance_m == 0.0
    assert replace(ideal, extra_clearance_m=0.0) == ideal
    with pytest.raises(InputError, match="extra_clearance_m = 2e-05: this model's state has no extra_clearance_m"):
        replace(ideal, extra_clearance_m=2e-5)
    with pytest.raises(InputError, match="unknown field 'bogus'"):
        State(bogus=1.0)
    with pytest.raises(AttributeError):
        ideal.bogus  # noqa: B018


def test_kernel_constants_are_named_and_the_kernels_read_them_by_name():
    p = preset("s30")
    fu = Simulator(p, "fu2018").model
    el = Simulator(p, "elastic").model
    # the array the kernel reads is the NamedTuple, field for field
    for model, array, cls in ((fu, fu.kernel_constants[0], kernels.Fu2018Constants), (el, el._kernel_e, kernels.ElasticConstants)):
        assert type(model.constants) is cls and array.tolist() == [float(v) for v in model.constants]
    assert fu.constants.p == p.geometry.lead_per_rad_m and fu.constants.h == 1e-3
    assert fu.constants.nr == p.geometry.n_rollers and fu.constants.mu == p.friction.mu_screw_roller
    assert el.constants.m == p.mass.moved_mass_kg and el.constants.zeta == p.elastic.contact_damping_ratio
    src = (ROOT / "prsm_sim/models/kernels.py").read_text(encoding="utf-8")
    for short, cls in (("FU", kernels.Fu2018Constants), ("EL", kernels.ElasticConstants),
                       ("FL", kernels.FlankConstants)):
        used = set(re.findall(rf"\b{short}\.([a-z0-9_]+)", src))
        assert used and used <= set(cls._fields), used - set(cls._fields)
    assert not re.search(r"\b[KE]\[\d+\]", src)  # no constant read by a bare position


def test_step_names_its_first_input_and_keeps_torque_nm_for_one_release():
    p = preset("s30")
    a, b = Simulator(p, "ideal"), Simulator(p, "ideal")
    with pytest.warns(DeprecationWarning, match="step\\(command, load_n\\)"):
        old = b.step(torque_nm=0.05, load_n=10.0)
    assert a.step(0.05, 10.0) == old
    with pytest.raises(InputError, match="give one of them"):
        a.step(0.05, 10.0, torque_nm=0.05)
    with pytest.raises(InputError, match="torque_nm = nan"):
        a.step(math.nan)
    from prsm_sim.actuator import ActuatorParams
    act = Simulator(p, "ideal", actuator=ActuatorParams())
    assert act.command_name == "command"
    with pytest.raises(InputError, match="command = nan"):
        act.step(math.nan)
    with pytest.raises(InputError, match="command = 0.1: run\\(\\) takes a 1-D array with one command per step"):
        act.run(0.1)


def _imports(path: Path, modules) -> set[str]:
    """Every prsm_sim module a file imports, at module level or inside functions (TYPE_CHECKING blocks excepted);
    ``from package import module`` counts as importing the module."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for n in ast.walk(node)}
    out = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("prsm_sim"):
            subs = {f"{node.module}.{a.name}" for a in node.names} & modules
            out |= subs if len(subs) == len(node.names) else subs | {node.module}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("prsm_sim")}
    return out


def _module(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    return ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)


def test_stepping_imports_only_the_records_below_it_and_models_not_their_registry():
    """Finer than the layer table (tests/test_layers.py, which also holds the no-cycle and the
    private-name rules): the stepping layer reads errors, checks and parameters only, and a model
    never imports the registry above it (both sit in one unit there)."""
    files = {_module(f): f for f in (ROOT / "prsm_sim").rglob("*.py")}
    graph = {m: {i for i in _imports(f, files.keys()) if i in files and i != m} for m, f in files.items()}
    allowed = ("prsm_sim.stepping", "prsm_sim.errors", "prsm_sim.checks", "prsm_sim.params")
    for m in (m for m in graph if m.startswith("prsm_sim.stepping")):
        above = {i for i in graph[m] if not i.startswith(allowed)}
        assert not above, f"{m} imports above the stepping layer: {above}"
    for m in (m for m in graph if m.startswith("prsm_sim.models.") and not m.endswith(("registry", "base"))):
        assert "prsm_sim.models.registry" not in graph[m], m


@pytest.mark.parametrize("model", ["ideal", "fu2018"])
def test_simulators_with_and_without_an_actuator_pickle_and_step_on_alike(model):
    import pickle

    from prsm_sim.actuator import ActuatorParams
    p = preset("s30")
    for sim in (Simulator(p, model), Simulator(p, model, actuator=ActuatorParams())):
        sim.step(0.05, 100.0)
        twin = pickle.loads(pickle.dumps(sim))
        assert type(twin.model) is type(sim.model) and twin.model.name == sim.model.name
        assert getattr(twin.model, "model_name", None) == getattr(sim.model, "model_name", None)
        a, b = twin.step(0.05, 100.0), sim.step(0.05, 100.0)
        assert a.scalars() == b.scalars() and np.array_equal(a.internal, b.internal)


def test_old_import_paths_are_aliases_of_the_new_homes():
    with warnings.catch_warnings():  # their import says they are deprecated, an error where the shell asks for one
        warnings.simplefilter("ignore", DeprecationWarning)
        import prsm_sim.models.base as base
        import prsm_sim.outputs as outputs
    from prsm_sim import params, stepping
    from prsm_sim.models import elastic, kernels, registry
    from prsm_sim.stepping import ledger, packed, trajectory
    assert base.Model is stepping.Model and base.energy_fault is ledger.energy_fault
    assert base.efficiency is ledger.efficiency and base.trajectory_from_rows is trajectory.trajectory_from_rows
    assert base.check_kernel is kernels.check_kernel and base.load_kernels is kernels.load
    assert outputs.State is State and outputs.PackedOutputs is packed.PackedOutputs
    assert outputs.Trajectory is trajectory.Trajectory
    assert params.Elastic is params.ElasticParams and elastic.Elastic is elastic.ElasticModel
    assert registry.MODELS["elastic"] is elastic.ElasticModel


@pytest.mark.parametrize("model", ["ideal", "jones2016", "fu2018", "elastic"])
def test_packed_record_values_are_its_fields_bit_for_bit(model):
    """`PackedOutputs.scalar_values` (written out in one place for the per-step path) gives each field exactly as
    its property reads it, and `step_from` on a packed state is `step`: the same record, the same next state, bit
    for bit, over a run through start-up (NaN efficiency), reversals and a load that drives the screw.

    Oracle: the record's own properties, one call per field, and `Model.step` (the public contract)."""
    sim = Simulator(preset("s30"), model, 1e-3)
    m, state = sim.model, sim.state
    fields = [n for n, _ in OUTPUT_FIELDS]
    for k in range(60):
        torque, load = (2.0 if k % 20 < 10 else -2.0), (300.0 if k % 15 < 8 else -900.0)
        rec = m.step_from(m.pack_state(state), torque, load)
        nxt, out = m.step(state, torque, load)
        by_field = tuple(getattr(rec, n) for n in fields)
        assert np.array(rec.scalar_values()).tobytes() == np.array(by_field).tobytes()
        assert np.array(out.scalar_values()).tobytes() == np.array(by_field).tobytes()
        assert rec.to_outputs().internal.tobytes() == out.internal.tobytes()
        assert m.unpack_state(rec) == nxt and repr(m.unpack_state(rec)) == repr(nxt)
        state = nxt
    with pytest.raises(InputError, match="torque_nm"):
        m.step_from(m.pack_state(state), math.nan, 0.0)


@pytest.mark.parametrize("record", ["State", "Outputs", "ActuatorState", "Ledger"])
def test_hand_written_record_constructors_take_the_declared_fields_and_defaults(record):
    """The records made every step set their slots in a constructor of their own (faster than the generated one):
    it takes every declared field, in order, with the declared default, and makes a record equal field by field
    to the one those values describe. Oracle: the dataclass field declarations."""
    import dataclasses
    import inspect

    from prsm_sim.actuator.actuator import ActuatorState, Ledger
    from prsm_sim.stepping.records import Outputs
    cls = {"State": State, "Outputs": Outputs, "ActuatorState": ActuatorState, "Ledger": Ledger}[record]
    params = [p for p in inspect.signature(cls.__init__).parameters.values()
              if p.name != "self" and p.kind is not inspect.Parameter.VAR_KEYWORD]
    declared = dataclasses.fields(cls)
    assert [p.name for p in params] == [f.name for f in declared]
    for p, f in zip(params, declared):
        if f.default is dataclasses.MISSING:  # `State` declares none: its constructor's zeros are the state at rest
            assert record == "State" or p.default is inspect.Parameter.empty, f.name
        else:
            assert p.default == f.default or (p.default != p.default and f.default != f.default), f.name  # NaN too
    values = {f.name: (State() if f.name == "screw" else float(k) + 0.5) for k, f in enumerate(declared)}
    made = cls(**values)
    assert all(getattr(made, n) is v for n, v in values.items())
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(made, declared[1].name, 1.0)
