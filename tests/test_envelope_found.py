"""Cases the widened envelope campaign (`prsm-sim envelope --runs 100000`) found broken, each
pinned as a regression case by its whole case (tests/envelope_found.json: plain data, independent of later
changes to the draws), with what it broke and the defect that breaks it.

They are marked xfail until the defect each names is fixed at its cause; a case that passes then shows
as XPASS and its entry moves to tests/envelope_fixed.json, whose cases must hold (strict regression
cases, with the fix each names). All in the slow tier.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from prsm_sim.envelope import run_case

pytestmark = pytest.mark.slow

FOUND_OPEN = json.loads((Path(__file__).parent / "envelope_found.json").read_text(encoding="utf-8"))
FOUND_FIXED = json.loads((Path(__file__).parent / "envelope_fixed.json").read_text(encoding="utf-8"))


@pytest.mark.parametrize("case", [pytest.param(f["case"], id=f"seed-{f['seed']}",
                                               marks=pytest.mark.xfail(reason=f["defect"], strict=False))
                                  for f in FOUND_OPEN])
def test_a_case_the_campaign_found(case):
    r = run_case(case)
    assert r.ok, r.violations
    assert r.steps > 0


@pytest.mark.parametrize("case", [pytest.param(f["case"], id=f"seed-{f['seed']}") for f in FOUND_FIXED])
def test_a_case_the_campaign_found_holds_since_its_fix(case):
    r = run_case(case)
    assert r.ok, r.violations
    assert r.steps > 0
