"""Parameters: validation names field, value and what is allowed; YAML round trip; nothing half-built."""

import math

import pytest

from prsm_ros.param_files import load_params_file, params_from_yaml, params_to_yaml
from prsm_sim import Geometry, ParamError, Params, preset


def test_presets_have_model_md_values():
    # docs/model.md §1 preset table
    j = preset("jones2016").geometry
    assert (j.screw_radius_m, j.roller_radius_m, j.starts, j.pitch_m, j.n_rollers, j.n_teeth) == \
        (9.75e-3, 3.25e-3, 5, 1e-3, 10, 40)
    assert j.nut_radius_m == pytest.approx(16.25e-3) and j.lead_m == pytest.approx(5e-3)
    s = preset("s30").geometry
    assert (s.screw_radius_m, s.roller_radius_m, s.n_teeth) == (15e-3, 5e-3, 30)
    lit = preset("jones2016_literal").geometry
    # the seed's literal numbers are not a consistent 5-start design: r_N / r_R = 5.9 (docs/model.md §1)
    assert lit.nut_radius_m / lit.roller_radius_m == pytest.approx(5.9)


@pytest.mark.parametrize("key,value,expect", [
    ("geometry.screw_radius_m", -0.01, "geometry.screw_radius_m = -0.01: must be a finite number > 0"),
    ("geometry.starts", 2, "geometry.starts = 2: must be a whole number >= 3"),
    ("geometry.flank_angle_deg", 90.0, "geometry.flank_angle_deg = 90.0: must lie in (0, 90) degrees"),
    ("geometry.flank_angle_deg", 0.0, "must lie in (0, 90) degrees"),
    ("geometry.roller_radius_m", math.nan, "geometry.roller_radius_m = nan"),
    ("friction.mu_screw_roller", -0.1, "friction.mu_screw_roller = -0.1: must be a finite number >= 0"),
    ("friction.contact_evaluation", "middle", "must be one of exact, line_of_centres"),
    ("ideal.efficiency_forward", 1.5, "must lie in (0, 1]"),
    ("geometry.n_rollers", 40, "at most 12 rollers"),
    ("geometry.starts", "five", "geometry.starts = 'five': must be a number"),
])
def test_bad_values_are_refused_with_field_value_and_range(key, value, expect):
    base = preset("jones2016")
    with pytest.raises(ParamError) as e:
        base.with_overrides({key: value})
    assert expect in str(e.value)
    assert base.geometry.screw_radius_m == 9.75e-3  # the original is untouched (frozen, rebuilt whole)


def test_unknown_keys_are_refused_naming_the_allowed_ones():
    with pytest.raises(ParamError, match=r"unknown parameter friction.mu_sr; allowed in friction: .*mu_screw_roller"):
        preset("s30").with_overrides({"friction.mu_sr": 0.1})
    with pytest.raises(ParamError, match="unknown parameter group"):
        Params.from_dict({"geometri": {}}, base=preset("s30"))


def test_yaml_round_trip_is_exact():
    for name in ("jones2016", "jones2016_literal", "s30"):
        p = preset(name)
        assert params_from_yaml(params_to_yaml(p)) == p


def test_yaml_file_can_be_a_diff_on_a_preset(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("preset: s30\nfriction:\n  mu_screw_roller: 0.1\n")
    p = load_params_file(f)
    assert p.friction.mu_screw_roller == 0.1 and p.geometry.screw_radius_m == 15e-3


@pytest.mark.parametrize("text,expect", [
    ("geometry: [1, 2\n", "line"),
    ("- just\n- a list\n", "expected a mapping"),
    ("preset: s30\ngeometry:\n  screw_radius: 0.01\n", "unknown parameter geometry.screw_radius"),
    ("preset: s31\n", "unknown preset 's31'"),
])
def test_broken_yaml_files_get_one_clear_message(tmp_path, text, expect):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    with pytest.raises(ParamError) as e:
        load_params_file(f)
    assert str(f) in str(e.value) and expect in str(e.value)


def test_derived_quantities():
    g = Geometry(screw_radius_m=0.015, roller_radius_m=0.005, starts=5, pitch_m=1e-3, n_rollers=10, n_teeth=30)
    assert g.nut_radius_m == pytest.approx(0.025)  # planetary fit r_N = r_S + 2 r_R
    assert g.gear_ratio == pytest.approx(5.0)  # g = r_N / r_R
    assert g.lead_per_rad_m == pytest.approx(5e-3 / (2 * math.pi))
    m = preset("jones2016").mass
    r = preset("jones2016").geometry.roller_radius_m
    assert m.roller_inertia_kgm2 == pytest.approx(m.roller_mass_kg * r**2 / 2)  # Jones 2016 eq. 14
