"""Basic axial load ratings of the nut from its thread form: static C_0a and dynamic C_a (docs/model.md "Ratings").

A thread contact sits where docs/model.md §3 puts it (roller profile radius r_R / sin β), but the
flank it sits on is short: from root to crest it spans ℓ_f (`Geometry.flank_contact_length_m`,
a fraction of h_t / cos β, h_t ∝ P). Loaded to a rating, the Hertz ellipse of such a contact is
longer than the flank at catalogue pitches (about 0.8 mm at 4.2 GPa on an s30 flank of 0.57 mm), so
the flank, not the ellipse, sets the contact's length: the contact carries load as a line contact
of length ℓ_f across the curvature ρ that runs across the flank (Johnson, *Contact Mechanics*,
§4.3: p₀ = (Q E* / (π ℓ R))^(1/2), so Q = π ℓ_f p₀² C_E / ρ, C_E = 1/E*).

- Static: ISO 76:2006 takes p₀ = 4000 MPa at the most heavily loaded line (roller) contact as the
  static-rating criterion. With N_R N_T uniformly loaded contacts per side, axial projection c_z:

      C_0a = f_0 · N_R · N_T · c_z · π ℓ_f p₀² C_E / ρ

  N_T ∝ 1/P and ℓ_f ∝ P: C_0a does not depend on the pitch in a nut of fixed engaged length, as
  roller-screw catalogues list it (docs/validation.md). f_0 (`ratings.static_factor`, default 1)
  is the profile factor a datasheet calibrates.
- Dynamic: ISO 281:2007's rating of a thrust roller bearing, N_T rows of N_R line contacts of length
  ℓ_f and rolling-element diameter D_we = 2 r_R at contact angle α (sin α = c_z), the rows combined
  as ISO 281 combines rows of equal rollers (C = N_T^(7/9) C_row):

      C_a = f_c (N_T ℓ_f cos α)^(7/9) N_R^(3/4) D_we^(29/27) tan α      (N, with lengths in mm)

  f_c (`ratings.dynamic_factor`) is the material/profile factor, in ISO 281's N/mm^(...) units.

ρ is the larger principal relative curvature of the contact (across the flank on the
screw side, the more highly stressed convex-on-convex contact; conservative elsewhere); the lower of
the two sides' static capacities rates the nut.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import TYPE_CHECKING

from prsm_sim.physics.hertz import ThreadContactStiffness, elastic_constant, thread_contact

if TYPE_CHECKING:  # the parameter records, for annotations only: params resolves derived values with physics
    from prsm_sim.params import Geometry, Material, Ratings

ISO76_LINE_CONTACT_PRESSURE_PA = 4.0e9  # ISO 76:2006 static-rating contact pressure for roller (line) contacts


def flank_line_capacity_n(side: ThreadContactStiffness, flank_length_m: float, pressure_pa: float) -> float:
    """Normal load Q at which a contact spread over the flank length ℓ_f reaches the pressure p₀, N.

    Line contact (Johnson §4.3): p₀² = Q E* / (π ℓ R), R = 1/ρ with ρ the larger principal relative
    curvature, E* = 1/C_E.
    """
    hz = side.hertz
    rho = hz.sum_rho_per_m * (1.0 + hz.f_rho) / 2.0
    return math.pi * flank_length_m * pressure_pa**2 * hz.elastic_constant_per_pa / rho


@lru_cache(maxsize=64)
def _contacts(geo: Geometry, e_pa: float, nu: float) -> tuple[ThreadContactStiffness, ThreadContactStiffness]:
    ce = elastic_constant(e_pa, nu)
    return thread_contact(geo, "screw", ce), thread_contact(geo, "nut", ce)


def _sides(geo: Geometry, material: Material) -> tuple[ThreadContactStiffness, ThreadContactStiffness]:
    return _contacts(geo, material.youngs_modulus_pa, material.poisson_ratio)


def static_load_rating_n(geo: Geometry, material: Material, ratings: Ratings) -> float:
    """C_0a = f_0 N_R N_T c_z Q_0 (module docstring), N: the weaker side's flank-limited contacts at p₀."""
    loads = [flank_line_capacity_n(side, geo.flank_contact_length_m, ratings.static_contact_pressure_pa)
             * side.axial_factor * geo.n_rollers * geo.n_teeth for side in _sides(geo, material)]
    return ratings.static_factor * float(min(loads))


def dynamic_load_rating_n(geo: Geometry, material: Material, ratings: Ratings) -> float:
    """C_a = f_c (N_T ℓ_f cos α)^(7/9) N_R^(3/4) D_we^(29/27) tan α (ISO 281 thrust roller form), N.

    Lengths enter in mm, as ISO 281 writes the formula; α from the screw-side contact normal.
    """
    c_z = min(1.0, _sides(geo, material)[0].axial_factor)
    alpha = math.asin(c_z)
    length_mm = geo.n_teeth * geo.flank_contact_length_m * 1e3
    d_we_mm = 2 * geo.roller_radius_m * 1e3
    return float(ratings.dynamic_factor * (length_mm * math.cos(alpha)) ** (7 / 9) * geo.n_rollers ** 0.75
                 * d_we_mm ** (29 / 27) * math.tan(alpha))
