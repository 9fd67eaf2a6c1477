"""What the envelope draws covers what a user may configure (issue: wide clearance, loads up to the rating,
impacts, any allowed step, drive loop rates, datasheet-built screws), and every case is plain data that
builds. Draws only: nothing is run here (test_envelope.py runs them)."""

from __future__ import annotations

import json
import math

import pytest

from prsm_sim.envelope import MAX_CLEARANCE_M, MAX_STEPS, build, case_from_seed, case_params


@pytest.fixture(scope="module")
def cases():
    return [case_from_seed(s) for s in range(1500)]


def test_steps_span_every_allowed_step_and_bound_the_run(cases):
    dts = [c["dt_s"] for c in cases]
    assert min(dts) < 2e-5 and max(dts) > 0.05 and max(dts) <= 0.1  # 0.1 s: the largest step a model accepts
    for c in cases:
        assert 1.0 / round(1.0 / c["dt_s"]) == c["dt_s"]  # whole hertz: the node's update_rate gives this step
        lr = c["loop_rate_hz"]
        n_sub = max(1, round(lr * c["dt_s"])) if lr else 1
        assert round(c["duration_s"] / c["dt_s"]) * n_sub <= MAX_STEPS
        if lr:  # a whole ratio of the step rate: no rounding (drive.loop_schedule would warn)
            ratio = lr * c["dt_s"]
            assert min(abs(ratio - round(ratio)), abs(1 / ratio - round(1 / ratio))) < 1e-9


def test_loads_clearance_preload_impacts_and_screws_reach_the_edges(cases):
    loads = [abs(c["load"]["value_n"]) / case_params(c).ratings.static_load_rating_n for c in cases[:400]]
    assert max(loads) > 0.5 and max(loads) <= 1.0
    clearances = [c["overrides"].get("elastic.axial_clearance_m", 0.0) for c in cases]
    assert max(clearances) > 1.5e-4 and MAX_CLEARANCE_M >= 2e-4  # log-uniform from 1 µm to 250 µm
    # past about 2√2 times the preload a flank of the preloaded nut unloads (Hertz, δ ∝ F^(2/3))
    assert any(abs(c["load"]["value_n"]) > 2 * math.sqrt(2) * c["overrides"]["elastic.preload_n"]
               for c in cases if "elastic.preload_n" in c["overrides"])
    impacts = [c for c in cases if c["controller"] == "impact"]
    assert {c["interface"] for c in impacts} == {"torque", "effort", "velocity", "position"}
    assert max(c["impact"]["speed_rad_s"] for c in impacts) > 450.0  # up to the motor's 500 rad/s
    sheets = {(c["datasheet"]["nominal_diameter_m"], c["datasheet"]["lead_m"], c["datasheet"]["starts"])
              for c in cases if "datasheet" in c}
    assert len(sheets) > 100 and {s[2] for s in sheets} == {3, 4, 5, 6}


def test_a_case_is_plain_data_that_builds(cases):
    for c in cases[:15]:
        assert json.loads(json.dumps(c)) == c
        session, _, p = build(c)
        assert session.simulator.dt_s == c["dt_s"] and p.geometry.starts == c.get("datasheet", {}).get("starts", 5)


def test_a_double_nut_is_drawn_only_on_an_even_tooth_count(cases):
    """Two halves of N_T/2 rows: a drawn datasheet screw with an odd N_T takes oversize rollers instead
    (seed 627 drew a double nut on N_T = 51, refused by the parameter check before a step)."""
    preloaded = [c for c in cases if "elastic.preload_kind" in c["overrides"] and "datasheet" in c]
    assert preloaded
    for c in preloaded:
        assert c["overrides"]["elastic.preload_kind"] != "double_nut" or c["overrides"].get("geometry.n_teeth", 0) % 2 == 0
    assert case_from_seed(627)["overrides"]["elastic.preload_kind"] == "oversize_rollers"
