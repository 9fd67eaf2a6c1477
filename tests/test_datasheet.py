"""`prsm-sim datasheet` and `prsm-sim params --datasheet`: the figures, the rules, the refusals.

Independent numbers: the `ideal` model's efficiency law (it must report the η_f, η_b it is given),
the standard design r_S = (n − 2) r_R (docs/model.md §1) and the chord rule for rollers on a circle.
"""

from __future__ import annotations

import json
import math

import pytest
import yaml

from prsm_sim import ParamError, preset
from prsm_sim.datasheet import Datasheet, model_datasheet, most_rollers, params_from_datasheet

from prsm_ros.cli import sim

SHEET = {"nominal_diameter_m": 0.030, "lead_m": 0.005, "starts": 5, "nut_length_m": 0.085,
         "nut_outer_diameter_m": 0.064}


def test_ideal_model_reports_the_efficiencies_it_is_given():
    # the lossy gear alone: `s30`'s equivalent no-load torque (docs/model.md §4.5) off
    p = preset("s30").with_overrides({"ideal.efficiency_forward": 0.83, "ideal.efficiency_backward": 0.71,
                                      "drag.enabled": False})
    s = model_datasheet(p, "ideal")
    assert s.efficiency_forward == pytest.approx(0.83, abs=2e-3)
    assert s.efficiency_backward == pytest.approx(0.71, abs=2e-3)
    assert abs(s.no_load_torque_nm) < 1e-9 and s.conditions["model"] == "ideal"
    assert s.conditions["load_n"] == pytest.approx(0.1 * p.ratings.dynamic_load_rating_n)


def test_geometry_from_a_sheet_follows_the_stated_rules():
    p, said = params_from_datasheet(Datasheet.from_dict(SHEET), preset("s30"))
    g = p.geometry
    assert g.screw_radius_m == pytest.approx(0.015) and g.roller_radius_m == pytest.approx(0.015 / 3)
    assert g.nut_radius_m == pytest.approx(5 * g.roller_radius_m) and g.pitch_m == pytest.approx(0.001)
    assert g.n_teeth == math.floor(0.6 * 0.085 / 0.001 + 1e-9)
    crest = g.roller_radius_m + g.tooth_height_m / 2
    a = g.carrier_radius_m
    # the chord between neighbouring centres clears two crests for N_R rollers, not for one more
    assert 2 * a * math.sin(math.pi / g.n_rollers) >= 2 * crest > 2 * a * math.sin(math.pi / (g.n_rollers + 1))
    assert g.n_rollers == most_rollers(g.screw_radius_m, g.roller_radius_m, crest)
    assert p.elastic.nut_outer_diameter_m == pytest.approx(0.064) and any("N_T" in s for s in said)


@pytest.mark.parametrize("patch,match", [
    ({"lead_mm": 5}, r"unknown key 'lead_mm'"),
    ({"starts": None}, r"starts is required"),
    ({"starts": 2}, r"datasheet\.starts = 2: must be a whole number >= 3"),
    ({"efficiency_forward": 1.2}, r"datasheet\.efficiency_forward = 1\.2: must be a number in \(0, 1\]"),
    ({"static_load_rating_n": "many"}, r"datasheet\.static_load_rating_n = 'many': must be a number"),
])
def test_bad_sheet_names_the_key(patch, match):
    with pytest.raises(ParamError, match=match):
        Datasheet.from_dict({**SHEET, **patch})


def test_cli_refuses_a_bad_sheet_in_one_line_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "sheet.yaml"
    bad.write_text(yaml.safe_dump({**SHEET, "efficiency_backward": 0}))
    out = tmp_path / "out.yaml"
    assert sim.main(["params", "--datasheet", str(bad), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "efficiency_backward = 0" in err[0] and str(bad) in err[0]
    assert not out.exists() and list(tmp_path.iterdir()) == [bad]


def test_cli_datasheet_json_lists_the_catalogue_figures(capsys):
    assert sim.main(["datasheet", "--preset", "s30", "--model", "jones2016", "--load", "5000", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    for key in ("efficiency_forward", "efficiency_backward", "no_load_torque_nm", "static_load_rating_n",
                "dynamic_load_rating_n", "axial_stiffness_n_per_um", "conditions"):
        assert key in d
    assert d["conditions"]["load_n"] == 5000 and d["conditions"]["model"] == "jones2016"
    assert 0 < d["efficiency_backward"] < d["efficiency_forward"] < 1 and d["axial_stiffness_n_per_um"] > 0


def test_plain_params_refuses_datasheet_only_options(capsys):
    assert sim.main(["params", "--preset", "s30", "-o", "x.yaml"]) == 2
    assert "-o applies with --datasheet only" in capsys.readouterr().err


def test_sheet_preload_becomes_an_oversize_roller_preload():
    p, said = params_from_datasheet(Datasheet.from_dict({**SHEET, "preload_n": 2000}), preset("s30"))
    assert p.elastic.preload_n == 2000 and p.elastic.preload_kind == "oversize_rollers"
    assert any("preload" in s for s in said)


def test_validate_refuses_a_missing_folder_before_running(tmp_path, capsys):
    target = tmp_path / "no" / "page.md"
    with pytest.raises(SystemExit) as e:
        sim.main(["validate", "-o", str(target)])
    assert e.value.code == 2 and "is not a folder" in capsys.readouterr().err
    assert not (tmp_path / "no").exists()


def test_a_sheets_parameter_file_loads_back_equal(tmp_path):
    """OUT.yaml is an ordinary parameter file: it loads back to the same parameter set."""
    from prsm_ros.param_files import load_params_file, params_to_yaml
    p, _ = params_from_datasheet(Datasheet.from_dict({**SHEET, "n_rollers": 9}), preset("s30"))
    path = tmp_path / "out.yaml"
    path.write_text(params_to_yaml(p))
    assert load_params_file(path) == p and p.geometry.n_rollers == 9


def test_yaml_exponents_without_a_dot_are_numbers():
    """YAML 1.1 reads 5e-3 as a string; the sheet takes it as the number it spells."""
    sheet = Datasheet.from_dict(yaml.safe_load("nominal_diameter_m: 30e-3\nlead_m: 5e-3\nstarts: 5\n"))
    assert sheet.lead_m == 5e-3 and sheet.nominal_diameter_m == 30e-3
