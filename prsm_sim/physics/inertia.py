"""The mechanism's inertia in the generalised coordinates (θ_S, θ_C), shared by the rigid models.

`jones2016` integrates with it; `ideal` reflects it to the screw at the ideal carrier ratio.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from prsm_sim.physics.kinematics import ideal_carrier_ratio

if TYPE_CHECKING:  # the parameter records, for annotations only: params resolves derived values with physics
    from prsm_sim.params import Params


def mass_matrix(params: Params) -> np.ndarray:
    """Kinetic energy T = ½ q̇ᵀ M q̇ (docs/model.md §4.1; Jones 2016 eq. 27 incl. the migration coupling).

    Roller axial velocity v_R = −(L/2π) ω_S + (P (n − g)/2π) ω_C couples the two coordinates
    when g ≠ n; for the standard design the off-diagonal term vanishes.
    """
    geo, m = params.geometry, params.resolved_mass
    p = geo.lead_per_rad_m
    k_mig = geo.pitch_m * (geo.starts - geo.gear_ratio) / (2 * math.pi)
    nr, mr = geo.n_rollers, m.roller_mass_kg
    j_s = m.screw_inertia_kgm2 + (m.moved_mass_kg + nr * mr) * p**2
    j_c = (m.carrier_inertia_kgm2 + nr * (mr * geo.carrier_radius_m**2 + mr * k_mig**2
                                          + m.roller_inertia_kgm2 * (1 - geo.gear_ratio) ** 2))
    j_sc = -nr * mr * p * k_mig
    return np.array([[j_s, j_sc], [j_sc, j_c]])


def reflected_inertia(params: Params) -> float:
    """Inertia at the screw, kg·m², with the carrier and rollers moving at the ideal ratio
    ω_C = k ω_S: J = M_SS + 2 M_SC k + M_CC k² (the mass matrix reduced on that constraint)."""
    M = mass_matrix(params)
    k = ideal_carrier_ratio(params.geometry)
    return float(M[0, 0] + 2 * M[0, 1] * k + M[1, 1] * k * k)
