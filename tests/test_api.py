"""The library API a notebook uses: `from prsm_sim import Simulator, preset` and a few lines.

Covers the notebook flow (run, repr, keys, time_s, to_dataframe, labelled internal loads), the
refusal of a scalar torque by `Simulator.run`, `__version__`, `py.typed`, and the error family
(every deliberate raise in `prsm_sim` is a `PrsmError`). The one physics figure checked here,
the steady speed ratio, comes from Jones 2016 eq. 42 through the closed form of docs/model.md §4.1.
"""

from __future__ import annotations

import ast
import builtins
import doctest
import importlib.metadata
import importlib.resources
import math
import re
from pathlib import Path

import numpy as np
import pytest

import prsm_sim
from prsm_sim import (OUTPUT_FIELDS, InputError, ModelError, ParamError, PrsmError, Simulator, Trajectory,
                      preset)
from prsm_sim.models.jones2016 import steady_state

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def jones_run():
    """Jones 2016's example held at its steady torque for 1 s (≈ 6.6 screw time constants)."""
    sim = Simulator(preset("jones2016"), "jones2016", dt_s=1e-3)
    tau = steady_state(sim.params)["torque_nm"]  # 0.0922 N·m for 1 rad/s (docs/model.md §4.1)
    return sim, sim.run(np.full(1000, tau), load_n=100.0)


def test_notebook_flow_reaches_the_papers_steady_state(jones_run):
    sim, traj = jones_run
    assert isinstance(traj, Trajectory) and len(traj) == 1000 and sim.nstep == 1000
    # Jones 2016 eq. 42: ω_S/ω_C = 2.669 at the exact contact; the closed form gives 2.66903.
    # The carrier follows the screw quasi-statically; the screw's remaining acceleration
    # (≈ 9e-3 rad/s² after 6.6 time constants) shifts the ratio by 3.9e-8 relative.
    ratio = steady_state(sim.params)["speed_ratio_screw_over_carrier"]
    screw_over_carrier = 1.0 / traj["speed_ratio"][-1]
    assert screw_over_carrier == pytest.approx(ratio, rel=1e-7)
    assert round(ratio, 3) == 2.669
    # screw speed: 1 rad/s less the e^(−1/0.152) ≈ 1.4e-3 transient still left (τ_S = 0.152 s)
    assert traj["screw_speed_rad_s"][-1] == pytest.approx(1.0 - math.exp(-1.0 / 0.152), abs=2e-4)


def test_repr_keys_time(jones_run):
    sim, traj = jones_run
    assert repr(traj) == ("Trajectory(1000 steps, 0.001–1 s, 22 scalar columns, internal 1000×60 in blocks "
                          "['per_roller'])")
    assert traj.keys() == [name for name, _ in OUTPUT_FIELDS]
    assert "efficiency" in traj and "nope" not in traj
    np.testing.assert_allclose(traj.time_s, 1e-3 * np.arange(1, 1001), rtol=0, atol=1e-12)
    assert dict(traj).keys() == set(traj.keys())  # keys() + __getitem__ make it a mapping
    with pytest.raises(KeyError, match="'nope': Trajectory columns are time_s"):
        traj["nope"]
    assert repr(sim).startswith("Simulator(model='jones2016', params='jones2016', dt_s=0.001, time_s=1,")


def test_to_dataframe(jones_run):
    pd = pytest.importorskip("pandas")
    _, traj = jones_run
    df = traj.to_dataframe()
    assert isinstance(df, pd.DataFrame) and df.index.name == "time_s"
    assert list(df.columns) == traj.keys()[1:]
    np.testing.assert_array_equal(df.index.to_numpy(), traj.time_s)
    np.testing.assert_array_equal(df["nut_force_n"].to_numpy(), traj["nut_force_n"])
    wide = traj.to_dataframe(internal=True)
    labels = traj.layout.labels()
    assert list(wide.columns) == traj.keys()[1:] + labels and len(labels) == 60
    np.testing.assert_array_equal(wide["per_roller[3].screw_slip_axial_m_s [m/s]"].to_numpy(),
                                  traj.internal_quantity("per_roller", "screw_slip_axial_m_s")[:, 3])


def test_internal_loads_by_name_agree_with_the_layout():
    sim = Simulator(preset("s30"), "fu2018", dt_s=1e-3)
    traj = sim.run(np.full(50, 5.0), load_n=5000.0)
    lay = sim.layout
    teeth = traj.internal_block("per_tooth")
    assert teeth.shape == (50, 10, 30, 2)
    # the same numbers through the flat vector's own view, step by step
    np.testing.assert_array_equal(teeth[-1], lay.view(traj.internal[-1], "per_tooth"))
    n_s = traj.internal_quantity("per_roller", "screw_normal_force_n")
    assert n_s.shape == (50, 10)
    # uniform sharing: the 30 teeth of a roller carry its normal force (docs/model.md §4.2, Σζ = N_T)
    np.testing.assert_allclose(teeth[..., 0].sum(axis=-1), n_s, rtol=1e-12)
    with pytest.raises(InputError, match="internal block 'nope': this model's blocks are per_roller, per_tooth"):
        traj.internal_block("nope")
    with pytest.raises(InputError, match="quantity 'x' of internal block 'per_roller': known quantities are"):
        traj.internal_quantity("per_roller", "x")
    ideal = Simulator(preset("s30"), "ideal").run(np.zeros(3))
    with pytest.raises(InputError, match="reports no internal loads"):
        ideal.internal_block("per_roller")


@pytest.mark.parametrize("bad, match", [
    (0.1, r"torque_nm = 0\.1: run\(\) takes a 1-D array with one torque per step"),
    (np.float64(0.1), r"torque_nm = np\.float64\(0\.1\): run\(\) takes a 1-D array"),
    (np.array(0.1), r"torque_nm = array\(0\.1\): run\(\) takes"),
    (np.zeros((2, 3)), r"torque_nm has shape \(2, 3\): run\(\) takes a 1-D array"),
    ("abc", r"torque_nm = 'abc': must be a number or an array of numbers"),
    ([0.1, math.inf], r"torque_nm\[1\] = .*inf.*: inputs must be finite numbers"),
])
def test_run_refuses_a_scalar_and_bad_arrays_and_keeps_the_state(bad, match):
    sim = Simulator(preset("jones2016"), "jones2016")
    sim.run(np.full(5, 0.1))
    before = sim.state
    with pytest.raises(InputError, match=match):
        sim.run(bad)
    assert sim.state is before and sim.nstep == 5


def test_run_load_shape_and_step_inputs():
    sim = Simulator(preset("jones2016"), "jones2016")
    with pytest.raises(InputError, match=r"load_n has shape \(3,\): must be a number or a 1-D array of 2 values"):
        sim.run([0.1, 0.1], [1.0, 2.0, 3.0])
    traj = sim.run([0.1, 0.1], [1.0, 2.0])
    np.testing.assert_array_equal(traj["load_force_n"], [1.0, 2.0])
    for bad in (math.nan, True, "1", None):
        with pytest.raises(InputError, match=r"torque_nm = .*: inputs must be finite numbers"):
            sim.step(bad)
    assert sim.nstep == 2


def test_version_matches_the_distribution_and_pyproject(monkeypatch):
    version = importlib.metadata.version("prsm")
    assert prsm_sim.__version__ == version
    declared = re.search(r'(?m)^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text()).group(1)
    assert version == declared

    def not_installed(_name):
        raise importlib.metadata.PackageNotFoundError("prsm")

    # without an installed distribution the version comes from pyproject.toml beside the package
    monkeypatch.setattr(importlib.metadata, "version", not_installed)
    assert prsm_sim._version() == declared


def test_py_typed_is_shipped():
    assert importlib.resources.files("prsm_sim").joinpath("py.typed").is_file()
    assert 'prsm_sim = ["py.typed"]' in (ROOT / "pyproject.toml").read_text()


def test_error_family():
    assert issubclass(ParamError, PrsmError) and issubclass(ParamError, ValueError)
    assert issubclass(InputError, PrsmError) and issubclass(InputError, ValueError)
    assert issubclass(ModelError, PrsmError) and issubclass(ModelError, RuntimeError)
    from prsm_sim.life import cubic_mean_load, l10_revolutions
    from prsm_sim.physics.contact import contact_for
    from prsm_sim.scenarios import default_spec, run_scenario

    p = preset("s30")
    cases = [
        (lambda: preset("nope"), ParamError, "unknown preset 'nope'; known presets: jones2016"),
        (lambda: Simulator(p, "nope"), ParamError, "model = 'nope': known models are ideal, jones2016, fu2018"),
        (lambda: Simulator(p, "ideal", dt_s=0.0), ParamError, r"dt_s = 0.0: the step must be"),
        (lambda: p.with_overrides({"geometry.n_rollers": 2}), ParamError, "geometry.n_rollers = 2"),
        (lambda: default_spec(p, "nope"), ParamError, "unknown scenario 'nope'"),
        (lambda: run_scenario(Simulator(p, "ideal"), default_spec(p, "step"), 0.0), InputError, "duration_s = 0.0"),
        (lambda: cubic_mean_load([1.0], [1.0, 2.0]), InputError, "load_n has shape"),
        (lambda: l10_revolutions(-1.0, 1.0), InputError, "dynamic_load_rating_n = -1.0"),
        (lambda: steady_state(p, screw_speed_rad_s=1.0, torque_nm=1.0), InputError, "give one of them, not both"),
        (lambda: contact_for(p.geometry, "screw", "nope"), ParamError, "friction.contact_evaluation = 'nope'"),
    ]
    for call, cls, match in cases:
        with pytest.raises(cls, match=match) as err:
            call()
        assert isinstance(err.value, PrsmError) and "\n" not in str(err.value)


# Built-in exceptions prsm_sim may still raise on purpose: the mapping protocol's KeyError
# (Trajectory["nope"]), ImportError for an optional dependency, NotImplementedError in a base class.
ALLOWED_BUILTIN_RAISES = {"KeyError", "ImportError", "NotImplementedError"}


# prsm_ros besides: IndexError (a sequence index out of range), AttributeError (`__getattr__`),
# SystemExit (a command-line tool ending).
ALLOWED_BUILTIN_RAISES_IO = ALLOWED_BUILTIN_RAISES | {"IndexError", "AttributeError", "SystemExit"}


@pytest.mark.parametrize("package, allowed", [("prsm_sim", ALLOWED_BUILTIN_RAISES),
                                              ("prsm_ros", ALLOWED_BUILTIN_RAISES_IO)])
def test_every_deliberate_raise_is_a_prsm_error(package, allowed):
    builtin_errors = {n for n in dir(builtins) if isinstance(getattr(builtins, n), type)
                      and issubclass(getattr(builtins, n), BaseException)}
    offenders = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Raise) and node.exc is not None:
                exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                name = exc.id if isinstance(exc, ast.Name) else None
                if name in builtin_errors and name not in allowed:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} raises {name}")
    assert not offenders, "raise a PrsmError subclass (prsm_sim.errors) instead:\n" + "\n".join(offenders)


@pytest.mark.parametrize("module", ["prsm_sim.simulator", "prsm_sim.stepping.trajectory", "prsm_sim.params"])
def test_docstring_examples_run(module):
    """The Examples sections of the public docstrings are real code (doctest)."""
    import importlib

    result = doctest.testmod(importlib.import_module(module), optionflags=doctest.ELLIPSIS)
    assert result.attempted > 0 and result.failed == 0
