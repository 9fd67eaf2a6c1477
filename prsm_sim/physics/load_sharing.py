"""Static axial load distribution over the threads and the axial stiffness of the nut (docs/model.md §4.3).

A threaded joint of N_T engaged tooth rows (each row: N_R identical rollers in parallel). Along
each roller's load path a row carries the axial force through, in series, the screw–roller Hertz
contact, the teeth (screw, roller on both flanks, nut: bending and shear), and the roller–nut
Hertz contact; the roller body is taken axially rigid over one pitch [assumed]. Between rows the
screw and nut bodies stretch by the force they carry over one pitch. Compatibility: the difference
of the row approaches of neighbouring rows equals the relative body stretch between them
(Sopwith 1948; Stoeckly & Macke 1952 give the continuous limit, docs/model.md §4.3):

    g(F_{k+1}) − g(F_k) = P · h(S_k),   S_k = Σ_{j≤k} F_j,   Σ_k F_k = F,

with h(S) = S (1/E₁A₁ + 1/E₂A₂) when the load enters screw and nut at the same end (x from the
free end) and h(S) = S/E₁A₁ − (F − S)/E₂A₂ when it enters at opposite ends. Solved by Newton's
method on the N_T equations (the Jacobian is dense lower-triangular plus one row; N_T ≈ 30).

Preload (double nut or oversize rollers): two such flank sets pressed against each other by P₀; the
external load shifts the nut by x, one side's approach grows to δ₀ + x, the other's falls to
δ₀ − x, and F = Q_A(δ₀ + x) − Q_B(δ₀ − x) until the unloaded side lifts off (at 2^(3/2) P₀ for pure
Hertz springs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from prsm_sim.errors import ModelError
from prsm_sim.physics.hertz import elastic_constant, thread_contact
from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.physics.kinematics import ideal_carrier_ratio

if TYPE_CHECKING:  # the parameter records, for annotations only: params resolves derived values with physics
    from prsm_sim.params import Geometry, Params

ISO76_PEAK_PRESSURE_PA = 4.2e9  # ISO 76 static-rating contact pressure for point contacts


@dataclass(frozen=True)
class ToothRow:
    """The axial force–approach law of one tooth row (N_R rollers in parallel).

    Per roller, the axial approach under an axial force f is c_H f^(2/3) + c_T f (Hertz contacts of
    both sides plus the teeth); a row carrying F has f = F / N_R.
    """

    n_rollers: int
    hertz_coefficient: float  # c_H, m / N^(2/3): screw- and nut-side contacts in series
    tooth_compliance_m_per_n: float  # c_T per roller path

    def approach_m(self, force_n):
        f = np.maximum(np.asarray(force_n, dtype=float), 0.0) / self.n_rollers
        return self.hertz_coefficient * f ** (2.0 / 3.0) + self.tooth_compliance_m_per_n * f

    def compliance_m_per_n(self, force_n):
        """dδ/dF (infinite at zero load for a Hertz row)."""
        f = np.maximum(np.asarray(force_n, dtype=float), 1e-300) / self.n_rollers
        return ((2.0 / 3.0) * self.hertz_coefficient * f ** (-1.0 / 3.0) + self.tooth_compliance_m_per_n) / self.n_rollers

    def force_n(self, approach_m: float) -> float:
        """Inverse of `approach_m` (Newton on f^(1/3); zero for a non-positive approach)."""
        if approach_m <= 0.0:
            return 0.0
        ch, ct = self.hertz_coefficient, self.tooth_compliance_m_per_n
        if ch == 0.0:
            return self.n_rollers * approach_m / ct
        s = (approach_m / ch) ** 0.5 if ct == 0.0 else min((approach_m / ch) ** 0.5, (approach_m / ct) ** (1 / 3))
        for _ in range(60):  # φ(s) = c_H s² + c_T s³ − δ, convex increasing in s > 0
            r = ch * s * s + ct * s**3 - approach_m
            s_new = s - r / (2 * ch * s + 3 * ct * s * s)
            if abs(s_new - s) <= 1e-15 * s:
                s = s_new
                break
            s = s_new
        return self.n_rollers * s**3


@dataclass(frozen=True)
class Joint:
    """A threaded joint: tooth rows at pitch P between two axial members (docs/model.md §4.3)."""

    row: ToothRow
    n_teeth: int
    pitch_m: float
    ea_screw_n: float  # E₁A₁ of the screw over the engaged length
    ea_nut_n: float  # E₂A₂ of the nut body
    mounting: str  # "same_end" | "opposite_end"


@dataclass(frozen=True)
class Distribution:
    """A solved load distribution: row loads (x from the free end), joint approach and stiffness."""

    load_n: float
    row_loads_n: np.ndarray  # N_T values summing to load_n
    approach_m: float  # nut load point relative to the screw where the load leaves the joint
    stiffness_n_per_m: float  # dF/dδ of the joint

    @property
    def shares(self) -> np.ndarray:
        """ζ_T,k = F_k / (F / N_T): sums to N_T (docs/model.md §4.2, §4.3)."""
        n = len(self.row_loads_n)
        return self.row_loads_n * n / self.load_n if self.load_n > 0 else np.ones(n)


def solve_distribution(joint: Joint, load_n: float, *, tol: float = 1e-12, max_iter: int = 100) -> Distribution:
    """Row loads from compatibility (Newton on the N_T equations above); load_n ≥ 0 (the loaded flank set)."""
    n, p = joint.n_teeth, joint.pitch_m
    a1, a2 = 1.0 / joint.ea_screw_n, 1.0 / joint.ea_nut_n
    same = joint.mounting == "same_end"
    if load_n <= 0.0:
        return Distribution(0.0, np.zeros(n), 0.0, _zero_load_stiffness(joint))
    f = np.full(n, load_n / n)
    tri = np.tril(np.ones((n - 1, n)))  # S_k = Σ_{j≤k} F_j for k = 0 … n−2
    for _ in range(max_iter):
        s = tri @ f
        h = s * (a1 + a2) if same else s * a1 - (load_n - s) * a2
        g = joint.row.approach_m(f)
        res = np.empty(n)
        res[:-1] = g[1:] - g[:-1] - p * h
        res[-1] = f.sum() - load_n
        jac = _jacobian(joint, f, tri, a1 + a2)
        step = np.linalg.solve(jac, -res)
        t = 1.0
        while np.any(f + t * step <= 0.0):  # loads stay positive (the Hertz law has no tension)
            t *= 0.5
            if t < 1e-12:
                raise ModelError("load distribution: a tooth row unloads completely; the joint is too soft")
        f = f + t * step
        if np.max(np.abs(step)) <= tol * load_n:
            break
    else:
        raise ModelError(f"load distribution did not converge at {load_n} N")
    # approach at the load point and its derivative (implicit differentiation of the system)
    jac = _jacobian(joint, f, tri, a1 + a2)
    rhs = np.zeros(n)
    rhs[-1] = 1.0
    if not same:
        rhs[:-1] = -p * a2  # ∂res/∂F of the opposite-end h(S) term, moved to the right
    df = np.linalg.solve(jac, rhs)
    cg = joint.row.compliance_m_per_n(f)
    if same:
        approach = float(joint.row.approach_m(f[-1])) + 0.5 * p * load_n * (a1 + a2)
        dapproach = cg[-1] * df[-1] + 0.5 * p * (a1 + a2)
    else:
        s = tri @ f
        approach = float(joint.row.approach_m(f[0])) + 0.5 * p * load_n * (a1 + a2) + p * a1 * s.sum()
        dapproach = cg[0] * df[0] + 0.5 * p * (a1 + a2) + p * a1 * (tri @ df).sum()
    return Distribution(float(load_n), f, approach, 1.0 / dapproach)


def _jacobian(joint: Joint, f: np.ndarray, tri: np.ndarray, a_sum: float) -> np.ndarray:
    n, p = joint.n_teeth, joint.pitch_m
    cg = joint.row.compliance_m_per_n(f)
    jac = np.zeros((n, n))
    jac[:-1] = -p * a_sum * tri  # ∂(P h(S_k))/∂F_j = P (1/E₁A₁ + 1/E₂A₂) for j ≤ k, both mountings
    idx = np.arange(n - 1)
    jac[idx, idx + 1] += cg[1:]
    jac[idx, idx] -= cg[:-1]
    jac[-1] = 1.0
    return jac


def _zero_load_stiffness(joint: Joint) -> float:
    """A Hertz joint has zero stiffness at zero load (dδ/dF infinite); a linear one its spring constant."""
    return 0.0 if joint.row.hertz_coefficient > 0 else solve_distribution(joint, 1.0).stiffness_n_per_m


# -- building the chain from parameters ----------------------------------------------------------

def tooth_compliance_m_per_n(params: Params) -> float:
    """Axial compliance of the teeth on one roller's load path: screw, roller (two flanks), nut [assumed].

    Each tooth a cantilever from the pitch line to the root, of length h = h_t / 2 (h_t the thread
    form's tooth height, `geometry.tooth_height_m`), axial thickness t = P/2 + h tan β (mean of the
    pitch-line thickness P/2 and the root thickness P/2 + 2 h tan β), width w
    (elastic.tooth_effective_width_m), loaded at the pitch line: δ = f h³/(3EI) + 1.2 f h/(G w t)
    (Euler–Bernoulli bending plus Timoshenko shear, I = w t³/12). A coarse stand-in for Yamamoto's
    thread compliance (docs/model.md §4.3); `elastic.tooth_model = none` removes it.
    """
    el = params.elastic
    if el.tooth_model == "none":
        return 0.0
    mat, g = params.material, params.geometry
    h = g.tooth_height_m / 2
    t, w = g.pitch_m / 2 + h * math.tan(g.flank_angle_rad), params.resolved_elastic.tooth_effective_width_m
    one = h**3 / (3 * mat.youngs_modulus_pa * w * t**3 / 12) + 1.2 * h / (mat.shear_modulus_pa * w * t)
    return 4 * one


@lru_cache(maxsize=64)
def _thread_contacts(geo: Geometry, e_pa: float, nu: float):
    ce = elastic_constant(e_pa, nu)
    return thread_contact(geo, "screw", ce), thread_contact(geo, "nut", ce)


def thread_contacts(params: Params):
    """(screw-side, nut-side) `ThreadContactStiffness` of the preset (cached per geometry and material)."""
    return _thread_contacts(params.geometry, params.material.youngs_modulus_pa, params.material.poisson_ratio)


def screw_section_m2(params: Params) -> float:
    return math.pi * params.resolved_elastic.root_diameter_m**2 / 4


def nut_section_m2(params: Params) -> float:
    return math.pi * (params.resolved_elastic.nut_outer_diameter_m**2 - (2 * params.geometry.nut_radius_m) ** 2) / 4


def joint_from_params(params: Params, n_teeth: int | None = None) -> Joint:
    """The threaded joint of one flank set (n_teeth rows, default the geometry's N_T)."""
    scr, nut = thread_contacts(params)
    g, e = params.geometry, params.material.youngs_modulus_pa
    row = ToothRow(g.n_rollers, scr.axial_coefficient + nut.axial_coefficient, tooth_compliance_m_per_n(params))
    return Joint(row, n_teeth or g.n_teeth, g.pitch_m, e * screw_section_m2(params), e * nut_section_m2(params),
                 params.elastic.mounting)


def shaft_stiffness_n_per_m(params: Params, nut_position_m: float = 0.0) -> float:
    """Screw shaft between the fixed bearing and the nut: K = π d_root² E / (4ℓ), ℓ = |x_nut − x_bearing|."""
    ell = max(abs(nut_position_m - params.resolved_elastic.bearing_position_m), 1e-6)
    return params.material.youngs_modulus_pa * screw_section_m2(params) / ell


def iso76_static_rating_n(params: Params) -> float:
    """Axial load at which uniformly shared thread contacts reach a peak Hertz pressure of 4.2 GPa.

    ISO 76 takes 4.2 GPa at the most heavily loaded point contact as the static-rating
    criterion; with uniform sharing over N_R N_T contacts per side, p_max ∝ Q^(1/3).
    """
    g = params.geometry
    loads = []
    for side in thread_contacts(params):
        q_ref = 1.0
        q = q_ref * (ISO76_PEAK_PRESSURE_PA / float(side.hertz.max_pressure_pa(q_ref))) ** 3
        loads.append(q * side.axial_factor * g.n_rollers * g.n_teeth)
    return float(min(loads))


# -- preload -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Side:
    """One flank set's force–approach characteristic, tabulated from `solve_distribution`."""

    joint: Joint
    loads_n: np.ndarray
    approaches_m: np.ndarray

    @classmethod
    def tabulate(cls, joint: Joint, max_load_n: float, n: int = 400) -> Side:
        loads = np.concatenate([[0.0], np.geomspace(max_load_n * 1e-7, max_load_n, n)])
        approaches = np.array([solve_distribution(joint, q).approach_m for q in loads])
        return cls(joint, loads, approaches)

    def approach_m(self, load_n: float) -> float:
        return float(solve_distribution(self.joint, load_n).approach_m)

    def load_n(self, approach_m: float) -> float:
        """Inverse characteristic: table bracket, then Newton on the exact solve."""
        if approach_m <= 0.0:
            return 0.0
        q = float(np.interp(approach_m, self.approaches_m, self.loads_n))
        for _ in range(50):
            d = solve_distribution(self.joint, max(q, 1e-12))
            dq = (approach_m - d.approach_m) * d.stiffness_n_per_m
            q = max(q + dq, 0.5 * q)
            if abs(dq) <= 1e-12 * q:
                break
        return q


@dataclass(frozen=True)
class PairState:
    """The preloaded pair under an external load: side loads, shift, stiffness."""

    load_n: float
    shift_m: float  # nut displacement from the preloaded rest position
    loaded_side_n: float
    unloaded_side_n: float
    stiffness_n_per_m: float
    loaded: Distribution


def preloaded_pair(side_a: Side, side_b: Side, preload_n: float, load_n: float) -> PairState:
    """Solve F = Q_A(δ₀ + x) − Q_B(δ₀ − x) for the shift x (docs/model.md §4.3, preload).

    Beyond lift-off (Q_B = 0) side A alone carries F. Stiffness K_A + K_B while both touch.
    """
    d0a, d0b = side_a.approach_m(preload_n), side_b.approach_m(preload_n)

    def net(x: float) -> float:
        return side_a.load_n(d0a + x) - side_b.load_n(d0b - x) - load_n

    lo, hi = -d0a, max(d0b, 1e-12)
    # F(x) is increasing; bracket: at x = d0b side B is off
    if net(hi) < 0.0:
        da = side_a.approach_m(load_n)
        x = da - d0a
        dist = solve_distribution(side_a.joint, load_n)
        return PairState(load_n, x, load_n, 0.0, dist.stiffness_n_per_m, dist)
    from scipy.optimize import brentq
    x = brentq(net, lo, hi, xtol=1e-16, rtol=1e-13)
    qa, qb = side_a.load_n(d0a + x), side_b.load_n(d0b - x)
    dist_a, dist_b = solve_distribution(side_a.joint, qa), solve_distribution(side_b.joint, max(qb, 0.0))
    return PairState(load_n, x, qa, qb, dist_a.stiffness_n_per_m + dist_b.stiffness_n_per_m, dist_a)


# -- the whole axial chain ------------------------------------------------------------------------

@dataclass(frozen=True)
class AxialPoint:
    """Axial deflection and stiffness of the assembly at one load (one record of `prsm-sim stiffness`)."""

    load_n: float
    nut_deflection_m: float
    shaft_deflection_m: float
    housing_deflection_m: float
    nut_stiffness_n_per_m: float
    shaft_stiffness_n_per_m: float
    housing_stiffness_n_per_m: float
    row_loads_n: np.ndarray
    shares: np.ndarray
    unloaded_side_n: float

    @property
    def deflection_m(self) -> float:
        return self.nut_deflection_m + self.shaft_deflection_m + self.housing_deflection_m

    @property
    def stiffness_n_per_m(self) -> float:
        return 1.0 / (1.0 / self.nut_stiffness_n_per_m + 1.0 / self.shaft_stiffness_n_per_m
                      + 1.0 / self.housing_stiffness_n_per_m) if self.nut_stiffness_n_per_m > 0 else 0.0


class AxialChain:
    """Shaft, nut (one flank set or a preloaded pair) and housing in series, from a parameter set."""

    def __init__(self, params: Params, nut_position_m: float = 0.0) -> None:
        self.params = params
        el = params.elastic
        self.preload_n = el.preload_n
        n_side = params.geometry.n_teeth
        if el.preload_kind == "double_nut":
            n_side = max(1, params.geometry.n_teeth // 2)
        self.joint = joint_from_params(params, n_side)
        self.k_shaft = shaft_stiffness_n_per_m(params, nut_position_m)
        self.k_housing = el.housing_stiffness_n_per_m
        self._side = None
        if self.preload_n > 0:
            # both flank sets share the joint's geometry (mirror images) [assumed]
            self._side = Side.tabulate(self.joint, max(10 * self.preload_n, params.resolved_ratings.static_load_rating_n))

    def at(self, load_n: float) -> AxialPoint:
        """The chain under an axial load ≥ 0 (the load direction is symmetric for mirror-image flanks)."""
        f = abs(float(load_n))
        if self._side is None:
            d = solve_distribution(self.joint, f)
            nut_defl, k_nut, unloaded = d.approach_m, d.stiffness_n_per_m, 0.0
        else:
            pr = preloaded_pair(self._side, self._side, self.preload_n, f)
            d, nut_defl, k_nut, unloaded = pr.loaded, pr.shift_m, pr.stiffness_n_per_m, pr.unloaded_side_n
        return AxialPoint(load_n=f, nut_deflection_m=nut_defl, shaft_deflection_m=f / self.k_shaft,
                          housing_deflection_m=f / self.k_housing if math.isfinite(self.k_housing) else 0.0,
                          nut_stiffness_n_per_m=k_nut, shaft_stiffness_n_per_m=self.k_shaft,
                          housing_stiffness_n_per_m=self.k_housing, row_loads_n=d.row_loads_n, shares=d.shares,
                          unloaded_side_n=unloaded)


# -- linearised axial dynamics ----------------------------------------------------------------------

@dataclass(frozen=True)
class Mode:
    frequency_hz: float  # damped natural frequency
    undamped_frequency_hz: float
    damping_ratio: float


def axial_masses_kg(params: Params) -> tuple[float, float]:
    """(M_S, m): the rotating side reflected to the nut axis and the axially moving side (docs/model.md §4.3).

    M_S = J (2π/L)² with J the screw inertia plus the carrier and roller motion carried at the
    ideal carrier ratio (`physics.inertia.mass_matrix`, its moved-mass part removed) [assumed: the rollers
    roll without slip in the mode]; the rollers ride the screw's thread axially (as in the `elastic`
    model, where the compliance sits between them and the nut); m = the moved mass.
    """
    g, m = params.geometry, params.mass
    mm = mass_matrix(params)
    r = ideal_carrier_ratio(g)
    v = np.array([1.0, r])
    m_axial = m.moved_mass_kg
    j_rot = float(v @ mm @ v) - m_axial * g.lead_per_rad_m**2
    return j_rot / g.lead_per_rad_m**2, m_axial


def linear_modes(mass_kg: np.ndarray, damping_n_s_m: np.ndarray, stiffness_n_m: np.ndarray) -> list[Mode]:
    """Modes of M q̈ + C q̇ + K q = 0 from the eigenvalues of its first-order form, lowest first.

    Rigid-body modes come out at 0 Hz; each oscillating pair is reported once.
    """
    n = len(mass_kg)
    minv = np.linalg.inv(mass_kg)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ stiffness_n_m, -minv @ damping_n_s_m]])
    lam = np.linalg.eigvals(a)
    tiny = 1e-6 * float(np.max(np.abs(lam)))
    lam = np.where(np.abs(lam) < tiny, 0.0, lam)  # the rigid-body double zero, rounded
    modes = []
    if np.any(lam == 0.0):
        modes.append(Mode(0.0, 0.0, 0.0))
    for ev in sorted((z for z in lam if z.imag > tiny), key=abs):  # one of each conjugate pair
        w = abs(ev)
        modes.append(Mode(frequency_hz=ev.imag / (2 * math.pi), undamped_frequency_hz=w / (2 * math.pi),
                          damping_ratio=-ev.real / w))
    return modes


@dataclass(frozen=True)
class ModalAnalysis:
    load_n: float
    stiffness_n_per_m: float
    damping_n_s_per_m: float
    screw_side_mass_kg: float
    nut_side_mass_kg: float
    free: list[Mode]  # screw free to rotate (torque-controlled): a rigid-body mode and the axial mode
    held: list[Mode]  # screw held by a stiff servo


def axial_modes(params: Params, load_n: float, nut_position_m: float = 0.0) -> ModalAnalysis:
    """Linearised axial modes about an operating load (docs/model.md §4.3, first axial mode).

    Two masses (M_S, m) joined by the chain's tangent stiffness K at the load and a damper sized
    by `elastic.contact_damping_ratio` on the free mode: c = 2 ζ √(K M_S m / (M_S + m)).
    Closed form of the free mode: f = (1/2π) √(K (1/m + 1/M_S)); held: f = (1/2π) √(K/m).
    """
    k = AxialChain(params, nut_position_m).at(load_n).stiffness_n_per_m
    ms, m = axial_masses_kg(params)
    c = 2 * params.elastic.contact_damping_ratio * math.sqrt(k * ms * m / (ms + m))
    spring = np.array([[1.0, -1.0], [-1.0, 1.0]])
    free = linear_modes(np.diag([ms, m]), c * spring, k * spring)
    held = linear_modes(np.array([[m]]), np.array([[c]]), np.array([[k]]))
    return ModalAnalysis(float(load_n), k, c, ms, m, free, held)
