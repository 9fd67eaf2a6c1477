"""`over_static_rating`, a per-step output: 1 while the load held over the step exceeds the static load
rating C₀a (ISO 76: past it the threads deform permanently), in every step path and in `prsm-sim run`'s CSV.

The closed case: a load 0.1 % under and 0.1 % over `ratings.static_load_rating_n`, the ends removed so the
nut runs free under it."""

import csv
import subprocess
import sys
import warnings

import numpy as np
import pytest

from prsm_sim import MODELS, Session, Simulator, preset
from prsm_sim.actuator import ActuatorParams


def _params():
    return preset("s30").with_overrides({"geometry.thread_ends": False})


@pytest.mark.parametrize("model", MODELS)
def test_the_rating_flag_is_an_output_of_every_step_path(model):
    p = _params()
    c0 = p.ratings.static_load_rating_n
    loads = [0.999 * c0, 1.001 * c0, -1.001 * c0, -0.999 * c0, 0.0]
    want = [0.0, 1.0, 1.0, 0.0, 0.0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the one-time warning is tested in test_configurable_edges
        sim = Simulator(p, model, 1e-3)
        per_step = [sim.step(0.0, f) for f in loads]
        batch = Simulator(p, model, 1e-3).run(np.zeros(len(loads)), loads)
        reference = Simulator(p, model, 1e-3, kernel="reference") if model in ("fu2018", "elastic") else None
        ref = [reference.step(0.0, f).over_static_rating for f in loads] if reference else want
    assert [o.over_static_rating for o in per_step] == want
    assert [o.scalars()["over_static_rating"] for o in per_step] == want
    assert batch.columns["over_static_rating"].tolist() == want
    assert [batch.row(k).over_static_rating for k in range(len(loads))] == want
    assert ref == want


def test_the_rating_flag_through_an_actuator_session():
    p = _params()
    c0 = p.ratings.static_load_rating_n
    s = Session(p, "jones2016", 1e-3, actuator=ActuatorParams(), interface="effort")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        flags = [s.step(0.0, f).over_static_rating for f in (0.999 * c0, 1.001 * c0, 0.0)]
    assert flags == [0.0, 1.0, 0.0]


def test_prsm_sim_run_writes_the_rating_flag_to_its_csv(tmp_path):
    p = preset("jones2016")
    c0 = p.ratings.static_load_rating_n
    out = tmp_path / "run.csv"
    for load, flag in ((1.001 * c0, "1"),):  # the flag's 0 side: the step paths above
        r = subprocess.run([sys.executable, "-m", "prsm_ros.cli.sim", "run", "--model", "ideal", "--scenario", "step",
                            "--set", "geometry.thread_ends=false", "--duration", "0.01", "--load", repr(load),
                            "--csv", str(out), "--no-progress"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        rows = list(csv.reader(out.open()))
        col = rows[0].index("over_static_rating [1]")
        assert {row[col] for row in rows[1:]} == {flag}


@pytest.mark.parametrize("actuator", [None, ActuatorParams()], ids=["bare", "actuator"])
def test_an_end_that_loads_the_nut_past_the_rating_is_flagged_everywhere(actuator):
    """No load: the nut is driven onto its thread end by 400 N·m, whose thrust 2π τ η / L (ideal, η 0.85,
    5 mm lead: 427 kN) exceeds C₀a = 281 kN; the end's force is then the nut's load. The output's field,
    the simulator's flag, the one-time warning and the session's event judge the same load."""
    s = Session(preset("s30"), "ideal", 1e-3, actuator=actuator, nut_position_m=0.134, max_effort_nm=1e6)
    c0 = s.simulator.params.ratings.static_load_rating_n
    with pytest.warns(UserWarning, match="the nut load"):
        outs = [s.step(400.0, 0.0) for _ in range(5)]
    flagged = [o for o in outs if o.over_static_rating == 1.0]
    assert flagged and all(abs(o.load_force_n) > c0 for o in flagged)
    assert all(abs(o.load_force_n) <= c0 for o in outs if o.over_static_rating == 0.0)
    assert s.simulator.over_static_rating == outs[-1].over_static_rating
    ev = [e for e in s.take_edge_events() if type(e).__name__ == "RatingEvent"]
    assert ev and ev[0].what == "exceeded" and ev[0].force_n == flagged[0].load_force_n, ev
