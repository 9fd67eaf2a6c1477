"""The `elastic` model level: the `fu2018` force system plus an axially compliant screw–nut chain.

docs/model.md §4.3. Degrees of freedom: screw angle and carrier angle with their speeds (the
`fu2018` core: screw, rollers, carriers, its friction laws), and the nut's own axial position and
velocity. The rollers ride the screw's thread kinematically (x = (L/2π) θ_S); between that
kinematic thread position and the nut sits the axial chain, whose deflection δ = (L/2π) θ_S − x_N
carries the thread force F(δ) + c δ̇ to the nut:

- nut side (Hertz contacts per thread, teeth, nut body, with the load distribution solved from
  compatibility, `physics.load_sharing`): represented by δ_nut(F) = a F^(2/3) + b F, fitted to the
  static solution over 0.01 %–50 % of the static rating (within 0.6 % for `s30`) [derived];
- screw shaft between the fixed bearing and the nut, EA/ℓ with ℓ = |x_N − x_bearing|, and the
  housing, in series;
- axial clearance (a dead zone of total width c: lost motion at a reversal) or a preloaded pair
  (two opposed flank sets pressed together by P₀);
- contact damping c = 2ζ √(K μ) with K the tangent stiffness and μ the reduced mass of the two
  sides, so every load has modal damping ratio ζ (`elastic.contact_damping_ratio`).

The elastic potential V(δ, x_N) is that of the same law (complementary energy of the power-law
terms). Because ℓ changes with x_N, the nut also feels −∂V/∂x_N = (F²/2) d(ℓ/EA)/dx_N, which keeps
the system conservative.

Integration: each step of dt_s is split into `substeps` sub-steps sized so that ω h ≤ 0.5 for
the stiffest axial mode (several hundred Hz at a 1 ms step: 8 sub-steps for `s30`); each sub-step is a kick–drift–kick
(velocity Verlet) for the nut with one `fu2018` ROS2 step (L-stable, its own stiff carrier mode)
for the rotating core under the thread force, taken at the sub-step's midpoint. Impacts: where the
held elastic force's work f Δδ misses the change of V (a contact closing or opening inside the
sub-step, the first sub-steps of a Hertz contact) by more than IMPACT_TOL of the sub-step's input
work (+ IMPACT_FLOOR of V), the sub-step is redone with the secant force (V₁ − V₀ − nsf Δx)/Δδ, a
discrete gradient whose work is ΔV exactly (at most IMPACT_ITERATIONS times, the best attempt kept).
The damping force and the Stribeck torque, held over the sub-step, are booked as dissipated with
exactly the work they did, so the ledger closes to the integration error of the core.

Preload kinds: `oversize_rollers` loads both flanks of all N_T rows; `double_nut` is two halves of
N_T/2 rows each, half A (rows 0 … N_T/2 − 1 of the per-thread block) loaded by δ > 0 (P₀ plus its
share of the thread force), half B (the other rows) unloaded by it (P₀ minus its share, zero after
lift-off at 2^(3/2) P₀ for Hertz springs, docs/model.md §4.3); each half's rows carry its own solved
distribution and sum to its force.

Stiction (the `stiction` group, Karnopp type with a Stribeck decay): a screw slower than the stick
window (the screw speed at which the screw–roller slip |v_N|/sin β, docs/model.md §3, equals fu2018's
Coulomb regularisation speed ε, at most the Stribeck speed) sticks while the torque lies in the
breakaway band [p F η_b,s, p F/η_f,s] (sliding-only efficiencies of docs/model.md §4.2 at μ_s =
breakaway_ratio · μ); held, it does not creep at all. Sliding, the screw feels `fu2018`'s friction
plus the Stribeck excess: μ(v) = μ_c + (μ_s − μ_c) exp(−(v/v_s)²) at the slip v = |ω_S| p / sin β
(v_s = `stribeck_speed_m_s`), applied as a resisting screw torque p|F| (1/η_f(μ(v)) − 1/η_f(μ_c))
driving, p|F| (η_b(μ_c) − η_b(μ(v))) back-driven, held over each sub-step at its start speed and
booked as dissipated. The core's kinetic energy at the moment it sticks is booked as dissipated.
`breakaway_ratio` 1 turns both off (fu2018's friction, its own stick included).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from prsm_sim.models import kernels
from prsm_sim.models.fu2018 import (CARRIER_QUANTITIES, PER_ROLLER_QUANTITIES, PER_TOOTH_QUANTITIES, Forces, Fu2018,
                                    slip_speed)
from prsm_sim.models.kernels import ElasticConstants, kernel_memory, memory_from_kernel
from prsm_sim.params import Params
from prsm_sim.physics import load_sharing as ls
from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.stepping.model import Model
from prsm_sim.stepping.records import InternalBlock, InternalLayout, State
from prsm_sim.stepping.trajectory import Trajectory, trajectory_from_columns

ELASTIC_QUANTITIES = (
    ("deflection_m", "m"),  # δ = (L/2π) θ_S − x_N
    ("lost_motion_m", "m"),  # part of δ inside the clearance (no force)
    ("thread_force_n", "N"),  # axial force the threads deliver to the nut, +x_nut
    ("contact_stiffness_n_per_m", "N/m"),  # tangent stiffness of the chain at δ
    ("elastic_energy_j", "J"),  # V(δ, x_N)
    ("nut_velocity_m_s", "m/s"),
)
PER_THREAD_QUANTITIES = (("thread_load_n", "N"), ("load_share", "1"))
OMEGA_H_MAX = 0.5  # sub-step so that ω h ≤ this for the stiffest axial mode (Verlet phase error (ωh)²/24 ≈ 1 %)
FIT_RANGE = (1e-4, 0.5)  # fraction of the static rating over which δ_nut(F) is fitted
# A sub-step whose held elastic force missed the change of V by more than IMPACT_TOL of the sub-step's input work
# |τ Δθ_S| plus IMPACT_FLOOR of the elastic energy at its ends is redone with the secant force, at most
# IMPACT_ITERATIONS times (each cuts the miss by about (ωh)²/2 ≈ 1/8). The ledger's cumulative miss is then of
# order IMPACT_TOL of the flow; smooth contact passes on the first attempt (backlash crossings and the first
# sub-steps of a Hertz contact pay: about 25 % more core steps on ±20 rad/s reversals into 50 µm of play).
# The floor is small: with the screw held (static friction, no input work) a loaded chain rings on the nut, and a
# miss of 1e-3 V per sub-step went unbooked (a 20 kN load applied to an unloaded chain tripped the energy guard).
IMPACT_TOL = 1e-4
IMPACT_FLOOR = 1e-4
IMPACT_ITERATIONS = 4
ROOT_STEP_TOL = 1e-9  # relative Newton step at which `power_law_root` stops (its error is then below rounding)


@dataclass(frozen=True)
class PowerLaw:
    """δ(F) = a F^(2/3) + b F for F ≥ 0, its inverse, tangent stiffness and complementary energy."""

    a: float
    b: float

    def approach(self, f: float) -> float:
        return self.a * f ** (2.0 / 3.0) + self.b * f

    def force(self, d: float) -> float:
        s = power_law_root(d, self.a, self.b)
        return s * s * s

    def compliance(self, f: float) -> float:
        f = max(f, 1e-300)
        return (2.0 / 3.0) * self.a * f ** (-1.0 / 3.0) + self.b

    def complementary(self, f: float) -> float:
        """∫₀^F δ dF' = (3/5) a F^(5/3) + b F²/2; the stored energy is F δ − this."""
        return 0.6 * self.a * f ** (5.0 / 3.0) + 0.5 * self.b * f * f


def power_law_root(d: float, a: float, b: float) -> float:
    """s = F^(1/3) with δ = a F^(2/3) + b F, i.e. a s² + b s³ = d (0 for d ≤ 0): the inverse of the power law.

    In s the law is a polynomial, convex and increasing for s > 0, so Newton from an upper bound
    (the smaller of the pure-Hertz root √(d/a) and the pure-linear root ∛(d/b), picked by comparing
    a³ with d b² so that only one root is taken) converges monotonically, with no fractional power
    inside the loop. The stiffness and energy then follow from s without powers either
    (`AxialLaw.evaluate`). The compiled kernel (`models.kernels._power_root`) does the same arithmetic.

    Stopping: Newton's error after a step of relative size r is at most about r² (the relative curvature
    term g''/(2g') s of this polynomial lies in [1/2, 1]), so a step below ROOT_STEP_TOL = 1e-9 leaves an
    error under 1e-17 of s, below double rounding: the iteration stops there instead of taking one more
    step only to see it vanish (3.1 iterations on average instead of 3.75; the root is taken about twice
    per sub-step).
    """
    if d <= 0.0:
        return 0.0
    if a == 0.0:
        return (d / b) ** (1.0 / 3.0)
    s = math.sqrt(d / a) if b == 0.0 or a * a * a >= d * b * b else (d / b) ** (1.0 / 3.0)
    for _ in range(60):
        r = a * s * s + b * s * s * s - d
        s_new = s - r / (2.0 * a * s + 3.0 * b * s * s)
        if abs(s_new - s) <= ROOT_STEP_TOL * s:
            return s_new
        s = s_new
    return s


def _stiffness_at_root(s: float, a: float, b: float) -> float:
    """dF/dδ = 1 / ((2/3) a F^(−1/3) + b) at F = s³ (s floored where F^(−1/3) would overflow)."""
    return 1.0 / ((2.0 / 3.0) * a / max(s, 1e-100) + b)


def _complementary_at_root(s: float, a: float, b: float) -> float:
    """∫₀^F δ dF' = (3/5) a F^(5/3) + b F²/2 at F = s³."""
    f = s * s * s
    return 0.6 * a * (s * s * s * s * s) + 0.5 * b * f * f


def fit_side(joint: ls.Joint, rating_n: float) -> PowerLaw:
    """Least-squares fit (relative error) of δ_nut(F) = a F^(2/3) + b F to the static distribution."""
    loads = np.geomspace(FIT_RANGE[0], FIT_RANGE[1], 40) * rating_n
    d = np.array([ls.solve_distribution(joint, f).approach_m for f in loads])
    basis = np.column_stack([loads ** (2.0 / 3.0), loads]) / d[:, None]
    (a, b), *_ = np.linalg.lstsq(basis, np.ones_like(d), rcond=None)
    return PowerLaw(float(a), float(max(b, 0.0)))


def sliding_efficiencies(geo, mu: float) -> tuple[float, float]:
    """(η_f, η_b) of screw–roller sliding alone at friction coefficient μ (docs/model.md §4.2):
    η_f = 1 / (1 + μ / (sin β (c_zS − μ sin β))), η_b = 1 − μ / (sin β (c_zS + μ sin β)),
    c_zS = cos α_nS cos λ_S, α_nS = atan(tan β cos λ_S)."""
    czs, sb = _czs_sin_beta(geo)
    return _sliding_efficiencies(czs, sb, mu)


def _czs_sin_beta(geo) -> tuple[float, float]:
    lam, beta = geo.screw_lead_angle_rad, geo.flank_angle_rad
    return math.cos(math.atan(math.tan(beta) * math.cos(lam))) * math.cos(lam), math.sin(beta)


def _sliding_efficiencies(czs: float, sb: float, mu: float) -> tuple[float, float]:
    """`sliding_efficiencies` from c_zS and sin β (scalar arithmetic only: the stepping loop calls it)."""
    return 1.0 / (1.0 + mu / (sb * (czs - mu * sb))), 1.0 - mu / (sb * (czs + mu * sb))


class AxialLaw:
    """Thread force, tangent stiffness and elastic energy of the chain at a deflection δ and nut position x."""

    def __init__(self, params: Params) -> None:
        el, g = params.elastic, params.geometry
        self.params = params
        self.clearance = el.axial_clearance_m
        self.preload = el.preload_n
        self.double_nut = el.preload_kind == "double_nut"
        self.n_side = n_side = g.n_teeth // 2 if self.double_nut else g.n_teeth  # even: Params checks it
        self.joint = ls.joint_from_params(params, n_side)
        self.side = fit_side(self.joint, params.ratings.static_load_rating_n)
        self.ea = params.material.youngs_modulus_pa * ls.screw_section_m2(params)
        self.x_bearing = el.bearing_position_m
        k_h = el.housing_stiffness_n_per_m
        self.c_housing = 0.0 if math.isinf(k_h) else 1.0 / k_h
        self.d0 = self.side.approach(self.preload) if self.preload > 0 else 0.0
        self.v0 = (self.preload * self.d0 - self.side.complementary(self.preload)) if self.preload > 0 else 0.0
        self.shares = _share_table(self.joint, params.ratings.static_load_rating_n)

    def external_compliance(self, x_n: float) -> tuple[float, float]:
        """(ℓ/EA + 1/K_h, its derivative in x_N)."""
        ell = x_n - self.x_bearing
        s = 1.0 if ell >= 0 else -1.0
        return max(abs(ell), 1e-6) / self.ea + self.c_housing, s / self.ea

    def evaluate(self, delta: float, x_n: float, extra_clearance_m: float = 0.0) -> tuple[float, float, float, float]:
        """(F, K = dF/dδ, V, lost motion) at deflection δ and nut position x_N, with the clearance
        widened by `extra_clearance_m` (a growing-backlash fault; unpreloaded nuts only)."""
        c_ext, _ = self.external_compliance(x_n)
        if self.preload > 0:
            return self._preloaded(delta, c_ext)
        half = 0.5 * (self.clearance + extra_clearance_m)
        mag = abs(delta) - half
        if mag <= 0.0:
            return 0.0, 0.0, 0.0, delta
        a, b = self.side.a, self.side.b + c_ext
        r = power_law_root(mag, a, b)
        f = r * r * r
        k = _stiffness_at_root(r, a, b)
        v = f * mag - _complementary_at_root(r, a, b)
        sgn = 1.0 if delta > 0 else -1.0
        return sgn * f, k, v, sgn * half

    def _preloaded(self, delta: float, c_ext: float) -> tuple[float, float, float, float]:
        """Pair shift x_p with δ = x_p + F(x_p) c_ext, F = Q_A(δ₀ + x_p) − Q_B(δ₀ − x_p) (Newton on x_p)."""
        a, b, d0 = self.side.a, self.side.b, self.d0
        x = delta / 2.0
        for _ in range(60):
            ra, rb = power_law_root(d0 + x, a, b), power_law_root(d0 - x, a, b)
            qa, qb = ra * ra * ra, rb * rb * rb
            ka = _stiffness_at_root(ra, a, b) if qa > 0 else 0.0
            kb = _stiffness_at_root(rb, a, b) if qb > 0 else 0.0
            f = qa - qb
            r = x + f * c_ext - delta
            dx = -r / (1.0 + (ka + kb) * c_ext)
            x += dx
            if abs(dx) <= 1e-15 * max(abs(x), d0):
                break
        ra, rb = power_law_root(d0 + x, a, b), power_law_root(d0 - x, a, b)
        qa, qb = ra * ra * ra, rb * rb * rb
        ka = _stiffness_at_root(ra, a, b) if qa > 0 else 0.0
        kb = _stiffness_at_root(rb, a, b) if qb > 0 else 0.0
        f = qa - qb
        k_pair = ka + kb
        k = k_pair / (1.0 + k_pair * c_ext)
        va = qa * (d0 + x) - _complementary_at_root(ra, a, b)
        vb = (qb * (d0 - x) - _complementary_at_root(rb, a, b)) if qb > 0 else 0.0
        return f, k, va + vb - 2 * self.v0 + 0.5 * f * f * c_ext, 0.0

    def pair_forces(self, delta: float, x_n: float) -> tuple[float, float]:
        """(Q_A, Q_B) of a preloaded pair at δ: the flank set that δ > 0 loads, and the opposed one (N)."""
        c_ext, _ = self.external_compliance(x_n)
        f = self._preloaded(delta, c_ext)[0]
        x = delta - f * c_ext
        return self.side.force(self.d0 + x), self.side.force(self.d0 - x)

    def deflection_at(self, force_n: float, x_n: float) -> float:
        """The deflection δ at which the chain carries `force_n` at nut position x_N (the inverse of
        `evaluate`; closed form without preload, safeguarded Newton on the pair law with it)."""
        if force_n == 0.0 and self.preload == 0.0:
            return 0.0
        c_ext, _ = self.external_compliance(x_n)
        mag = abs(force_n)
        guess = self.side.a * mag ** (2.0 / 3.0) + (self.side.b + c_ext) * mag
        d = math.copysign(0.5 * self.clearance + guess, force_n)
        if self.preload == 0.0:
            return d
        lo, hi = -abs(d) - self.d0 - 1e-9, abs(d) + self.d0 + 1e-9
        for _ in range(100):
            f, k = self.evaluate(d, x_n)[:2]
            if f > force_n:
                hi = d
            else:
                lo = d
            if abs(f - force_n) <= 1e-12 * max(abs(force_n), self.preload):
                break
            nd = d - (f - force_n) / k if k > 0 else math.nan
            d = nd if lo < nd < hi else 0.5 * (lo + hi)
        return d

    def nut_side_force(self, force_n: float, x_n: float) -> float:
        """−∂V/∂x_N at fixed δ: (F²/2) d(ℓ/EA)/dx_N (the shaft length changes under the nut)."""
        _, dc = self.external_compliance(x_n)
        return 0.5 * force_n * force_n * dc


def _share_table(joint: ls.Joint, rating_n: float) -> tuple[np.ndarray, np.ndarray]:
    loads = np.concatenate([[0.0], np.geomspace(1e-5, 1.0, 60) * rating_n])
    shares = np.array([ls.solve_distribution(joint, f).shares if f > 0 else np.ones(joint.n_teeth) for f in loads])
    return loads, shares


class ElasticPart(NamedTuple):
    """The memory of `elastic` in `State.part`: its `fu2018` core's (`fu2018.Fu2018Part`), the nut's own
    axial state, the coupling's last acceleration and the clearance a fault added."""

    flank_sign: int = 1
    pin_force_n: float = 0.0
    gear_force_n: float = 0.0
    solver: tuple = ()
    nut_axial_m: float = 0.0  # the nut's own axial position x_N (the other models tie it to θ_S)
    nut_speed_m_s: float = 0.0
    screw_accel_rad_s2: float = 0.0  # the last sub-step's, for the coupling's midpoint prediction
    # axial clearance added to `elastic.axial_clearance_m` (m), set by whoever steps the model (the
    # actuator's growing-backlash fault): an input carried in the state, 0 by default
    extra_clearance_m: float = 0.0


class ElasticModel(Model):
    name = "elastic"
    compiled_kernel = True
    has_carrier = True
    has_internal_forces = True
    has_friction_laws = True
    has_axial_chain = True
    part_type = ElasticPart

    def __init__(self, params: Params, dt_s: float, kernel: str = "compiled") -> None:
        """
        Parameters
        ----------
        params : Params
            Validated parameters.
        dt_s : float
            Fixed output step, s.
        kernel : {"compiled", "reference"}
            "compiled": the sub-step loop (core included) and the batch loop run as numba code
            (`models.kernels`, the same arithmetic); "reference": the pure-Python methods, their specification.
        """
        self._kn = kernels.load(kernel)
        self.kernel = kernel
        super().__init__(params, dt_s)
        self.law = AxialLaw(params)
        self.m = params.mass.moved_mass_kg
        self.p = self.geo.lead_per_rad_m
        # the rotating core: fu2018 with the moved mass taken off (the nut is its own body here)
        core_params = params.with_overrides({"mass.moved_mass_kg": 1e-9 * self.m})
        ms, _ = ls.axial_masses_kg(params)
        self.screw_side_mass_kg = ms
        self.mu = ms * self.m / (ms + self.m)
        self.zeta = params.elastic.contact_damping_ratio
        k_max = max(ls.AxialChain(params).at(f).stiffness_n_per_m
                    for f in (0.0, 0.5 * params.ratings.static_load_rating_n))
        omega = math.sqrt(k_max / self.mu)
        self.substeps = max(1, math.ceil(omega * self.dt_s / OMEGA_H_MAX))
        self.core = Fu2018(core_params, self.dt_s / self.substeps, kernel=kernel)
        mm = mass_matrix(core_params)
        # the core's mass matrix as Python floats: numpy scalars would slow every step's arithmetic
        self._m_core = ((float(mm[0, 0]), float(mm[0, 1])), (float(mm[1, 0]), float(mm[1, 1])))
        # breakaway (the `stiction` group): a hold band of screw torque wider than the running one
        st = params.stiction
        self.breakaway = st.breakaway_ratio > 1.0
        self.eta_static = sliding_efficiencies(self.geo, st.breakaway_ratio * params.friction.mu_screw_roller)
        # stick window: the screw speed at which the screw–roller slip (|v_N|/sin β, docs/model.md §3) is the
        # Stribeck speed
        self.w_stick = st.stribeck_speed_m_s * math.sin(self.geo.flank_angle_rad) / self.p
        # Stribeck decay of the excess (`_stribeck_torque`): μ(v) = μ_c + (μ_s − μ_c) exp(−(v/v_s)²)
        self.czs, self.sin_beta = _czs_sin_beta(self.geo)
        self.mu_c = params.friction.mu_screw_roller
        self.eta_running = _sliding_efficiencies(self.czs, self.sin_beta, self.mu_c)
        self.d_mu = (st.breakaway_ratio - 1.0) * self.mu_c
        self.p_over_sin_beta_per_vs = self.p / (self.sin_beta * st.stribeck_speed_m_s)  # ω_S → v/v_s
        nr, nt = self.geo.n_rollers, self.geo.n_teeth
        self.layout = InternalLayout(blocks=(
            InternalBlock("per_roller", ("roller", "quantity"), (nr, len(PER_ROLLER_QUANTITIES)), PER_ROLLER_QUANTITIES),
            InternalBlock("per_tooth", ("roller", "tooth", "quantity"), (nr, nt, 2), PER_TOOTH_QUANTITIES),
            InternalBlock("carrier", ("quantity",), (len(CARRIER_QUANTITIES),), CARRIER_QUANTITIES),
            InternalBlock("elastic", ("quantity",), (len(ELASTIC_QUANTITIES),), ELASTIC_QUANTITIES),
            InternalBlock("per_thread", ("tooth", "quantity"), (nt, 2), PER_THREAD_QUANTITIES),
        ))
        self._gather = self._gather_index()
        self._share_loads = self.law.shares[0].tolist()
        law = self.law
        m_core = self._m_core
        self.constants = ElasticConstants(
            p=self.p, m=self.m, mu=self.mu, zeta=self.zeta, substeps=float(self.substeps), hs=self.core.dt_s,
            breakaway=float(self.breakaway), eta_sf=self.eta_static[0], eta_sb=self.eta_static[1], w_stick=self.w_stick,
            czs=self.czs, sin_beta=self.sin_beta, mu_c=self.mu_c, eta_rf=self.eta_running[0],
            eta_rb=self.eta_running[1], d_mu=self.d_mu, p_sb_vs=self.p_over_sin_beta_per_vs, clearance=law.clearance,
            preload=law.preload, law_a=law.side.a, law_b=law.side.b, ea=law.ea, x_bearing=law.x_bearing,
            c_housing=law.c_housing, d0=law.d0, v0=law.v0, m00=m_core[0][0], m01=m_core[0][1], m11=m_core[1][1],
            impact_tol=IMPACT_TOL, impact_floor=IMPACT_FLOOR, impact_iter=float(IMPACT_ITERATIONS))
        self._kernel_e = np.array(self.constants, dtype=float)  # the compiled kernel's (`kernels.ElasticConstants`)
        if self._kn is not None:  # compiled or loaded from the disk cache now, not in a realtime loop's first step
            self._kn.elastic_advance(*self._kernel_args(self.initial_state()), 0.0, 0.0, self._kernel_e,
                                     self.core._kernel_k, self.core._kernel_s)

    def initial_state(self, nut_position_m: float = 0.0, load_n: float = 0.0) -> State:
        """At rest with the nut at `nut_position_m`; under a nut load F the chain is deflected to carry it
        (contacts, teeth, nut body, shaft and housing: the law's static solution, docs/model.md §4.3) and
        the core holds the static friction state of F (`Fu2018.initial_state`): started with the
        holding torque (L/2π) F, the thread force is F from the first step."""
        s = super().initial_state(nut_position_m)
        x = float(nut_position_m)
        if load_n == 0.0:
            return replace(s, part=ElasticPart(nut_axial_m=x))
        core = self.core.initial_state(nut_position_m, load_n).part
        f = load_n  # the nut's balance: thread force + the shaft-length term (−∂V/∂x_N) = load
        for _ in range(3):
            f = load_n - self.law.nut_side_force(f, x)
        delta = self.law.deflection_at(f, x)
        return replace(s, screw_angle_rad=(x + delta) / self.p,
                       part=ElasticPart(flank_sign=core.flank_sign, pin_force_n=core.pin_force_n,
                                        gear_force_n=core.gear_force_n, nut_axial_m=x))

    def nut_motion(self, state: State) -> tuple[float, float]:
        """The nut's own position (m) and velocity (m/s) in `state`."""
        return state.nut_axial_m, state.nut_speed_m_s

    def _core_step(self, ws, wc, sign, pin_abs, gear, mem, tau, load):
        """One `fu2018` step of the core (length core.dt_s) under a held thread force.

        Returns (ω_S, ω_C, Δθ_S, Δθ_C, dissipated J, end forces, flank sign, pin force, gear force,
        solver memory): `Fu2018._step`, with its stick and its error-controlled sub-steps at friction
        transitions.
        """
        return self.core._step(ws, wc, sign, pin_abs, gear, mem, tau, load)

    def _holds(self, torque_nm: float, thread_force_n: float) -> bool:
        """Static friction holds the screw at rest: the torque lies inside the breakaway band
        [p F η_b,s, p F/η_f,s] (mirrored for F < 0), efficiencies at μ_s = breakaway_ratio · μ."""
        eta_f, eta_b = self.eta_static
        t = self.p * thread_force_n
        lo, hi = (t * eta_b, t / eta_f) if t >= 0 else (t / eta_f, t * eta_b)
        return lo <= torque_nm <= hi

    def _core_holds(self, torque_nm: float, thread_force_n: float, sign, pin_abs, gear) -> bool:
        """The running law's static friction (fu2018 `stick_forces`) holds the screw at rest under the torque
        left once the static Stribeck excess has taken its share (`_rest_torque`)."""
        st, r = self.core.stick_forces(self._rest_torque(torque_nm, thread_force_n), thread_force_n, sign, pin_abs,
                                       1.0 if gear >= 0.0 else -1.0)
        return st is not None and r <= 1.0

    def _core_kinetic_j(self, ws: float, wc: float) -> float:
        (m00, m01), (_, m11) = self._m_core
        return 0.5 * (m00 * ws * ws + 2 * m01 * ws * wc + m11 * wc * wc)

    # -- energy ---------------------------------------------------------------------------
    def total_stored_energy_j(self, state: State) -> float:
        """Kinetic energy of the core and the nut plus the chain's elastic energy (J), at the state's
        clearance (`State.extra_clearance_m` added to the parameter's)."""
        delta = self.p * state.screw_angle_rad - state.nut_axial_m
        _, _, v, _ = self.law.evaluate(delta, state.nut_axial_m, state.extra_clearance_m)
        return self._stored_j(state.screw_speed_rad_s, state.carrier_speed_rad_s, state.nut_speed_m_s, v)

    def _stored_j(self, ws: float, wc: float, v_n: float, v_el: float) -> float:
        """Core and nut kinetic energy plus the chain's elastic energy `v_el` (J)."""
        return self._core_kinetic_j(ws, wc) + 0.5 * self.m * v_n**2 + v_el

    # -- stepping -------------------------------------------------------------------------
    def _force(self, th_s, w_s, x_n, v_n, extra=0.0):
        delta = self.p * th_s - x_n
        f, k, v, lost = self.law.evaluate(delta, x_n, extra)
        c = 2.0 * self.zeta * math.sqrt(k * self.mu) if k > 0 else 0.0
        rate = self.p * w_s - v_n
        return f + c * rate, f, k, v, lost, delta, c

    def _stribeck_torque(self, ws: float, thread_force_n: float) -> float:
        """Excess friction torque (N m, resisting ω_S) of the Stribeck law over `fu2018`'s running friction.

        μ(v) = μ_c + (μ_s − μ_c) exp(−(v/v_s)²) at the screw–roller slip v = |ω_S| p / sin β (docs/model.md §3),
        expressed through the sliding-only efficiencies of docs/model.md §4.2: driving (ω_S F ≥ 0) the screw
        torque of the sliding contacts is p|F|/η_f(μ), back-driven p|F| η_b(μ); the excess is the difference
        between μ(v) and μ_c. Zero when `breakaway_ratio` is 1 or the screw is at rest (`_rest_torque` then).
        """
        if not self.breakaway or ws == 0.0:
            return 0.0
        r = ws * self.p_over_sin_beta_per_vs
        g = math.exp(-r * r)
        if g < 1e-12:
            return 0.0
        ex = self._excess(ws, thread_force_n, g)
        return ex if ws > 0.0 else -ex

    def _excess(self, direction: float, thread_force_n: float, g: float) -> float:
        """|excess torque| (N m) for motion in `direction` (sign of ω_S) at Stribeck decay g = exp(−(v/v_s)²)."""
        mu = self.mu_c + self.d_mu * g
        eta_f, eta_b = _sliding_efficiencies(self.czs, self.sin_beta, mu)
        eta_fc, eta_bc = self.eta_running
        t = abs(self.p * thread_force_n)
        # driving (ω_S F ≥ 0): p|F|/η_f(μ) less its running value; back-driven: p|F| η_b(μ_c) less p|F| η_b(μ)
        return t * (1.0 / eta_f - 1.0 / eta_fc) if direction * thread_force_n >= 0.0 else t * (eta_bc - eta_b)

    def _rest_torque(self, torque_nm: float, thread_force_n: float) -> float:
        """Screw torque the core sees at rest: the Stribeck excess at zero slip acts as extra static friction
        against the net torque τ − p F, up to its full value (the v → 0 limit of `_stribeck_torque`), so the
        screw breaks away where the running law's stick band plus that excess ends (p F/η_f,s with frictionless
        pins), and the friction just after breakaway is the friction just before it."""
        d = torque_nm - self.p * thread_force_n
        if not self.breakaway or d == 0.0:
            return torque_nm
        ex0 = self._excess(d, thread_force_n, 1.0)
        return torque_nm - math.copysign(min(abs(d), ex0), d)

    def _kernel_args(self, s: State) -> tuple:
        """The state as the compiled kernel takes it (floats; the solver memory as `kernels.kernel_memory`)."""
        # float() on every field: an int (a user's replace(state, nut_axial_m=0)) would make numba compile a
        # second specialisation on the spot
        q = s.part if isinstance(s.part, ElasticPart) else ElasticPart(*s.part)
        return (float(s.screw_angle_rad), float(s.screw_speed_rad_s), float(s.carrier_angle_rad),
                float(s.carrier_speed_rad_s), float(q.nut_axial_m), float(q.nut_speed_m_s), float(q.flank_sign),
                float(q.pin_force_n), float(q.gear_force_n), kernel_memory(q.solver), float(q.screw_accel_rad_s2),
                float(q.extra_clearance_m))

    def _run_impl(self, state: State, torque_nm: np.ndarray, load_n: np.ndarray) -> Trajectory:
        """The batch form: with the compiled kernel the whole loop runs compiled and the internal-load block is
        built when first read; the reference path is the step repeated."""
        if self._kn is None:
            return super()._run_impl(state, torque_nm, load_n)
        n = len(torque_nm)
        cols, comp = np.empty((n, 17)), np.empty((n, len(PER_ROLLER_QUANTITIES) + len(CARRIER_QUANTITIES)))
        args = self._kernel_args(state)
        th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc = self._kn.elastic_run(
            *args, torque_nm, load_n, self._kernel_e, self.core._kernel_k, self.core._kernel_s, cols, comp)
        extra = args[-1]
        final = State(screw_angle_rad=th_s, screw_speed_rad_s=ws, carrier_angle_rad=th_c, carrier_speed_rad_s=wc,
                      part=ElasticPart(int(sign), pin_abs, gear, memory_from_kernel(mem), x_n, v_n, acc, extra))

        def internal():
            return np.array([self._internal(comp[i], *cols[i, 12:17], cols[i, 5], cols[i, 4], extra)
                             for i in range(n)], dtype=float).reshape(n, self.layout.size)
        return trajectory_from_columns(
            state, final, self.total_stored_energy_j(state), dt_s=self.dt_s, gear_ratio=self.geo.gear_ratio,
            layout=self.layout, internal=internal, torque_nm=torque_nm, load_n=load_n, th_s=cols[:, 0],
            w_s=cols[:, 1], th_c=cols[:, 2], w_c=cols[:, 3], dtheta=cols[:, 8], nut_x=cols[:, 4], nut_v=cols[:, 5],
            nut_force=cols[:, 6], slip=cols[:, 7], work_out_j=cols[:, 9], dissipated_j=cols[:, 10],
            stored_j=cols[:, 11])

    def _make_step(self):
        """The step: `_substeps` and the ledger. The stored energy from the chain's energy the sub-steps end
        with (`_stored_j`: `total_stored_energy_j` would evaluate the chain law again); the step's end forces
        and chain figures are the record's aux, from which the slip speed and the internal vector
        (`_internal`) are derived when read.
        """
        substeps, stored, internal = self._substeps, self._stored_j, self._internal
        finish = self.finisher(lambda w_s, w_c, aux: slip_speed(aux[0]),
                               lambda w_s, w_c, aux: internal(aux[0].compact, *aux[1:]))

        def step(x, torque_nm: float, load_n: float):
            sign, pin_abs, gear, mem, x_n, v_n, acc, extra = x[11]
            (ws, wc, th_s, th_c, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f_th, f1, f_el, k, v_el, lost,
             delta) = substeps(x[2], x[4], x[1], x[3], x_n, v_n, sign, pin_abs, gear, mem, acc, extra, torque_nm,
                               load_n)
            return finish(x, th_s, ws, th_c, wc, torque_nm, load_n, diss, stored(ws, wc, v_n, v_el),
                          (sign, pin_abs, gear, mem, x_n, v_n, acc, extra),
                          (f1, f_el, k, v_el, lost, delta, v_n, x_n, extra), f_th, (x_n, v_n, w_out))
        return step

    def _substeps(self, ws, wc, th_s, th_c, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, torque_nm, load_n):
        """One output step of `substeps` sub-steps (module doc), on plain floats.

        Returns (ω_S, ω_C, θ_S, θ_C, x_N, v_N, flank sign, pin force, gear force, solver memory, screw
        acceleration, dissipated J, the load's work J, thread force on the nut N, the core's end forces, and
        the chain's elastic force, tangent stiffness, energy, lost motion and deflection at the end).
        With the compiled kernel: `models.kernels.elastic_advance`, the same arithmetic.
        """
        if self._kn is not None:
            (th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f1, f_el0, k, v_el0, lost, delta,
             f_th, _) = self._kn.elastic_advance(
                float(th_s), float(ws), float(th_c), float(wc), float(x_n), float(v_n), float(sign), float(pin_abs),
                float(gear), kernel_memory(mem), float(acc), float(extra), float(torque_nm), float(load_n),
                self._kernel_e, self.core._kernel_k, self.core._kernel_s)
            return (ws, wc, th_s, th_c, x_n, v_n, int(sign), pin_abs, gear, memory_from_kernel(mem), acc, diss,
                    w_out, f_th, Forces(*f1), f_el0, k, v_el0, lost, delta)
        hs, m, core, law, p = self.core.dt_s, self.m, self.core, self.law, self.p
        diss = 0.0
        f_th, f_el0, k, v_el0, lost, delta, c0 = self._force(th_s, ws, x_n, v_n, extra)
        w_out = 0.0
        for _ in range(self.substeps):
            # Screw side and nut see the same thread force, taken at the sub-step's midpoint (predicted with
            # the accelerations at its start): equal and opposite impulses, second order in the axial mode.
            a_n = (f_th - load_n + law.nut_side_force(f_el0, x_n)) / m
            x_mid = x_n + 0.5 * hs * v_n + 0.125 * hs * hs * a_n
            _, f_el, k_mid, _, _, _, c = self._force(th_s + 0.5 * hs * ws + 0.125 * hs * hs * acc, ws + 0.5 * hs * acc,
                                                     x_mid, v_n + 0.5 * hs * a_n, extra)
            rate = p * (ws + 0.5 * hs * acc) - (v_n + 0.5 * hs * a_n)
            f_str = self._stribeck_torque(ws, f_el + c * rate)
            best = None
            for attempt in range(IMPACT_ITERATIONS + 1):
                f_mid = f_el + c * rate
                stuck = self.breakaway and ws == 0.0 and wc == 0.0 and self._holds(torque_nm, f_mid)
                if stuck:  # static friction holds the screw: no creep below breakaway
                    f1 = core.solve_forces((0.0, 0.0), torque_nm, f_mid, sign, pin_abs, 1.0 if gear >= 0 else -1.0)
                    ws1, wc1, dth_s, dth_c, d_core = 0.0, 0.0, 0.0, 0.0, 0.0
                    sign1, pin1, gear1, mem1 = sign, pin_abs, gear, mem
                else:
                    if ws == 0.0 and wc == 0.0:
                        f_str = torque_nm - self._rest_torque(torque_nm, f_mid)
                    ws1, wc1, dth_s, dth_c, d_core, f1, sign1, pin1, gear1, mem1 = self._core_step(
                        ws, wc, sign, pin_abs, gear, mem, torque_nm - f_str, f_mid)
                nsf = law.nut_side_force(f_el, x_mid)
                v1 = v_n + hs * (f_mid - load_n + nsf) / m
                dx = 0.5 * hs * (v_n + v1)
                d_delta = p * dth_s - dx
                _, f_el1, k1, v_el1, lost1, delta1, c1 = self._force(th_s + dth_s, ws1, x_n + dx, v1, extra)
                # Energy consistency of the held elastic force: its work f Δδ (+ the nut-side term) must equal
                # the change of V. Where the contact closes or opens inside the sub-step (a backlash crossing,
                # an impact) the midpoint force does not see it and misses by up to the whole V of the
                # sub-step. There the sub-step is redone with the secant force (V₁ − V₀ − nsf Δx)/Δδ of the
                # last attempt (a discrete gradient: its work is ΔV exactly), a contraction since (ωh)²/2 < 1;
                # the attempt with the smallest miss is kept. Only sub-steps that miss pay for it (crossings, the
                # first sub-steps of a Hertz contact; smooth contact passes the first time).
                err = f_el * d_delta + nsf * dx - (v_el1 - v_el0)
                if best is None or abs(err) < abs(best[0]):
                    best = (err, f_el, c, rate, stuck, f1, ws1, wc1, dth_s, dth_c, d_core, sign1, pin1, gear1, mem1,
                            v1, dx, d_delta, f_el1, k1, v_el1, lost1, delta1, c1, f_mid)
                if (attempt == IMPACT_ITERATIONS or abs(d_delta) < 1e-15
                        or abs(err) <= IMPACT_TOL * abs(torque_nm * dth_s) + IMPACT_FLOOR * (abs(v_el1) + abs(v_el0))):
                    break
                f_el = (v_el1 - v_el0 - nsf * dx) / d_delta
                rate = d_delta / hs
                # damping on the sub-step's mean rate, with the stiffer of the two tangent stiffnesses seen
                # (at a contact entry the predicted midpoint may still lie in the gap, K = 0)
                c = 2.0 * self.zeta * math.sqrt(max(k_mid, k1) * self.mu) if max(k_mid, k1) > 0 else 0.0
            (err, f_el, c, rate, stuck, f1, ws1, wc1, dth_s, dth_c, d_core, sign1, pin1, gear1, mem1,
             v1, dx, d_delta, f_el1, k1, v_el1, lost1, delta1, c1, f_mid) = best
            # the held damping force and Stribeck torque take out exactly the work they did over the sub-step
            diss += d_core + c * rate * d_delta + f_str * dth_s
            sign, pin_abs, gear, mem = sign1, pin1, gear1, mem1
            acc = (ws1 - ws) / hs
            th_s += dth_s
            th_c += dth_c
            if (self.breakaway and not stuck and abs(ws1) < self.w_stick
                    and (self._holds(torque_nm, f_mid) or self._core_holds(torque_nm, f_mid, sign, pin_abs, gear))):
                # Karnopp: slower than the stick window with the torque inside the breakaway band (or the running
                # law's stick band widened by the static excess), the screw sticks; its kinetic energy (and the
                # carrier's) goes to friction, counted in the ledger
                diss += self._core_kinetic_j(ws1, wc1)
                ws1 = wc1 = acc = 0.0
                _, f_el1, k1, v_el1, lost1, delta1, c1 = self._force(th_s, 0.0, x_n + dx, v1, extra)
            x_n += dx
            v_n = v1
            w_out += load_n * dx
            ws, wc = ws1, wc1
            f_el0, k, v_el0, lost, delta = f_el1, k1, v_el1, lost1, delta1
            f_th = f_el1 + c1 * (p * ws - v_n)
        return (ws, wc, th_s, th_c, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f_th, f1, f_el0, k, v_el0,
                lost, delta)

    def _internal(self, compact, f_el, k, v_el, lost, delta, v_n, x_n=0.0, extra=0.0) -> np.ndarray:
        """Output block: fu2018's per-roller, per-tooth and carrier quantities, the chain, the per-thread loads.

        Per thread: unpreloaded and oversize rollers, one row per tooth row, thread load ζ_k |F|/N_T with ζ
        the solved distribution at |F| (sums to |F|). Double nut: rows 0 … N_T/2 − 1 are half A (the flank
        set that δ > 0 loads: P₀ + its share of F), rows N_T/2 … N_T − 1 half B (P₀ − its share, zero once
        lifted off); each half carries its own solved distribution at its own force Q_A or Q_B, so each half's
        rows sum to that half's force and Q_A − Q_B = F. `load_share` is the thread load over the mean
        thread load (Q_A + Q_B)/N_T, so the column sums to N_T. The per-tooth block spreads fu2018's contact
        forces (for the net thread force) over the rows by `load_share`.
        """
        nt = self.geo.n_teeth
        if self.law.double_nut:
            qa, qb = self.law.pair_forces(delta, x_n)
            thread_load = np.concatenate([self._shares_at(qa) * qa, self._shares_at(qb) * qb]) / self.law.n_side
            mean = (qa + qb) / nt
            shares = thread_load / mean if mean > 0 else np.ones(nt)
        else:
            fa = abs(f_el)
            shares = self._shares_at(fa)
            thread_load = shares * fa / nt
        spread = shares / nt
        # one gather from [compact, the chain, ζ/N_T N_S, ζ/N_T N_N, thread loads, shares] (`_gather_index`)
        src = np.concatenate((compact, (delta, lost, f_el, k, v_el, v_n), spread * compact[0], spread * compact[1],
                              thread_load, shares))
        return src[self._gather]

    def _gather_index(self) -> np.ndarray:
        """Positions in `_internal`'s source vector of every element of the layout."""
        geo = self.geo
        nr, nt, nq = geo.n_rollers, geo.n_teeth, len(PER_ROLLER_QUANTITIES)
        ncomp = nq + len(CARRIER_QUANTITIES)
        nel = len(ELASTIC_QUANTITIES)
        start = ncomp + nel  # the two per-tooth columns, then thread loads and shares, nt each
        per_tooth = np.tile((start + np.arange(nt)[:, None] + nt * np.arange(2)[None, :]).ravel(), nr)
        thread = (start + 2 * nt + np.arange(nt)[:, None] + nt * np.arange(2)[None, :]).ravel()
        return np.concatenate([np.tile(np.arange(nq), nr), per_tooth, np.arange(nq, ncomp),
                               np.arange(ncomp, ncomp + nel), thread])

    def _shares_at(self, force_n: float) -> np.ndarray:
        """ζ of one flank set's rows at axial force `force_n` ≥ 0, interpolated in the solved table."""
        loads, table = self.law.shares
        j = bisect.bisect_left(self._share_loads, force_n)  # np.searchsorted's answer without its call overhead
        if j <= 0:
            return table[0]
        if j >= len(loads):
            return table[-1]
        w = (force_n - loads[j - 1]) / (loads[j] - loads[j - 1])
        return (1 - w) * table[j - 1] + w * table[j]


Elastic = ElasticModel  # the model's name before the parameter group took `Elastic`; an alias for one release
