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
the stiffest axial mode with the nut at the centre (several hundred Hz at a 1 ms step: 8 sub-steps for `s30`), times
2^j where the chain can reach ω h > OMEGA_H_REFINE at the nut's position (the nut near the fixed bearing: a short
shaft; `kernels._refinement`); each sub-step is a kick–drift–kick
(velocity Verlet) for the nut with one `fu2018` ROS2 step (L-stable, its own stiff carrier mode)
for the rotating core under the thread force, taken at the sub-step's midpoint. Impacts: where the
held elastic force's work f Δδ less the shaft-length force's nsf Δx misses the change of V (a contact
closing or opening inside the sub-step, an impact, the first sub-steps of a Hertz contact) by more
than IMPACT_TOL of the sub-step's input work plus IMPACT_FLOOR of V where the miss takes energy out
(then booked as the contact's loss), of the sub-step's change of V where it would create energy, the
sub-step is redone with the
discrete gradient (V₁ − V₀ + nsf Δx)/Δδ, whose work is ΔV exactly (Gonzalez 1996), then by secant
steps (at most IMPACT_ITERATIONS times, the best attempt kept). Where the path jumps with the force
(a flank impact reversing the screw into static friction), the attempt kept creates no energy and
its miss is booked as the contact's loss (Armero & Petőcz 1998; docs/model.md §4.3, Impacts). Where every
attempt would create energy (the screw breaks away from static friction and the force its turning builds would
hold it again inside the sub-step), the output step is taken again at twice its sub-steps, up to the finest
refinement level (REFINE_LEVELS).
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
from typing import NamedTuple, cast

import numpy as np

from prsm_sim.models import kernels
from prsm_sim.models.fu2018 import (CARRIER_QUANTITIES, PER_ROLLER_QUANTITIES, PER_TOOTH_QUANTITIES, Forces, Fu2018,
                                    Fu2018Part, slip_speed)
from prsm_sim.models.kernels import ROOT_STEP_TOL  # noqa: F401 (public here, where the chain law is described)
from prsm_sim.models.kernels import ElasticConstants, kernel_memory, memory_from_kernel, specialised
from prsm_sim.params import END_STOP_STIFFNESS_N_M, Params
from prsm_sim.physics import load_sharing as ls
from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.physics.kinematics import ideal_carrier_ratio
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
# A step whose chain can reach ω h above OMEGA_H_REFINE at the nut's position (the nut near the fixed bearing: a short
# shaft, up to 4 times the stiffness at the centre) takes 2, 4 … 2^(REFINE_LEVELS − 1) times the sub-steps
# (`kernels._refinement`): the Verlet phase error stays below (0.75)²/24 ≈ 2.3 % (it reached 4 % on s30's thread
# end next to the bearing), and the steps of the central travel, where the count was sized, cost nothing more.
OMEGA_H_REFINE = 0.75
REFINE_LEVELS = 4
# the books each core sub-step must close to (`kernels._books_open`): a quarter of the energy guard's share. A
# sub-step is the chain's (~130 µs on s30 at any output step), and the elastic step closes the output step's books
# itself (its impacts and the held elastic force); fu2018's own twentieth (`fu2018.STEP_BALANCE_TOL`) is
# for output steps of 20-100 ms, and here it sent an 80 kN press onto a thread end at 43 ms down other
# sub-step paths that tripped the guard
CORE_STEP_BALANCE_TOL = 2.5e-4
FIT_RANGE = (1e-4, 0.5)  # fraction of the static rating over which δ_nut(F) is fitted
# A sub-step whose held elastic force missed the change of V by more than IMPACT_TOL of the sub-step's input work
# |τ Δθ_S| plus IMPACT_FLOOR of the elastic energy at its ends is redone, at most IMPACT_ITERATIONS times: first
# with the secant force of the attempt (cuts the miss by about (ωh)²/4), then by the secant through the last two
# attempts (about 1e-2 of the miss left each time). The ledger's cumulative miss is then of order IMPACT_TOL of
# the flow; smooth contact passes on the first attempt (backlash crossings and the first sub-steps of a Hertz
# contact pay: about 25 % more core steps on ±20 rad/s reversals into 50 µm of play).
# The floor is small: a chain that rings (a load step near the rating, an impact, the screw held with no input
# work) stores far more than flows through it per sub-step, and misses of 1e-4 V per sub-step added up to 3e-4 of
# the flow after a 200 kN load step; at 1e-5 about 2 % of default sub-steps are redone (1e-4: 0.7 %). A miss
# that would create energy gets the floor of the sub-step's change of V instead (`kernels._settled`): a chain
# released from its hold under 230 kN stores ~40 J while its first steps move millijoules, and 1e-5 V there
# was 1.5 % of their flow.
IMPACT_TOL = 1e-4
IMPACT_FLOOR = 1e-5
IMPACT_ITERATIONS = 4
_LAW = kernels.load("reference")


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


# the chain law's arithmetic, written once in `models.kernels` (uncompiled here: these run outside the step)
power_law_root = _LAW._power_root  # s = F^(1/3) with δ = a F^(2/3) + b F (`kernels._power_root`)
_stiffness_at_root = _LAW._stiffness_at_root
_complementary_at_root = _LAW._complementary_at_root
_sliding_efficiencies = _LAW._sliding_eff  # (η_f, η_b) from c_zS, sin β and μ (`kernels._sliding_eff`)


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
        self.side = fit_side(self.joint, params.resolved_ratings.static_load_rating_n)
        self.ea = params.material.youngs_modulus_pa * ls.screw_section_m2(params)
        self.x_bearing = params.resolved_elastic.bearing_position_m
        k_h = el.housing_stiffness_n_per_m
        self.c_housing = 0.0 if math.isinf(k_h) else 1.0 / k_h
        self.d0 = self.side.approach(self.preload) if self.preload > 0 else 0.0
        self.v0 = (self.preload * self.d0 - self.side.complementary(self.preload)) if self.preload > 0 else 0.0
        self.shares = _share_table(self.joint, params.resolved_ratings.static_load_rating_n)
        # the law's constants as the step's kernels read them (the rest of `ElasticConstants` is the model's)
        self.constants = ElasticConstants(*(math.nan,) * len(ElasticConstants._fields))._replace(
            clearance=self.clearance, preload=self.preload, law_a=self.side.a, law_b=self.side.b, ea=self.ea,
            x_bearing=self.x_bearing, c_housing=self.c_housing, d0=self.d0, v0=self.v0, inv_ea=1.0 / self.ea)

    def external_compliance(self, x_n: float) -> tuple[float, float]:
        """(ℓ/EA + 1/K_h, its derivative in x_N)."""
        ell = x_n - self.x_bearing
        s = 1.0 if ell >= 0 else -1.0
        return max(abs(ell), 1e-6) / self.ea + self.c_housing, s / self.ea

    def evaluate(self, delta: float, x_n: float, extra_clearance_m: float = 0.0) -> tuple[float, float, float, float]:
        """(F, K = dF/dδ, V, lost motion) at deflection δ and nut position x_N, with the clearance
        widened by `extra_clearance_m` (a growing-backlash fault; unpreloaded nuts only): `kernels.law_evaluate`.
        """
        return _LAW.law_evaluate(delta, x_n, extra_clearance_m, self.constants)

    def pair_forces(self, delta: float, x_n: float) -> tuple[float, float]:
        """(Q_A, Q_B) of a preloaded pair at δ: the flank set that δ > 0 loads, and the opposed one (N)."""
        c_ext, _ = self.external_compliance(x_n)
        f = self.evaluate(delta, x_n)[0]
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
            The sub-step loop's source (core included), `models.kernels`, run as numba code ("compiled") or
            by the Python interpreter ("reference").
        """
        self._kn = kernels.load(kernel)
        self.kernel = kernel
        super().__init__(params, dt_s)
        self.law = AxialLaw(params)
        self.m = params.mass.moved_mass_kg
        self.p = self.geo.lead_per_rad_m
        # the rotating core: fu2018 with the moved mass taken off (the nut is its own body here); its idle flanks
        # press with this model's preload P₀ (held at its zero-load value: exact at zero load, where a preload
        # torque is specified), not the rigid nut's internal preload, which the chain's clearance replaces
        core_params = params.with_overrides({"mass.moved_mass_kg": 1e-9 * self.m,
                                             "drag.internal_preload_n": params.elastic.preload_n})
        ms, _ = ls.axial_masses_kg(params)
        self.screw_side_mass_kg = ms
        self.mu = ms * self.m / (ms + self.m)
        self.zeta = params.elastic.contact_damping_ratio
        chain = ls.AxialChain(params)  # built once: a preloaded pair's is 401 load-distribution solves
        k_max = max(chain.at(f).stiffness_n_per_m for f in (0.0, 0.5 * params.resolved_ratings.static_load_rating_n))
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
        self._contact_setup()
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
        self.constants = law.constants._replace(
            p=self.p, m=self.m, inv_m=1.0 / self.m, mu=self.mu, zeta=self.zeta, substeps=float(self.substeps),
            hs=self.core.dt_s, breakaway=float(self.breakaway), eta_sf=self.eta_static[0], eta_sb=self.eta_static[1],
            w_stick=self.w_stick, czs=self.czs, sin_beta=self.sin_beta, mu_c=self.mu_c, eta_rf=self.eta_running[0],
            eta_rb=self.eta_running[1], d_mu=self.d_mu, p_sb_vs=self.p_over_sin_beta_per_vs, m00=m_core[0][0],
            m01=m_core[0][1], m11=m_core[1][1], impact_tol=IMPACT_TOL, impact_floor=IMPACT_FLOOR,
            impact_iter=float(IMPACT_ITERATIONS), c_side=self._side_compliance(), wh_refine=OMEGA_H_REFINE)
        # the step's constants (`kernels.ElasticConstants`): a float array for numba, a tuple of Python floats for
        # the interpreter (`_law_e` always the tuple: the stored energy is computed outside the step too)
        self._law_e = tuple(self.constants)
        self._kernel_e: tuple | np.ndarray = self._law_e
        self._kernel_core = self._core_levels(kernel)
        self._advance = self._kn.elastic_advance
        if kernel == "compiled":
            self._kernel_e = np.array(self._law_e, dtype=float)
            # compiled or loaded from the disk cache now, not in a realtime loop's first step
            warm = (*self._kernel_args(self.initial_state()), 0.0, 0.0, self._kernel_e, *self._kernel_core)
            self._kn.elastic_advance(*warm)
            self._advance = specialised(self._kn.elastic_advance, *warm)  # the per-step path's entry

    def _core_levels(self, kernel: str) -> tuple:
        """(the core's constants per refinement level j: row j steps hs/2^j, its flank geometry), as the step's
        kernel takes them (`kernels.elastic_advance`'s KL, S: arrays compiled, tuples of floats otherwise)."""
        c0 = self.core.constants._replace(balance_tol=CORE_STEP_BALANCE_TOL)
        levels = tuple(tuple(c0._replace(h=c0.h / 2**j, h_min=c0.h_min / 2**j, h_zone=c0.h_zone / 2**j))
                       for j in range(REFINE_LEVELS))
        if kernel == "compiled":
            return np.array(levels, dtype=float), self.core.kernel_constants[1]
        return levels, self.core.kernel_constants[1]

    def _side_compliance(self) -> float:
        """Compliance of the nut's flank set(s) at the static rating, m/N: the stiffest the chain's nut side gets
        (a preloaded pair: both sets, each at most as stiff as one at the rating, in parallel)."""
        side = self.law.side
        c = side.compliance(self.params.resolved_ratings.static_load_rating_n)
        return 0.5 * c if self.law.preload > 0 else c

    def initial_state(self, nut_position_m: float = 0.0, load_n: float = 0.0) -> State:
        """At rest with the nut at `nut_position_m`; under a nut load F the chain is deflected to carry it
        (contacts, teeth, nut body, shaft and housing: the law's static solution, docs/model.md §4.3) and
        the core holds the static friction state of F (`Fu2018.initial_state`): started with the
        holding torque (L/2π) F, the thread force is F from the first step."""
        s = super().initial_state(nut_position_m)
        x = float(nut_position_m)
        if load_n == 0.0:
            return replace(s, part=ElasticPart(nut_axial_m=x))
        core = cast(Fu2018Part, self.core.initial_state(nut_position_m, load_n).part)  # the core's part_type
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

    # -- energy ---------------------------------------------------------------------------
    def total_stored_energy_j(self, state: State) -> float:
        """Kinetic energy of the core and the nut plus the chain's elastic energy (J), at the state's
        clearance (`State.extra_clearance_m` added to the parameter's)."""
        delta = self.p * state.screw_angle_rad - state.nut_axial_m
        _, _, v, _ = self.law.evaluate(delta, state.nut_axial_m, state.extra_clearance_m)
        return self._stored_j(state.screw_speed_rad_s, state.carrier_speed_rad_s, state.nut_speed_m_s, v)

    def _stored_j(self, ws: float, wc: float, v_n: float, v_el: float) -> float:
        """Core and nut kinetic energy plus the chain's elastic energy `v_el` (J), as the step books it."""
        return _LAW._core_kinetic(ws, wc, self._law_e) + 0.5 * self.m * v_n ** 2.0 + v_el

    # -- stepping: `kernels.elastic_advance`, the one source (compiled or uncompiled) ---------------------
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
        """The batch form: one call of `kernels.elastic_run`; the internal-load block is built when first read."""
        n = len(torque_nm)
        cols, comp = np.empty((n, 17)), np.empty((n, len(PER_ROLLER_QUANTITIES) + len(CARRIER_QUANTITIES)))
        args = self._kernel_args(state)
        th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc = self._kn.elastic_run(
            *args, torque_nm, load_n, self._kernel_e, *self._kernel_core, cols, comp)
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
        """The step: `kernels.elastic_advance` (`substeps` sub-steps, module doc) and the ledger. The stored energy
        from the chain's energy the sub-steps end with (`_stored_j`: `total_stored_energy_j` would evaluate the
        chain law again); the step's end forces
        and chain figures are the record's aux, from which the slip speed and the internal vector
        (`_internal`) are derived when read.
        """
        advance, kernel_e, core, internal = self._advance, self._kernel_e, self._kernel_core, self._internal
        finish = self.finisher(lambda w_s, w_c, aux: slip_speed(aux[0]),
                               lambda w_s, w_c, aux: internal(aux[0].compact, *aux[1:]))
        l_stable, contact, rigid_shift = self.reverses_l_stable, self._contact, self._rigid_shift

        # the packed part is in the kernel's own form (`packed_part`): floats from the last step or `pack_state`,
        # the inputs floats from the caller's checks, so the step converts nothing
        def step(x, torque_nm: float, load_n: float):
            sign, pin_abs, gear, mem, x_n, v_n0, acc, extra = x[11]
            (th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f1, f_el, k, v_el, lost, delta,
             f_th, e_end) = advance(x[1], x[2], x[3], x[4], x_n, v_n0, sign, pin_abs, gear, mem, acc, extra, torque_nm,
                                    load_n, kernel_e, *core)
            if l_stable and contact[0] and x[2] * ws < 0.0:
                shifted = rigid_shift(x[1], th_s, ws, th_c, x_n, v_n, extra, torque_nm, load_n, v_el)
                if shifted is not None:
                    th_s, th_c, x_n, f_th, f_el, k, v_el, lost, delta, d_w_out, d_diss, d_v = shifted
                    w_out, diss, e_end = w_out + d_w_out, diss + d_diss, e_end + d_v
            return finish(x, th_s, ws, th_c, wc, torque_nm, load_n, diss, e_end,
                          (sign, pin_abs, gear, mem, x_n, v_n, acc, extra),
                          (Forces(*f1), f_el, k, v_el, lost, delta, v_n, x_n, extra), f_th, (x_n, v_n, w_out))
        return step

    def _contact_setup(self) -> None:
        """Against an end or stop the step does not resolve (h √(k/m) > 2 for the ends' default 1e8 N/m on the
        train's reflected mass: the nut's and the core's J/p²) the position-consistent stop force held over the
        step reflects the train's speed (v₁ ≈ −v₀, as the trapezoid does) and the contact's damping takes many
        steps to end that ring; a contact trial that reverses the screw is then backward Euler in the rigid mode
        (`_rigid_shift`), as `ideal` takes its own (`jones2016` takes every contact trial so; shifting the trials
        that do not reverse too undoes the settling of a train back-driven onto an end,
        tests/test_envelope_large_steps.py)."""
        omega_end = math.sqrt(END_STOP_STIFFNESS_N_M / (self.m + self._m_core[0][0] / self.p**2))
        self.reverses_l_stable = self.dt_s * omega_end > 2.0
        self._contact = [False]  # `set_contact`: only a contact's trial steps are shifted
        self._carrier_ratio = ideal_carrier_ratio(self.geo)

    def set_contact(self, on: bool) -> None:
        self._contact[0] = bool(on)

    def _rigid_shift(self, th_s0: float, th_s: float, ws: float, th_c: float, x_n: float, v_n: float, extra: float,
                     torque_nm: float, load_n: float, v_el: float) -> tuple | None:
        """A contact trial's reversing step made backward Euler in the rigid mode (`reverses_l_stable`; the screw
        reversed, which the step without the contact's force did not: `Model.in_contact`): the sub-steps' end
        speeds kept, the whole screw–nut train moved along its rigid mode (θ_S, θ_C and x_N together at the ideal
        ratios: the chain's deflection δ unchanged) so that the screw turned h ω_S₁ over the step, as
        θ₁ = θ₀ + h ω₁ has it (the screw's speed, not the nut's: the nut's own swings with the chain's mode). For
        a rigid train under the held net force F the sub-steps moved it h (v₀ + v₁)/2, so the shift
        s = h (v₁ − v₀)/2 and the forces' work over it, F s = ½ m (v₁ − v₀)², is the scheme's numerical loss,
        booked as dissipated with the change of the shaft-length term of V. Returns (θ_S, θ_C, x_N, the chain's
        end figures as `kernels._el_force` gives them, the load's extra work, the extra dissipation, the change
        of V), or None where that loss would be negative (the train not rigid over the step: the sub-steps'
        result stands)."""
        s = self.p * (self.dt_s * ws - (th_s - th_s0))
        th_s1, th_c1, x_n1 = th_s + s / self.p, th_c + self._carrier_ratio * s / self.p, x_n + s
        f_th, f_el, k, v_el1, lost, delta, _, _ = _LAW._el_force(th_s1, ws, x_n1, v_n, extra, self._law_e, 0.0)
        d_v = v_el1 - v_el
        d_diss = torque_nm * s / self.p - load_n * s - d_v
        if not d_diss >= 0.0:
            return None
        return th_s1, th_c1, x_n1, f_th, f_el, k, v_el1, lost, delta, load_n * s, d_diss, d_v

    def packed_part(self, part: ElasticPart) -> tuple:
        """The part as `kernels.elastic_advance` takes it: floats, the solver memory as `kernels.kernel_memory`."""
        return (float(part.flank_sign), float(part.pin_force_n), float(part.gear_force_n), kernel_memory(part.solver),
                float(part.nut_axial_m), float(part.nut_speed_m_s), float(part.screw_accel_rad_s2),
                float(part.extra_clearance_m))

    def state_part(self, packed: tuple) -> tuple:
        """`packed_part` undone: the flank sign an int, no solver memory ``()``; a part in `State`'s form (plain
        data) passes as it is."""
        sign, pin_abs, gear, mem, *nut = packed
        return (int(sign), pin_abs, gear, memory_from_kernel(mem) if len(mem) == 6 else mem, *nut)

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
