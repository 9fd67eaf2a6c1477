"""Thread form and load ratings against a roller-screw catalogue and closed forms.

Catalogue: the SRS-C roller screw line (docs/validation/data/srs_c_roller_screws.csv, whose header
names the source: the line's technical data and nut dimensions as transcribed in the public
repository vdimichele-helix/email-roller-screw-configuration). Closed form: Johnson, *Contact
Mechanics*, §4.3 (line contact). Criterion: ISO 76:2006 (4000 MPa for roller contacts).
"""

from __future__ import annotations

import math
import statistics

import pytest

from prsm_sim import ParamError, preset
from prsm_sim.calibration import fit_ratings
from prsm_sim.datasheet import params_from_datasheet
from prsm_sim.physics.contact import solve_contact
from prsm_sim.physics.load_sharing import thread_contacts
from prsm_sim.physics.ratings import ISO76_LINE_CONTACT_PRESSURE_PA, flank_line_capacity_n

from prsm_ros.cli.validation import DATA, read_catalogue, sheet_of, thread_depth_per_pitch

SOURCE, ROWS = read_catalogue(DATA)


def _row(d0: float, lead: float) -> dict:
    return next(r for r in ROWS if (r["nominal_diameter_mm"], r["lead_mm"]) == (d0, lead))


def test_the_data_file_names_its_source():
    text = " ".join(SOURCE)
    assert "vdimichele-helix/email-roller-screw-configuration" in text and "srsCTechnicalData.jsx" in text
    assert len(ROWS) >= 40 and {int(r["starts"]) for r in ROWS} == {5, 6}


def test_default_tooth_height_is_the_catalogue_thread_depth():
    """SRS-C: (d1 − d2)/2 per pitch over every row; the default h_t/P = 0.4 lies within 0.02 of its median."""
    median = statistics.median(thread_depth_per_pitch(ROWS))
    assert abs(preset("s30").geometry.tooth_height_per_pitch - median) <= 0.02


def test_flank_capacity_is_the_line_contact_closed_form():
    """Johnson §4.3: a line contact of length ℓ under Q peaks at p₀ = (Q E* / (π ℓ R))^(1/2)."""
    p = preset("s30")
    scr, _ = thread_contacts(p)
    ell, p0 = 0.4e-3, 3.1e9
    q = flank_line_capacity_n(scr, ell, p0)
    hz = scr.hertz
    r = 2.0 / (hz.sum_rho_per_m * (1.0 + hz.f_rho))
    assert math.sqrt(q / hz.elastic_constant_per_pa / (math.pi * ell * r)) == pytest.approx(p0, rel=1e-12)


def test_s30_static_rating_is_iso76_on_its_flank_contacts():
    p = preset("s30")
    g = p.geometry
    q = [flank_line_capacity_n(s, g.flank_contact_length_m, ISO76_LINE_CONTACT_PRESSURE_PA) * s.axial_factor
         for s in thread_contacts(p)]
    assert p.ratings.static_load_rating_n == pytest.approx(min(q) * g.n_rollers * g.n_teeth, rel=1e-12)


@pytest.mark.parametrize("d0", [30.0, 39.0])
def test_static_rating_flat_over_lead_in_one_nut(d0):
    """SRS-C lists C0a flat over leads 2–15 mm in one nut (276–281 kN at d0 30); the model's: max/min ≤ 1.3."""
    base = preset("s30")
    c0 = [params_from_datasheet(sheet_of(r), base)[0].ratings.static_load_rating_n for r in ROWS
          if r["nominal_diameter_mm"] == d0 and r["lead_mm"] <= 15]
    listed = [r["static_load_rating_kn"] for r in ROWS if r["nominal_diameter_mm"] == d0 and r["lead_mm"] <= 15]
    assert max(listed) / min(listed) <= 1.1 and len(c0) >= 6
    assert max(c0) / min(c0) <= 1.3


PREDICTED = [(30.0, 2.0), (30.0, 10.0), (30.0, 15.0), (21.0, 5.0), (39.0, 2.0), (39.0, 10.0), (48.0, 10.0),
             (36.0, 12.0), (44.0, 18.0), (64.0, 6.0), (64.0, 18.0)]


def test_static_rating_fitted_on_one_size_predicts_the_line():
    """SRS-C: f_0 fitted on 30 × 5; C0a of 5- and 6-start sizes d0 21–64 (pitch ≤ 3 mm) within ±30 %."""
    base = preset("s30")
    fitted, _ = fit_ratings(params_from_datasheet(sheet_of(_row(30.0, 5.0)), base)[0], sheet_of(_row(30.0, 5.0)))
    for d0, lead in PREDICTED:
        r = _row(d0, lead)
        c0 = params_from_datasheet(sheet_of(r), fitted)[0].ratings.static_load_rating_n
        assert c0 / (r["static_load_rating_kn"] * 1e3) == pytest.approx(1.0, abs=0.3), (d0, lead)


def test_thread_form_moves_ratings_not_the_contact():
    """The contact point stays where the profile radius r_R / sin β puts it (docs/model.md §3)."""
    p = preset("s30")
    q = p.with_overrides({"geometry.tooth_height_per_pitch": 0.3, "geometry.flank_contact_fraction": 0.5})
    for side in ("screw", "nut"):
        a, b = solve_contact(p.geometry, side), solve_contact(q.geometry, side)
        assert a.body_angle_rad == b.body_angle_rad and list(a.point_m) == list(b.point_m)
    assert q.ratings.static_load_rating_n == pytest.approx(p.ratings.static_load_rating_n * 0.75 * 0.5, rel=1e-12)
    assert q.ratings.dynamic_load_rating_n == pytest.approx(p.ratings.dynamic_load_rating_n * 0.375 ** (7 / 9),
                                                            rel=1e-12)
    # a rating given as a number stays as given when the thread form changes
    given = p.with_overrides({"ratings.static_load_rating_n": 2.0e5})
    assert given.with_overrides({"geometry.tooth_height_per_pitch": 0.3}).ratings.static_load_rating_n == 2.0e5


@pytest.mark.parametrize("key,value,match", [
    ("geometry.tooth_height_per_pitch", 0.6, r"geometry\.tooth_height_per_pitch = 0\.6: must lie in \(0, 0\.5\]"),
    ("geometry.flank_contact_fraction", 0.0, r"geometry\.flank_contact_fraction = 0\.0"),
    ("ratings.static_factor", -1.0, r"ratings\.static_factor"),
])
def test_bad_thread_form_names_the_field(key, value, match):
    with pytest.raises(ParamError, match=match):
        preset("s30").with_overrides({key: value})
