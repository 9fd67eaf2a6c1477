"""Exact thread contact between the roller's arc profile and the straight screw/nut flanks (docs/model.md §3).

The screw and nut flanks are helicoids with straight generators at the flank angle β; the
roller flank is a helicoid swept by an arc of radius R_p = r_R / sin β centred on the roller
axis. A contact is a common point of the two surfaces with parallel normals: five equations
(3 position, 2 normal direction) in five unknowns (body radius and angle, roller radius and
angle, roller profile axial offset), solved by Newton's method from the line of centres.

Which flanks touch depends on the direction of the axial load (Jones 2016: screw thread top
against roller thread bottom on the screw side, roller top against nut bottom on the nut
side): the roller must be pushed one way by the screw and the other way by the nut, so its
screw-side and nut-side contacts lie on opposite flanks of its teeth. `load_sign = +1` is a
load resisting positive nut motion (the threads push the nut toward +x_nut = −z).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from prsm_sim.errors import InputError, ModelError, ParamError
from prsm_sim.physics.kinematics import sliding_matrix

if TYPE_CHECKING:  # the parameter records, for annotations only: params resolves derived values with physics
    from prsm_sim.params import Geometry


@dataclass(frozen=True)
class ContactPoint:
    """One thread contact, in the carrier frame with the roller axis at (a, 0) and the contact at z = 0.

    `normal_on_roller`: unit vector of the compressive normal force the body exerts on the roller.
    `body_angle_rad`: angle of the point about the screw axis from the line of centres.
    `roller_angle_rad`: angle about the roller axis from the line of centres (toward the body).
    """

    side: str
    point_m: np.ndarray
    normal_on_roller: np.ndarray
    body_radius_m: float
    roller_contact_radius_m: float
    body_angle_rad: float
    roller_angle_rad: float
    evaluation: str

    def sliding_matrix(self, geo: Geometry) -> np.ndarray:
        """3×2 G with sliding velocity (roller relative to body) v_s = G @ (ω_S, ω_C)."""
        return sliding_matrix(geo, self.side, self.point_m)


def _flank_signs(side: str, load_sign: int) -> tuple[int, int]:
    """(body flank slope sign dz/dr, roller arc: +1 upper / −1 lower) of the loaded flanks."""
    if side == "screw":
        return (load_sign, load_sign)
    return (load_sign, -load_sign)


def flank_surfaces(geo: Geometry, side: str, load_sign: int = 1):
    """Parametrisations of the two loaded flank helicoids of one side, in the carrier frame.

    Returns (body(r, φ), roller(ρ, ψ, z0), ψ0): the screw or nut flank z = p φ + s tan β (r − r_b)
    (straight generator at the flank angle), the roller flank swept by the arc of radius
    R_p = r_R / sin β about the roller axis at (a, 0), and the roller angle ψ0 of the line of
    centres (π on the screw side, 0 on the nut side). docs/model.md §3.
    """
    beta = geo.flank_angle_rad
    tb = math.tan(beta)
    a = geo.carrier_radius_m
    r_p = geo.roller_radius_m / math.sin(beta)
    p_body = geo.lead_per_rad_m  # screw and nut have the same lead
    p_roll = geo.pitch_m / (2 * math.pi)
    r_body0 = geo.screw_radius_m if side == "screw" else geo.nut_radius_m
    s_body, s_arc = _flank_signs(side, load_sign)

    def body(r: float, phi: float) -> np.ndarray:
        return np.array([r * math.cos(phi), r * math.sin(phi), p_body * phi + s_body * tb * (r - r_body0)])

    def roller(rho: float, psi: float, z0: float) -> np.ndarray:
        root = math.sqrt(max(r_p**2 - rho**2, 1e-30))
        return np.array([a + rho * math.cos(psi), rho * math.sin(psi), z0 + p_roll * psi + s_arc * root])

    return body, roller, (math.pi if side == "screw" else 0.0)


def solve_contact(geo: Geometry, side: str, load_sign: int = 1) -> ContactPoint:
    """Exact tangency contact for one side (docs/model.md §3)."""
    if side not in ("screw", "nut"):
        raise InputError(f"side must be 'screw' or 'nut', got {side!r}")
    if load_sign not in (1, -1):
        raise InputError(f"load_sign must be +1 or -1, got {load_sign!r}")
    beta = geo.flank_angle_rad
    tb = math.tan(beta)
    r_r = geo.roller_radius_m
    r_p = r_r / math.sin(beta)
    p_body = geo.lead_per_rad_m  # screw and nut have the same lead
    p_roll = geo.pitch_m / (2 * math.pi)
    r_body0 = geo.screw_radius_m if side == "screw" else geo.nut_radius_m
    psi0 = math.pi if side == "screw" else 0.0
    s_body, s_arc = _flank_signs(side, load_sign)
    scale = 1.0 / r_r  # solve in units of the roller radius for conditioning

    body_at, roller_at, _ = flank_surfaces(geo, side, load_sign)

    def surfaces(x):
        r, phi, rho, psi, z0 = x
        body = body_at(r, phi)
        roll = roller_at(rho, psi, z0)
        root = math.sqrt(max(r_p**2 - rho**2, 1e-30))
        e_r = np.array([math.cos(phi), math.sin(phi), 0.0])
        e_phi = np.array([-math.sin(phi), math.cos(phi), 0.0])
        e_rho = np.array([math.cos(psi), math.sin(psi), 0.0])
        e_psi = np.array([-math.sin(psi), math.cos(psi), 0.0])
        # gradients of z − f(...) for each helicoid; both have unit z component
        n_body = -s_body * tb * e_r - (p_body / r) * e_phi + np.array([0.0, 0.0, 1.0])
        dh = -s_arc * rho / root
        n_roll = -dh * e_rho - (p_roll / rho) * e_psi + np.array([0.0, 0.0, 1.0])
        return body, roll, n_body, n_roll

    def residual(x):
        body, roll, n_body, n_roll = surfaces(x)
        return np.r_[(body - roll) * scale, (n_body - n_roll)[:2]]

    x0 = np.array([r_body0, 0.0, r_r, psi0, -p_roll * psi0 - s_arc * r_r / tb])
    from scipy.optimize import fsolve  # here: `import prsm_sim` stays quick without scipy
    x, _, ier, msg = fsolve(residual, x0, full_output=True, xtol=1e-13)
    if ier != 1 or np.max(np.abs(residual(x))) > 1e-9:
        raise ModelError(f"geometry: the {side}–roller tangency contact was not found for these radii, pitch "
                         f"and flank angle ({msg.strip()})")
    r, phi, rho, psi, _ = x
    body, _, _, n_roll = surfaces(x)
    # the arc's material lies toward its centre: outward normal is +n_roll for the upper arc
    normal_on_roller = -s_arc * n_roll / np.linalg.norm(n_roll)
    point = body.copy()
    point[2] = 0.0
    return ContactPoint(side=side, point_m=point, normal_on_roller=normal_on_roller, body_radius_m=float(r),
                        roller_contact_radius_m=float(rho), body_angle_rad=float(phi),
                        roller_angle_rad=float(psi - psi0), evaluation="exact")


def line_of_centres_contact(geo: Geometry, side: str, load_sign: int = 1) -> ContactPoint:
    """The pitch point on the line of centres with the pitch-point flank normal, as the seed's equations assume.

    Normal from docs/model.md §3 at the pitch radius (axial, circumferential, radial split by α_n, λ).
    """
    beta = geo.flank_angle_rad
    if side == "screw":
        lam, r_body = geo.screw_lead_angle_rad, geo.screw_radius_m
    else:
        lam, r_body = geo.nut_lead_angle_rad, geo.nut_radius_m
    s_body, s_arc = _flank_signs(side, load_sign)
    # gradient of z − pφ − s tanβ (r − r_b) at the pitch point, in (e_r, e_φ, e_z) = (x, y, z) here
    grad = np.array([-s_body * math.tan(beta), -math.tan(lam), 1.0])
    # the same orientation rule as the exact solution: the force points into the roller's material
    normal = -s_arc * grad / np.linalg.norm(grad)
    return ContactPoint(side=side, point_m=np.array([r_body, 0.0, 0.0]), normal_on_roller=normal,
                        body_radius_m=r_body, roller_contact_radius_m=geo.roller_radius_m,
                        body_angle_rad=0.0, roller_angle_rad=0.0, evaluation="line_of_centres")


def contact_for(geo: Geometry, side: str, evaluation: str, load_sign: int = 1) -> ContactPoint:
    """The contact used by the models: exact tangency or line of centres."""
    if evaluation == "exact":
        return solve_contact(geo, side, load_sign)
    if evaluation == "line_of_centres":
        return line_of_centres_contact(geo, side, load_sign)
    raise ParamError(f"friction.contact_evaluation = {evaluation!r}: must be 'exact' or 'line_of_centres'")


def predicted_screw_offset_rad(geo: Geometry) -> float:
    """docs/model.md §3 estimate of the screw–roller offset: (λ_S − λ_R) / tan β (sign: toward −φ for load_sign +1)."""
    return (geo.screw_lead_angle_rad - geo.roller_lead_angle_rad) / math.tan(geo.flank_angle_rad)
