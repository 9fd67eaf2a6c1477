"""Rigid-body kinematics of the PRSM (docs/model.md §2).

Internally the body frame has z along the screw axis (right-hand threads); nut motion is
reported along x_nut = −z (see `outputs` for the sign convention). Angular velocities are
about +z: screw ω_S, carrier ω_C, roller spin relative to the carrier ω_r.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from prsm_sim.errors import InputError

if TYPE_CHECKING:  # the parameter records, for annotations only: params resolves derived values with physics
    from prsm_sim.params import Geometry


def ideal_carrier_ratio(geo: Geometry) -> float:
    """ω_C / ω_S for pure rolling at both pitch circles: r_S / (2 (r_S + r_R)) (docs/model.md §2, Velinsky 2009)."""
    return geo.screw_radius_m / (2 * geo.carrier_radius_m)


def ideal_speed_ratio(geo: Geometry) -> float:
    """ω_S / ω_C at ideal kinematics: 2 (r_S + r_R) / r_S; 2(n − 1)/(n − 2) for the standard design."""
    return 1.0 / ideal_carrier_ratio(geo)


def roller_spin(geo: Geometry, carrier_speed_rad_s: float) -> float:
    """Roller spin relative to the carrier from the spur/ring gear: ω_r = −g ω_C (docs/model.md §2)."""
    return -geo.gear_ratio * carrier_speed_rad_s


def nut_velocity(geo: Geometry, screw_speed_rad_s: float) -> float:
    """Nut velocity along x_nut: (L / 2π) ω_S, whatever the carrier speed or slip (docs/model.md §2)."""
    return geo.lead_per_rad_m * screw_speed_rad_s


def roller_axial_velocity_z(geo: Geometry, screw_speed_rad_s: float, carrier_speed_rad_s: float) -> float:
    """Roller axial velocity along +z from the screw–roller thread engagement (docs/model.md §2).

    v_R = −(L_S/2π)(ω_S − ω_C) + (L_R/2π) ω_r. Exact at any contact point: each term is a
    helicoidal motion that maps one of the two thread surfaces onto itself.
    """
    w_r = roller_spin(geo, carrier_speed_rad_s)
    return -geo.lead_per_rad_m * (screw_speed_rad_s - carrier_speed_rad_s) + geo.pitch_m / (2 * np.pi) * w_r


def roller_migration_velocity(geo: Geometry, carrier_speed_rad_s: float) -> float:
    """Axial roller velocity relative to the nut, along +z: (P ω_C / 2π)(n − g) (docs/model.md §2)."""
    return geo.pitch_m * carrier_speed_rad_s / (2 * np.pi) * (geo.starts - geo.gear_ratio)


def roller_point_velocity(geo: Geometry, point_m: np.ndarray, screw_speed_rad_s: float,
                          carrier_speed_rad_s: float) -> np.ndarray:
    """Absolute velocity of the roller material point at `point_m`.

    The point is given in the carrier frame at the instant, with the roller's axis at (a, 0).
    """
    a = geo.carrier_radius_m
    w_c = carrier_speed_rad_s
    spin_abs = w_c + roller_spin(geo, w_c)
    axis = np.array([a, 0.0, 0.0])
    rel = np.asarray(point_m, dtype=float) - axis
    rel[2] = 0.0
    v = np.cross([0.0, 0.0, w_c], axis) + np.cross([0.0, 0.0, spin_abs], rel)
    v[2] += roller_axial_velocity_z(geo, screw_speed_rad_s, w_c)
    return v


def sliding_velocity(geo: Geometry, side: str, point_m: np.ndarray, screw_speed_rad_s: float,
                     carrier_speed_rad_s: float) -> np.ndarray:
    """Velocity of the roller relative to the screw (side "screw") or nut (side "nut") at a contact point."""
    v_roller = roller_point_velocity(geo, point_m, screw_speed_rad_s, carrier_speed_rad_s)
    if side == "screw":
        p = np.asarray(point_m, dtype=float).copy()
        p[2] = 0.0
        return v_roller - np.cross([0.0, 0.0, screw_speed_rad_s], p)
    if side == "nut":  # the nut translates along z at −(L/2π) ω_S and does not rotate
        return v_roller - np.array([0.0, 0.0, -nut_velocity(geo, screw_speed_rad_s)])
    raise InputError(f"side must be 'screw' or 'nut', got {side!r}")


def sliding_matrix(geo: Geometry, side: str, point_m: np.ndarray) -> np.ndarray:
    """3×2 matrix G with v_s = G @ (ω_S, ω_C): sliding velocity is linear in the two speeds."""
    return np.column_stack([sliding_velocity(geo, side, point_m, 1.0, 0.0),
                            sliding_velocity(geo, side, point_m, 0.0, 1.0)])
