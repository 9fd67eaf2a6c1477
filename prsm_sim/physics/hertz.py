"""Hertz point contact: exact elliptic-integral solution, Hamrock–Brewe fast form, surface curvatures.

docs/model.md §4.3 (Harris & Kotzalas, *Rolling Bearing Analysis*, ch. 6; Johnson, *Contact
Mechanics*, ch. 4). Two bodies touch at a point; their relative curvature (the sum of the two
surfaces' curvature tensors in the common tangent plane, convex positive) has eigenvalues 2A ≤ 2B.
With Σρ = 2(A + B) and F(ρ) = (B − A)/(A + B) the contact ellipse ratio κ = a/b solves

    F(ρ) = ((κ² + 1) 𝓔 − 2 𝓕) / ((κ² − 1) 𝓔),   𝓕, 𝓔 complete elliptic integrals, modulus² 1 − 1/κ²

and for a normal load Q, with X = (3 Q C_E / (2 Σρ))^(1/3):

    a = (2κ²𝓔/π)^(1/3) X,   b = (2𝓔/(πκ))^(1/3) X,   δ = (2𝓕/π)(π/(2κ²𝓔))^(1/3) X² Σρ/2,   p_max = 3Q/(2πab).

δ ∝ Q^(2/3): one coefficient per contact geometry (`HertzContact.approach_coefficient`), so the hot
path never solves for κ; the exact κ is found once per geometry. Hamrock & Brewe (1983, J. Lubr.
Technol. 105:171) closed forms are offered for comparison and quick estimates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING
from collections.abc import Callable

import numpy as np

from prsm_sim.errors import InputError
from prsm_sim.physics.contact import flank_surfaces, solve_contact

if TYPE_CHECKING:  # the parameter records, for annotations only: params resolves derived values with physics
    from prsm_sim.params import Geometry

_KAPPA_MAX = 1e4  # F(ρ) = 1 − O(1e-8): a line contact for every purpose here


def curvature_difference(kappa: float) -> float:
    """F(ρ) of an ellipse ratio κ ≥ 1 (docs/model.md §4.3, Harris ch. 6)."""
    if kappa <= 1.0:
        return 0.0
    from scipy.special import ellipe, ellipk  # here: `import prsm_sim` stays quick without scipy
    m = 1.0 - 1.0 / kappa**2
    e, k = ellipe(m), ellipk(m)
    return float(((kappa**2 + 1.0) * e - 2.0 * k) / ((kappa**2 - 1.0) * e))


def ellipticity(f_rho: float) -> tuple[float, float, float]:
    """Exact (κ, 𝓔, 𝓕) for a curvature difference 0 ≤ F(ρ) < 1, κ = a/b ≥ 1.

    Solves the F(ρ) relation above for ln κ by Brent's method to machine precision.
    """
    if not (math.isfinite(f_rho) and 0.0 <= f_rho < 1.0):
        raise InputError(f"curvature difference F(rho) = {f_rho!r}: must lie in [0, 1)")
    if f_rho < 1e-12:
        return 1.0, math.pi / 2, math.pi / 2
    hi = math.log(_KAPPA_MAX)
    if f_rho >= curvature_difference(_KAPPA_MAX):
        raise InputError(f"curvature difference F(rho) = {f_rho!r}: ellipse ratio beyond {_KAPPA_MAX:g} (a line contact)")
    from scipy.optimize import brentq
    from scipy.special import ellipe, ellipk
    # near κ = 1, F ≈ (3/4)(κ² − 1)/2 … bracket from just above 1
    t = brentq(lambda t: curvature_difference(math.exp(t)) - f_rho, 1e-9, hi, xtol=1e-15, rtol=1e-15, maxiter=200)
    kappa = math.exp(t)
    m = 1.0 - 1.0 / kappa**2
    return kappa, float(ellipe(m)), float(ellipk(m))


def hamrock_brewe(f_rho: float) -> tuple[float, float, float]:
    """Hamrock & Brewe (1983) closed forms of (κ, 𝓔, 𝓕) from the radius ratio α = R_y/R_x = (1 + F)/(1 − F).

    κ ≈ 1.0339 α^0.6360, 𝓔 ≈ 1.0003 + 0.5968/α, 𝓕 ≈ 1.5277 + 0.6023 ln α (their eqs. for the
    "simplified solution"; a few per cent from the exact values).
    """
    if not (math.isfinite(f_rho) and 0.0 <= f_rho < 1.0):
        raise InputError(f"curvature difference F(rho) = {f_rho!r}: must lie in [0, 1)")
    alpha = (1.0 + f_rho) / (1.0 - f_rho)
    return 1.0339 * alpha**0.6360, 1.0003 + 0.5968 / alpha, 1.5277 + 0.6023 * math.log(alpha)


def elastic_constant(e1_pa: float, nu1: float, e2_pa: float | None = None, nu2: float | None = None) -> float:
    """C_E = (1 − ν₁²)/E₁ + (1 − ν₂²)/E₂ (1/Pa); body II defaults to body I's material. 1/C_E is Johnson's E*."""
    e2 = e1_pa if e2_pa is None else e2_pa
    n2 = nu1 if nu2 is None else nu2
    return (1.0 - nu1**2) / e1_pa + (1.0 - n2**2) / e2


@dataclass(frozen=True)
class HertzContact:
    """A point-contact geometry: curvature sum, curvature difference, elastic constant and its ellipse.

    Loads Q in N (normal force), lengths in m. Every load-dependent quantity is a power law in Q.
    """

    sum_rho_per_m: float
    f_rho: float
    elastic_constant_per_pa: float
    kappa: float
    ellip_e: float
    ellip_k: float
    method: str = "exact"

    def _x(self, q_n):
        return (1.5 * np.asarray(q_n, dtype=float) * self.elastic_constant_per_pa / self.sum_rho_per_m) ** (1.0 / 3.0)

    @property
    def approach_coefficient(self) -> float:
        """c with δ = c Q^(2/3) (m / N^(2/3))."""
        x1 = (1.5 * self.elastic_constant_per_pa / self.sum_rho_per_m) ** (1.0 / 3.0)
        return (2 * self.ellip_k / math.pi) * (math.pi / (2 * self.kappa**2 * self.ellip_e)) ** (1.0 / 3.0) \
            * x1**2 * self.sum_rho_per_m / 2

    def semi_axes_m(self, q_n):
        """(a, b): semi-major and semi-minor axes of the contact ellipse."""
        x = self._x(q_n)
        return ((2 * self.kappa**2 * self.ellip_e / math.pi) ** (1.0 / 3.0) * x,
                (2 * self.ellip_e / (math.pi * self.kappa)) ** (1.0 / 3.0) * x)

    def approach_m(self, q_n):
        """Mutual approach δ of distant points of the two bodies."""
        return self.approach_coefficient * np.abs(np.asarray(q_n, dtype=float)) ** (2.0 / 3.0)

    def load_n(self, approach_m):
        """Inverse: Q = (δ/c)^(3/2) for δ > 0, zero otherwise (no tension)."""
        d = np.maximum(np.asarray(approach_m, dtype=float), 0.0)
        return (d / self.approach_coefficient) ** 1.5

    def max_pressure_pa(self, q_n):
        a, b = self.semi_axes_m(q_n)
        return 3 * np.asarray(q_n, dtype=float) / (2 * math.pi * a * b)

    def stiffness_n_per_m(self, q_n):
        """dQ/dδ = 3Q/(2δ) = (3/2) c^(-1) Q^(1/3)."""
        return 1.5 * np.abs(np.asarray(q_n, dtype=float)) ** (1.0 / 3.0) / self.approach_coefficient


def point_contact(sum_rho_per_m: float, f_rho: float, elastic_constant_per_pa: float,
                  method: str = "exact") -> HertzContact:
    """The Hertz contact of this geometry, κ exact (elliptic integrals) or by Hamrock–Brewe."""
    if not (math.isfinite(sum_rho_per_m) and sum_rho_per_m > 0):
        raise InputError(f"curvature sum = {sum_rho_per_m!r}: must be a finite number > 0 (bodies must touch convexly)")
    if not (math.isfinite(elastic_constant_per_pa) and elastic_constant_per_pa > 0):
        raise InputError(f"elastic constant = {elastic_constant_per_pa!r}: must be a finite number > 0")
    if method == "exact":
        kappa, e, k = ellipticity(f_rho)
    elif method == "hamrock_brewe":
        kappa, e, k = hamrock_brewe(f_rho)
    else:
        raise InputError(f"method = {method!r}: must be exact or hamrock_brewe")
    return HertzContact(sum_rho_per_m, f_rho, elastic_constant_per_pa, kappa, e, k, method)


# -- curvatures of parametrised surfaces ------------------------------------------------------

Surface = Callable[[float, float], np.ndarray]


def curvature_tensor(surface: Surface, u: float, v: float, outward: np.ndarray, hu: float, hv: float,
                     basis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Curvature tensor (convex positive) of a surface X(u, v) at (u, v), from its second fundamental form.

    `outward`: approximate outward normal (out of the material, toward the other body); only its
    sign is used. Derivatives by fourth-order central differences with steps hu, hv. Returns the
    2×2 tensor in an orthonormal tangent basis and that basis (3×2); pass `basis` to express the
    tensor in a given tangent basis (it must span the same tangent plane).

    With the outward normal n, a convex surface bends away from n, so its height along n is
    −½ xᵀ K x with K = −II (II in orthonormal tangent coordinates).
    """
    def d1(f, h):
        return (-f(2 * h) + 8 * f(h) - 8 * f(-h) + f(-2 * h)) / (12 * h)

    def d2(f, h):
        return (-f(2 * h) + 16 * f(h) - 30 * f(0.0) + 16 * f(-h) - f(-2 * h)) / (12 * h * h)

    xu = d1(lambda s: surface(u + s, v), hu)
    xv = d1(lambda s: surface(u, v + s), hv)
    xuu = d2(lambda s: surface(u + s, v), hu)
    xvv = d2(lambda s: surface(u, v + s), hv)
    xuv = d1(lambda s: d1(lambda t: surface(u + s, v + t), hv), hu)
    n = np.cross(xu, xv)
    n /= np.linalg.norm(n)
    if n @ outward < 0:
        n = -n
    if basis is None:
        e1 = xu / np.linalg.norm(xu)
        e2 = np.cross(n, e1)
        basis = np.column_stack([e1, e2])
    t = basis.T @ np.column_stack([xu, xv])  # tangent vectors in the orthonormal basis
    ii = np.array([[xuu @ n, xuv @ n], [xuv @ n, xvv @ n]])
    ti = np.linalg.inv(t)
    k = -(ti.T @ ii @ ti)
    return 0.5 * (k + k.T), basis


def relative_curvature(k_body_i: np.ndarray, k_body_ii: np.ndarray) -> tuple[float, float, np.ndarray]:
    """(Σρ, F(ρ), principal directions) of two touching surfaces' curvature tensors in one tangent basis.

    The mirror-image sign conventions cancel: each tensor is convex-positive about its own outward
    normal, and the gap between the bodies is ½ xᵀ (K_I + K_II) x (Johnson §4.1).
    """
    w, vec = np.linalg.eigh(k_body_i + k_body_ii)
    s = float(w.sum())
    return s, float((w[1] - w[0]) / s), vec


# -- thread contacts ---------------------------------------------------------------------------

@dataclass(frozen=True)
class ThreadContactStiffness:
    """Hertz geometry of one side's thread contact and its axial projection.

    `axial_factor` c_z = |n_z| of the contact normal: an axial load f per contact presses it with
    Q = f / c_z and an axial relative displacement u approaches it by δ = u c_z, so the axial
    approach is δ_ax = δ/c_z (docs/model.md §3, §4.3).
    """

    side: str
    hertz: HertzContact
    axial_factor: float
    principal_curvatures_body_per_m: tuple[float, float]
    principal_curvatures_roller_per_m: tuple[float, float]

    def axial_approach_m(self, axial_force_n):
        """Axial approach of one contact carrying an axial force f ≥ 0 (N)."""
        f = np.maximum(np.asarray(axial_force_n, dtype=float), 0.0)
        return self.hertz.approach_m(f / self.axial_factor) / self.axial_factor

    @property
    def axial_coefficient(self) -> float:
        """c_ax with δ_ax = c_ax f^(2/3): c / c_z^(5/3)."""
        return self.hertz.approach_coefficient / self.axial_factor ** (5.0 / 3.0)


def thread_contact(geo: Geometry, side: str, elastic_constant_per_pa: float, load_sign: int = 1,
                   method: str = "exact") -> ThreadContactStiffness:
    """Hertz contact at the solved thread contact point of one side (docs/model.md §3, §4.3).

    Principal curvatures of both flank helicoids come from their parametrisations
    (`physics.contact.flank_surfaces`) at the exact tangency point, so the lead angles and the
    roller's arc profile R_p = r_R / sin β enter without a textbook formula.
    """
    c = solve_contact(geo, side, load_sign)
    body, roller, psi0 = flank_surfaces(geo, side, load_sign)
    n_body_out = c.normal_on_roller  # the force on the roller points out of the body's material
    hr = 1e-3 * geo.roller_radius_m
    k_b, basis = curvature_tensor(body, c.body_radius_m, c.body_angle_rad, n_body_out, hr, hr / c.body_radius_m)
    k_r, _ = curvature_tensor(lambda rho, psi: roller(rho, psi, 0.0), c.roller_contact_radius_m,
                              c.roller_angle_rad + psi0, -n_body_out, hr, hr / c.roller_contact_radius_m, basis)
    s, f, _ = relative_curvature(k_b, k_r)
    hz = point_contact(s, f, elastic_constant_per_pa, method)
    return ThreadContactStiffness(side=side, hertz=hz, axial_factor=abs(float(c.normal_on_roller[2])),
                                  principal_curvatures_body_per_m=tuple(np.linalg.eigvalsh(k_b)),
                                  principal_curvatures_roller_per_m=tuple(np.linalg.eigvalsh(k_r)))
