"""The `fu2018` spatial model: Newton–Euler force system per roller (docs/model.md §4.2, reconstructed).

Fu, Liu, Tong, Ma, Lim 2018 give the structure (seed abstract and nomenclature): a spatial
force system on screw, nut, rollers and carriers; Coulomb friction at screw–roller, rolling
friction at nut–roller, Couette drag at ring gear–carrier, gear and pin forces, a thread load
distribution coefficient ζ_T. docs/model.md §4.2 reconstructs the equations; the choices the
sources leave open are parameters (`Friction`).

Rigid bodies and identical rollers leave two independent speeds, u = (ω_S, ω_C), as in Jones
2016. At every evaluation the Newton–Euler equations of one representative roller, the screw,
the nut and the carriers are solved together for the accelerations and the internal forces
(`solve_forces`): unknowns (ω̇_S, ω̇_C, N_S, N_N, F_gt, F_pr, F_pt) —

1. screw rotation    I_S ω̇_S = τ − N_R (P_S × F_RS)_z
2. nut axial         m (L/2π) ω̇_S = N_R N_N n_N,z − F
3. roller axial      m_R a_R,z = F_RS,z + F_RN,z
4. roller radial     −m_R a ω_C² = F_RS,r + F_RN,r + F_g,r + F_pin,r
5. roller tangential m_R a ω̇_C = F_RS,t + F_RN,t + F_gt + F_pin,t
6. roller spin       I_R (1 − g) ω̇_C = (r_S × F_RS)_z + (r_N × F_RN)_z + r_g F_gt + M_pin + M_rr
7. carriers          I_C ω̇_C = N_R (−a F_pin,t − M_pin) + M_drag

with F_RS = N_S n_S + f_S (screw on roller, at the exact contact of docs/model.md §3),
F_RN = N_N n_N (nut on roller), f_S = −μ_SR N_S v_s/√(|v_s|² + ε²) (regularised Coulomb) or
−c N_T v_s (viscous, the Jones limit), M_rr = −μ_NR N_N r_R sgn(spin rel. nut) (rolling
resistance moment), M_pin = −μ_pin |F_pin| r_pin sgn(ω_r), M_drag = −2 · 2πρνbR³ ω_C / h
(laminar Couette flow in each ring gear–carrier gap, nut fixed). The loaded flanks follow the
sign of the axial load (`contact`); normal forces are compressive.

Per-tooth normal forces are ζ_T,k N / N_T (Σ ζ_T,k = N_T): identical rollers share one
force direction per side, so the step cost does not grow with the tooth count.

Integration: u̇ = f(u) is stiff in ω_C (Coulomb friction with a small regularisation speed),
so each step uses the two-stage L-stable Rosenbrock method ROS2 (Verwer et al. 1999, γ =
1 + 1/√2) with a finite-difference Jacobian; angles advance by the trapezoidal rule and the
dissipated work by the trapezoidal rule on the dissipated power, both second order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple, cast

import numpy as np

from prsm_sim.errors import ParamError
from prsm_sim.models import drag, kernels
from prsm_sim.models.kernels import FlankConstants, Fu2018Constants, ScrewRollerLaw, kernel_memory, memory_from_kernel
from prsm_sim.params import Params
from prsm_sim.physics.contact import ContactPoint, contact_for
from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.physics.kinematics import ideal_carrier_ratio
from prsm_sim.stepping.model import Model
from prsm_sim.stepping.packed import PackedOutputs
from prsm_sim.stepping.records import InternalBlock, InternalLayout, State
from prsm_sim.stepping.trajectory import Trajectory, trajectory_from_columns

PER_ROLLER_QUANTITIES = (
    ("screw_normal_force_n", "N"),
    ("nut_normal_force_n", "N"),
    ("screw_friction_radial_n", "N"),
    ("screw_friction_tangential_n", "N"),
    ("screw_friction_axial_n", "N"),
    ("screw_slip_radial_m_s", "m/s"),
    ("screw_slip_tangential_m_s", "m/s"),
    ("screw_slip_axial_m_s", "m/s"),
    ("nut_rolling_moment_nm", "N·m"),
    ("gear_tangential_force_n", "N"),
    ("gear_radial_force_n", "N"),
    ("pin_radial_force_n", "N"),
    ("pin_tangential_force_n", "N"),
    ("pin_friction_moment_nm", "N·m"),
    ("nut_friction_radial_n", "N"),
    ("nut_friction_tangential_n", "N"),
    ("nut_friction_axial_n", "N"),
    ("nut_slip_speed_m_s", "m/s"),
    ("tilting_moment_nm", "N·m"),
    ("pin_1_radial_force_n", "N"),
    ("pin_1_tangential_force_n", "N"),
    ("pin_2_radial_force_n", "N"),
    ("pin_2_tangential_force_n", "N"),
)
PER_TOOTH_QUANTITIES = (("screw_normal_force_n", "N"), ("nut_normal_force_n", "N"))
CARRIER_QUANTITIES = (("carrier_drag_torque_nm", "N·m"), ("axial_force_n", "N"), ("load_sign", "1"))
GEAR_PRESSURE_ANGLE_RAD = math.radians(20.0)  # standard involute spur/ring gear
# Adaptive sub-steps (`kernels.step`): where the friction state changes within a step (a speed
# changes sign, the flank pair switches, or the screw–roller slip is within SLIP_ZONE
# regularisation speeds of zero, where the regularised Coulomb law is far from saturated and
# stiff) the step is checked by step doubling and halved, down to min(dt, HALVING_BASE_S) / 2**MAX_HALVINGS:
# the smallest sub-step is the same at every output step above 1 ms, so a step of 20-100 ms resolves a stick
# capture against a stiff stop as finely as a 1 ms step does (at dt/2**10 = 22-90 µs its books stayed open by
# 0.5 % of the energy through)
MAX_HALVINGS = 10
HALVING_BASE_S = 1e-3
MIN_REGULARISATION_M_S = 1e-5  # smallest ε fu2018 accepts (`Fu2018.check_params`)
ZONE_HALVINGS = 4  # slow slip alone refines to dt/16
SLIP_ZONE = 10.0
# the drag's hold (`drag_holds_nm`) is its running torque where every regularised Coulomb law is within
# 1/(2·HOLD_SATURATION²) = 5e-5 of its Coulomb value: slip, seal speed and carrier speed ≥ HOLD_SATURATION ε
HOLD_SATURATION = 100.0
SUBSTEP_TOL = 0.05  # step-doubling agreement in the transition zone, in regularisation speeds ε of slip
SUBSTEP_TOL_FLOOR_M_S = 1e-5  # ... but never tighter than this (≈ 0.01 rad/s of screw speed on s30): below a
# regularisation of 2e-4 m/s the layer is too thin and stiff to resolve, and the L-stable step's quasi-static
# answer is the one wanted
# a step whose own energy balance misses by more than this share of the energy it moved goes to error
# control, and its halves must close their books too. A twentieth of the energy guard's own share
# (ENERGY_GUARD_REL): the measure counts each joule up to four times (in, stored, dissipated, out), and a
# drive that takes back what it gave halves the net flow an actuator's ledger is judged by, so a run of a few
# steps of 20-100 ms (each accelerating or reversing the screw) is judged by their own residuals. At a quarter
# of the guard's share such runs missed 1.1e-3 … 2e-3 of that flow; at the guard's share, steps accepted
# under hard acceleration added up to a guard trip (and their carrier speed was off by a tenth)
STEP_BALANCE_TOL = 5e-5
STEP_BALANCE_FLOOR_J = 1e-7  # ... or by more than this (creep at a few ε moves little energy per step)


def load_distribution(params: Params) -> np.ndarray:
    """ζ_T,k over the N_T teeth, Σ ζ = N_T (docs/model.md §4.2).

    "uniform": ζ = 1. "exponential": ζ_k ∝ exp(−d k), decaying from the loaded end (tooth 0),
    the shape static load-distribution models give for same-side mounting (docs/model.md §4.3).
    """
    n_t = params.geometry.n_teeth
    fr = params.friction
    if fr.load_distribution == "uniform":
        return np.ones(n_t)
    w = np.exp(-fr.load_distribution_decay * np.arange(n_t))
    return w * (n_t / w.sum())


def load_centroid_m(params: Params) -> float:
    """Axial position of the thread load's resultant on the roller, from its middle (+z toward pin 1).

    Tooth k sits at z_k = ((N_T − 1)/2 − k) P: tooth 0, the loaded end of the exponential
    profile, is on the side of pin/gear j = 1.
    """
    geo = params.geometry
    zeta = load_distribution(params)
    z = ((geo.n_teeth - 1) / 2 - np.arange(geo.n_teeth)) * geo.pitch_m
    return float(np.sum(zeta * z) / geo.n_teeth)


@dataclass(frozen=True)
class _Side:
    """Contact geometry for one load sign, flattened to floats for the hot path."""

    sign: int
    screw: ContactPoint
    nut: ContactPoint
    G: np.ndarray  # screw–roller sliding: v_s = G u
    H: np.ndarray  # nut–roller sliding: v_n = H u (zero in the standard design, g = r_N/r_R)


def flank_constants(side: _Side, a: float) -> FlankConstants:
    """One flank pair's geometry as floats for the scalar step (`FlankConstants`)."""
    ns, nn = side.screw.normal_on_roller, side.nut.normal_on_roller
    ps, pn = side.screw.point_m, side.nut.point_m
    return FlankConstants(*(float(v) for v in (*side.G.ravel(), *ns, ps[0], ps[1], ps[0] - a, ps[1], *nn, pn[0] - a,
                                               pn[1], *side.H.ravel())))


class Fu2018Part(NamedTuple):
    """The memory of `fu2018` in `State.part`: what its friction laws take lagged by one step
    (docs/model.md §4.2) and the integrator's memory, kept in the state so that a step stays a pure
    function of (state, inputs)."""

    flank_sign: int = 1  # the loaded flank pair (+1: load resisting positive nut motion)
    pin_force_n: float = 0.0  # |F_pin,1| + |F_pin,2| of the last step, N
    gear_force_n: float = 0.0  # the gear's tangential force of the last step, N
    solver: tuple = ()  # the frozen Jacobian and its age (empty: none)


class Forces(NamedTuple):
    """Accelerations and internal forces of one evaluation, per roller where it applies.

    A tuple on purpose (cheap on the hot path); fields from `n_s` on are the compact
    per-step record in layout order: PER_ROLLER_QUANTITIES, then CARRIER_QUANTITIES.
    Forces are those the named body exerts on the roller; components in the carrier frame
    (radial x, tangential y, axial z) at the roller.
    """

    acc_s: float
    acc_c: float
    dissipated_w: float
    n_s: float
    n_n: float
    fx: float  # friction of the screw on the roller, carrier frame (radial, tangential, axial)
    fy: float
    fz: float
    vx: float  # sliding velocity of the roller relative to the screw
    vy: float
    vz: float
    m_rr: float
    f_gt: float
    f_gr: float
    f_pr: float
    f_pt: float
    m_pin: float
    fnx: float  # friction of the nut on the roller (zero unless the nut contact slides)
    fny: float
    fnz: float
    v_nut: float  # sliding speed of the roller relative to the nut at the contact
    m_tilt: float  # moment of the thread forces about the roller centre, about the tangential axis
    p1r: float  # pin j = 1 (at +z) and j = 2 reactions on the roller: radial, tangential
    p1t: float
    p2r: float
    p2t: float
    m_drag: float
    axial: float  # axial thread force on the nut, all rollers, along +x_nut
    sign: float

    @property
    def compact(self) -> tuple:
        return self[3:]

    @property
    def pin_force_sum_n(self) -> float:
        """|F_pin,1| + |F_pin,2|: what pin friction scales with (√(x² + y²) rather than `math.hypot`, whose
        rounding differs from the C library's: the compiled kernel takes the same square roots)."""
        return (math.sqrt(self.p1r * self.p1r + self.p1t * self.p1t)
                + math.sqrt(self.p2r * self.p2r + self.p2t * self.p2t))


def _torque_and_carrier(ref, k: tuple, sides: tuple, w: float, wc: float, sign: float, pin: float,
                        gear: float) -> tuple[float, float]:
    """(τ with the screw's acceleration zero, the carrier's acceleration then) at speeds (w, wc) and no load;
    NaNs where τ does not act. `kernels.solve` is affine in τ, so one pair of evaluations solves it exactly."""
    a0 = ref.solve(w, wc, 0.0, 0.0, sign, pin, gear, False, False, 0.0, 0.0, 0.0, 0.0, 0.0, k, sides)
    a1 = ref.solve(w, wc, 1.0, 0.0, sign, pin, gear, False, False, 0.0, 0.0, 0.0, 0.0, 0.0, k, sides)
    if not a1[0] != a0[0]:
        return math.nan, math.nan
    tau = -a0[0] / (a1[0] - a0[0])
    return tau, a0[1] + tau * (a1[1] - a0[1])


def _steady_carrier_speed(ref, k: tuple, sides: tuple, ratio: float, w: float, sign: float, pin: float,
                          gear: float) -> float:
    """The carrier speed of steady no-load running (its acceleration zero) at screw speed w: bracketed outward
    from the kinematic ratio, then Brent's method. Where the carrier's acceleration does not change sign (the
    contacts carry nothing, so nothing drives it and the screw's torque does not depend on it) the speed where
    it is smallest of those tried."""
    from scipy.optimize import brentq  # scipy-heavy: kept off `import prsm_sim`, taken when a screw has drag

    def accel(x: float) -> float:
        return _torque_and_carrier(ref, k, sides, w, x, sign, pin, gear)[1]

    x0 = ratio * w
    g0 = accel(x0)
    best = (abs(g0), x0) if math.isfinite(g0) else (math.inf, x0)
    step = 1e-3 * abs(x0)
    for _ in range(60):
        for x in (x0 - step, x0 + step):
            g = accel(x)
            if not math.isfinite(g):
                continue
            if math.isfinite(g0) and g * g0 <= 0.0:
                a, b = sorted((x0, x))
                return brentq(accel, a, b, xtol=1e-15 * abs(w), rtol=1e-14, maxiter=200)
            best = min(best, (abs(g), x))
        step *= 2.0
    return best[1]


def steady_no_load(k: Fu2018Constants, sides: tuple, ratio: float, w: float) -> tuple[float, float]:
    """(screw torque N·m, slip speed m/s) of steady running at no load at screw speed w (rad/s) with the step's
    constants `k` and flank constants `sides`: the carrier speed where both accelerations vanish
    (`_steady_carrier_speed`), the pin force sum and the flank and gear force signs iterated to the forces they
    give, from the ones a run in that direction takes (at no load either flank pair solves: the run's history
    picks it). NaN torque where no steady running solves."""
    ref = kernels.load("reference")
    kk = tuple(k)
    d = math.copysign(1.0, w)
    sign, pin, gear = d, 0.0, -d
    tau, slip = math.nan, 0.0
    for _ in range(20):  # the pin force sum and the signs settle in two or three rounds
        wc = _steady_carrier_speed(ref, kk, sides, ratio, w, sign, pin, gear)
        tau = _torque_and_carrier(ref, kk, sides, w, wc, sign, pin, gear)[0]
        if not math.isfinite(tau):
            break
        f = ref.solve_forces(w, wc, tau, 0.0, sign, pin, gear, kk, sides)
        slip = math.sqrt(f[8] ** 2 + f[9] ** 2 + f[10] ** 2)
        new_pin = ref._pin_sum(f)
        settled = f[28] == sign and (f[12] >= 0.0) == (gear > 0.0) and abs(new_pin - pin) <= 1e-12 * new_pin
        sign, pin, gear = f[28], new_pin, 1.0 if f[12] >= 0.0 else -1.0
        if settled:
            break
    return tau, slip


class Fu2018(Model):
    name = "fu2018"
    compiled_kernel = True
    has_carrier = True
    has_internal_forces = True
    has_friction_laws = True
    part_type = Fu2018Part

    @classmethod
    def check_params(cls, params: Params) -> None:
        fr = params.friction
        if fr.contact_evaluation != "exact":
            # docs/model.md §3: the offset normal with a line-of-centres point has a sliding component
            # along the normal, so the normal force does work (a heavy-load run showed 62 W in, 1592 W out)
            raise ParamError(f"friction.contact_evaluation = {fr.contact_evaluation!r}: model fu2018 needs 'exact' "
                             "(a line-of-centres point with the contact normal lets the normal force do work; "
                             "line_of_centres is for jones2016)")

        if params.geometry.gear_ratio == 1.0:
            raise ParamError("geometry.gear_ratio = 1.0: model fu2018 needs g ≠ 1 (at g = 1 the roller does not spin "
                             "and its gear, of pitch radius a/(g − 1), cannot mesh with the ring)")
        if fr.screw_roller_law == "coulomb" and fr.coulomb_regularisation_m_s < MIN_REGULARISATION_M_S:
            # below this the regularised layer is ~1e-7 s thick: near the stick band's edge the error-controlled
            # sub-steps cost up to 100× a plain step (1e-6 m/s: ~10 s per simulated second) for no gain in
            # the figures a controller sees; 1e-5 closes the energy balance to 1e-6 of the energy that flowed
            raise ParamError(f"friction.coulomb_regularisation_m_s = {fr.coulomb_regularisation_m_s!r}: model fu2018 "
                             f"needs at least {MIN_REGULARISATION_M_S:g} m/s (stick is modelled exactly at rest; "
                             "the regularisation only shapes slip through zero)")

    def __init__(self, params: Params, dt_s: float, kernel: str = "compiled") -> None:
        """
        Parameters
        ----------
        params : Params
            Validated parameters (`check_params` refuses what this model cannot honour).
        dt_s : float
            Fixed output step, s.
        kernel : {"compiled", "reference"}
            The step's source, `models.kernels`, run as numba code ("compiled") or by the Python
            interpreter ("reference").
        """
        self._kn = kernels.load(kernel)
        self.kernel = kernel
        self.check_params(params)
        super().__init__(params, dt_s)
        geo = self.geo
        self.sides = {s: self._side(s) for s in (1, -1)}
        self.zeta = load_distribution(params)
        self.p = geo.lead_per_rad_m
        self.a = geo.carrier_radius_m
        fr = params.friction
        self.k_drag = 2 * 2 * math.pi * fr.lubricant_density_kg_m3 * fr.lubricant_viscosity_m2_s \
            * fr.drag_width_m * fr.drag_radius(geo)**3 / fr.drag_gap_m
        self.eps_v = fr.coulomb_regularisation_m_s
        self.screw_roller_law = ScrewRollerLaw.from_name(fr.screw_roller_law)
        self._expand_index, self._expand_scale = self._expansion()
        self._side_k = {sg: flank_constants(side, self.a) for sg, side in self.sides.items()}
        M = mass_matrix(params)
        self.kinetic = (float(M[0, 0]), float(M[0, 1]), float(M[1, 1]))  # energy guard
        nr, nt = geo.n_rollers, geo.n_teeth
        self.layout = InternalLayout(blocks=(
            InternalBlock("per_roller", ("roller", "quantity"), (nr, len(PER_ROLLER_QUANTITIES)), PER_ROLLER_QUANTITIES),
            InternalBlock("per_tooth", ("roller", "tooth", "quantity"), (nr, nt, 2), PER_TOOTH_QUANTITIES),
            InternalBlock("carrier", ("quantity",), (len(CARRIER_QUANTITIES),), CARRIER_QUANTITIES),
        ))
        constants = self._step_constants()
        forward, backward = self.drag_holds_nm(constants)
        self.constants = constants._replace(hold_forward=forward, hold_backward=backward)
        # the step's constants (`kernels.Fu2018Constants`, `kernels.FlankConstants` per flank pair): float arrays
        # for numba, tuples of Python floats for the interpreter (numpy scalars would slow every operation)
        k_arr: tuple | np.ndarray = tuple(self.constants)
        s_arr: tuple | np.ndarray = (self._side_k[1], self._side_k[-1])
        if kernel == "compiled":
            k_arr, s_arr = np.array(k_arr, dtype=float), np.array(s_arr, dtype=float)
        # (K, S) as the kernels take them: the contract a model built on this core (`elastic`) passes on
        self.kernel_constants = (k_arr, s_arr)
        # the per-step path's kernel (`kernels.step_record`: the step and its record) at the specialisation a
        # warm-up step at rest chose, entered without the dispatch; numba compiles (a fresh install) or loads its
        # disk cache in that step, when the model is built, rather than in the first step of a realtime loop
        rest = (0.0,) * 11 + (1.0, 0.0, 0.0, kernels.NO_MEMORY, 0.0, 0.0, *self.kernel_constants)
        if kernel == "compiled":
            self._kn.step_record(*rest)
        self._record_kernel = kernels.specialised(self._kn.step_record, *rest)

    def _step_constants(self) -> Fu2018Constants:
        """The step's constants (`kernels.Fu2018Constants`) from the parameters."""
        geo, fr, m, a, p = self.geo, self.params.friction, self.params.resolved_mass, self.a, self.p
        nr = geo.n_rollers
        k_mig = geo.pitch_m * (geo.starts - geo.gear_ratio) / (2 * math.pi)
        # pitch radius of the roller's gear: its mesh with the fixed ring rolls, a ω_C + (1 − g) ω_C r_g = 0, so
        # r_g = a/(g − 1) (= r_R in the standard design g = r_N/r_R); the gear force's lever about the roller axis
        r_gear = a / (geo.gear_ratio - 1.0)
        mr_a = m.roller_mass_kg * a
        # the nut contact slides only off the standard design (g ≠ r_N/r_R: roller migration)
        nut_slides = max(float(np.abs(side.H).max()) for side in self.sides.values()) > 1e-12 * a
        eps_w = self.eps_v / geo.roller_radius_m  # the regularisation as an angular speed at the rolling radius
        return Fu2018Constants(
            screw_roller_law=float(self.screw_roller_law), mu=fr.mu_screw_roller,
            mu_n=fr.mu_nut_roller_sliding if nut_slides else 0.0, eps_v2=self.eps_v**2, eps_w2=eps_w**2,
            c_nt=fr.viscous_n_s_m * geo.n_teeth, mu_pin_r=drag.pin_friction_coefficient(self.params) * geo.pin_radius_m,
            k_drag=self.k_drag,
            mu_rr_r=fr.mu_nut_roller_rolling * geo.roller_radius_m, nr=float(nr), a=a, r_g=r_gear,
            mp=m.moved_mass_kg * p, i_s=m.screw_inertia_kgm2, i_c=m.carrier_inertia_kgm2, mr_p=m.roller_mass_kg * p,
            mr_kmig=m.roller_mass_kg * k_mig, mr_a=mr_a,
            # I_R (1 − g) − r_R m_R a − r_R I_C / (N_R a): the carrier-mode inertia of the spin equation
            j_spin=(m.roller_inertia_kgm2 * (1.0 - geo.gear_ratio) - r_gear * mr_a
                    - r_gear * m.carrier_inertia_kgm2 / (nr * a)),
            tan_gear=math.tan(GEAR_PRESSURE_ANGLE_RAD), g=geo.gear_ratio,
            # sign of the roller's spin relative to the nut, (1 − g) ω_C, per sign of ω_C (g > 0, any side of 1)
            s_1g=0.0 if geo.gear_ratio == 1.0 else math.copysign(1.0, 1.0 - geo.gear_ratio),
            span=geo.roller_length_m,  # pins/gears j = 1, 2 at the two ends of the threaded length (assumed span)
            zbar=load_centroid_m(self.params), nut_slides=float(nut_slides), h=self.dt_s,
            h_min=min(self.dt_s, HALVING_BASE_S) / 2**MAX_HALVINGS, h_zone=self.dt_s / 2**ZONE_HALVINGS,
            slip_tol=max(SUBSTEP_TOL * self.eps_v, SUBSTEP_TOL_FLOOR_M_S), eps_v=self.eps_v, kss=self.kinetic[0],
            ksc=self.kinetic[1], kcc=self.kinetic[2], jacobian_refresh=float(JACOBIAN_REFRESH_STEPS),
            slip_zone=SLIP_ZONE, balance_tol=STEP_BALANCE_TOL, balance_floor=STEP_BALANCE_FLOOR_J, p=p,
            drag_on=float(self.params.drag.enabled), seal_torque=drag.seal_torque_nm(self.params),
            eps_ws=self.eps_v / geo.screw_radius_m, film_nt=drag.film_traction_n_s_per_m(self.params) * geo.n_teeth,
            idle_axial=2.0 * drag.idle_flank_force_n(self.params) / nr, hold_forward=0.0,
            hold_backward=0.0)

    def drag_holds_nm(self, k: Fu2018Constants) -> tuple[float, float]:
        """The screw torques the load-independent drag holds at rest (`kernels._drag_holds`), forward and
        backward (magnitudes), N·m: the screw torque of steady running at no load as the speed goes to 0⁺ in each
        direction (`steady_no_load`), i.e. with every regularised Coulomb law saturated (`HOLD_SATURATION`) and
        the viscous terms, which vanish at rest, left out (the film, the carrier's Couette drag, a viscous
        screw–roller law). The seals, the idle flanks and the pin and rolling friction their forces drive are
        all Coulomb friction, which holds at rest up to its sliding value; without this hold only the seals
        held, and a screw whose no-load torque is mostly its idle flanks' crept, in the regularised laws' band,
        under a third of the torque it runs with (`s30`: 0.090 of 0.263 N·m). Each direction has its own (equal
        on the presets: the mechanism is its own mirror image there). Zero with the drag off or all its
        magnitudes zero (the papers' screw).
        """
        if not self.params.drag.enabled or (k.seal_torque == 0.0 and k.idle_axial == 0.0):
            return 0.0, 0.0
        kk = k._replace(film_nt=0.0, k_drag=0.0, c_nt=0.0)
        sides = (self._side_k[1], self._side_k[-1])
        ratio = ideal_carrier_ratio(self.geo)
        held = []
        for direction in (1.0, -1.0):
            w = HOLD_SATURATION * max(k.eps_ws, math.sqrt(k.eps_w2) / ratio)
            tau, slip = steady_no_load(kk, sides, ratio, direction * w)
            # the idle flanks press the contacts: raise the speed until their slip is saturated too (without them
            # the contacts carry nothing at no load, whatever their slip)
            for _ in range(8):
                if k.idle_axial == 0.0 or slip >= HOLD_SATURATION * k.eps_v:
                    break
                w *= 2.0 * HOLD_SATURATION * k.eps_v / max(slip, 1e-2 * HOLD_SATURATION * k.eps_v)
                tau, slip = steady_no_load(kk, sides, ratio, direction * w)
            # no steady no-load running found (a design whose force system does not solve there): the seals hold
            # what they exactly do, the rest of the drag creeps as the regularised laws let it
            held.append(abs(tau) if math.isfinite(tau) else k.seal_torque)
        return held[0], held[1]

    def initial_state(self, nut_position_m: float = 0.0, load_n: float = 0.0) -> State:
        """At rest; under a nut load the friction state (flank pair, pin forces, gear force) is the static
        one that load and its frictionless holding torque (L/2π) F set (`stick_forces`)."""
        s = super().initial_state(nut_position_m)
        if load_n == 0.0:
            return s
        st, _ = self.stick_forces(self.geo.lead_per_rad_m * load_n, load_n, 1 if load_n >= 0.0 else -1, 0.0)
        if st is None:
            return s
        part = cast(Fu2018Part, s.part)  # `Model.initial_state` made it of this model's part_type
        return replace(s, part=part._replace(flank_sign=int(st.sign), pin_force_n=st.pin_force_sum_n,
                                             gear_force_n=st.f_gt))

    def _side(self, sign: int) -> _Side:
        ev = self.params.friction.contact_evaluation
        s = contact_for(self.geo, "screw", ev, sign)
        n = contact_for(self.geo, "nut", ev, sign)
        return _Side(sign=sign, screw=s, nut=n, G=s.sliding_matrix(self.geo), H=n.sliding_matrix(self.geo))

    # -- the force system and the step: `models.kernels`, the one source (compiled or uncompiled) -------------
    def solve_forces(self, u, torque_nm: float, load_n: float, sign: int = 1, pin_abs: float = 0.0,
                     gear_sign: float = 1.0) -> Forces:
        """The force system: equations 1–7 (module doc) solved for accelerations and internal forces
        (`kernels.solve_forces`).

        Contract (what a model built on this force system may rely on):

        - inputs: speeds u = (ω_S, ω_C) in rad/s, screw torque τ (N·m), nut load F (N, resisting
          positive nut motion), and the friction state: `sign` (±1, the flank pair tried first:
          the one of the last step), `pin_abs` = |F_pin,1| + |F_pin,2| of the last step (N,
          scales pin friction) and `gear_sign` (±1, sign of the last tangential gear force).
        - geometry and friction laws come from the parameters the model was built with; nothing
          else is read, nothing is stored: a pure function.
        - output: `Forces`, per roller: accelerations (rad/s²), normal and friction forces (N),
          sliding velocities (m/s), the pin end reactions j = 1, 2 and the thread tilting moment,
          the power dissipated (W, all rollers) and the flank pair that carried the load.
          The flank pair is the one that carries the load compressively: tried with `sign` and
          switched if a normal force comes out negative. Lagged |F_pin| and gear sign keep the
          system linear in the accelerations; they only scale the small pin-friction term and
          the gear's radial part, and the dissipation is computed with the same values, so the
          energy balance holds exactly in them.
        """
        return Forces(*self._kn.solve_forces(float(u[0]), float(u[1]), float(torque_nm), float(load_n), float(sign),
                                             float(pin_abs), float(gear_sign), *self.kernel_constants))

    def stick_forces(self, torque_nm: float, load_n: float, sign: int = 1, pin_abs: float = 0.0,
                     gear_sign: float = 1.0) -> tuple[Forces | None, float]:
        """The static state at rest (u = 0) with set-valued Coulomb friction (as `ideal` treats its loss;
        `kernels.stick_forces`).

        At rest with zero accelerations, equations 1–7 are linear in the screw normal force N_S and
        the screw–roller friction force q = N_S t (in the plane of the sliding directions, q = G c)
        once the share σ ∈ [−1, 1] of the pin and rolling-resistance moments (which act together
        against ω_C) is fixed: screw torque (1), roller axial (3) and roller spin (6) are three
        equations in (N_S, c₀, c₁), with N_N = F / (N_R n_N,z) from the nut (2). The solution is
        affine in σ, so |q|² − (μ N_S)² is a quadratic in σ: the mechanism sticks iff its minimum
        over [−1, 1] is ≤ 0 (closed form, no iteration). Returns (forces, r) with r = |q| / (μ N_S)
        at that σ (≤ 1: sticks), forces None when no compressive solution exists. The nut contact
        is taken as not slipping at rest (statically indeterminate against the screw side). The pin
        friction capacity scales with the pin forces the static state itself sets (solved twice when
        they differ by more than 1 %).
        """
        ok, f, r = self._kn.stick_forces(float(torque_nm), float(load_n), float(sign), float(pin_abs),
                                         float(gear_sign), *self.kernel_constants)
        return (Forces(*f) if ok else None), r

    def _make_step(self):
        """The step: `kernels.step_record`, the kernel's step and the ledger's record in one compiled call. The
        record keeps the end forces as its aux, from which the slip speed and the internal vector (`expand_one`)
        are derived when read, and their axial thread force as the nut force. The aux is the kernel's plain tuple,
        read by `Forces`' field order (`slip_speed`, `expand_one`): building a `Forces` would cost a tenth of the
        step. The packed state holds this model's part as the kernel takes and returns it (`packed_part`), so a
        step converts nothing: the floats come from the kernel's previous step or from `pack_state`, the inputs
        from the caller's checks (`Simulator.step`, `Model.step`).
        """
        expand_one, kernel_record = self.expand_one, self._record_kernel
        k_arr, s_arr = self.kernel_constants
        k = self.packed_constants(lambda w_s, w_c, f1: slip_speed(f1), lambda w_s, w_c, f1: expand_one(f1))

        def step_packed(x, torque_nm: float, load_n: float):
            sign, pin_abs, gear, mem = x[11]
            items, f1 = kernel_record(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], x[10], sign, pin_abs,
                                      gear, mem, torque_nm, load_n, k_arr, s_arr)
            return PackedOutputs(items + (k, f1))
        return step_packed

    def packed_part(self, part: Fu2018Part) -> tuple:
        """The part as `kernels.step` takes it: (flank sign, pin force sum, gear force) as floats and the solver
        memory as 6 floats (`kernels.kernel_memory`)."""
        return (float(part.flank_sign), float(part.pin_force_n), float(part.gear_force_n), kernel_memory(part.solver))

    def state_part(self, packed: tuple) -> tuple:
        """`packed_part` undone: the flank sign an int, no solver memory ``()`` (`kernels.memory_from_kernel`); a
        part in `State`'s form (plain data) passes as it is."""
        sign, pin_abs, gear, mem = packed
        return (int(sign), pin_abs, gear, memory_from_kernel(mem) if len(mem) == 6 else mem)

    def _run_impl(self, state: State, torque_nm: np.ndarray, load_n: np.ndarray) -> Trajectory:
        """The batch form of the step: one call of `kernels.fu2018_run`, the per-tooth expansion built when
        first read."""
        s, n = state, len(torque_nm)
        ws, wc, th_s, th_c = s.screw_speed_rad_s, s.carrier_speed_rad_s, s.screw_angle_rad, s.carrier_angle_rad
        sign, pin_abs, gear, mem = self.pack_state(s)[11]
        cols = np.empty((n, 8))
        compact = np.empty((n, self._compact_size))
        ws, wc, th_s, th_c, sign, pin_abs, gear, mem = self._kn.fu2018_run(
            float(ws), float(wc), float(th_s), float(th_c), float(sign), float(pin_abs), float(gear),
            kernel_memory(mem), torque_nm, load_n, *self.kernel_constants, cols, compact)
        sign, mem = int(sign), memory_from_kernel(mem)
        final = State(screw_angle_rad=th_s, screw_speed_rad_s=ws, carrier_angle_rad=th_c, carrier_speed_rad_s=wc,
                      part=Fu2018Part(sign, pin_abs, gear, mem))
        p = self.p
        w_s, w_c, dtheta = cols[:, 0], cols[:, 1], cols[:, 4]
        return trajectory_from_columns(
            state, final, self.total_stored_energy_j(state), dt_s=self.dt_s, gear_ratio=self.geo.gear_ratio,
            layout=self.layout, internal=lambda: self.expand(compact), torque_nm=torque_nm, load_n=load_n,
            th_s=cols[:, 2], w_s=w_s, th_c=cols[:, 3], w_c=w_c, dtheta=dtheta, nut_x=p * cols[:, 2], nut_v=p * w_s,
            nut_force=cols[:, 7], slip=cols[:, 6], work_out_j=load_n * p * dtheta, dissipated_j=cols[:, 5],
            stored_j=self.stored_energy_j(w_s, w_c))

    _compact_size = len(PER_ROLLER_QUANTITIES) + len(CARRIER_QUANTITIES)

    def expand_one(self, forces: tuple) -> np.ndarray:
        """`expand` for one step's end forces (a `Forces`, or the kernel's 29 floats in its order): each element of
        the layout is one force times its scale, 1 or ζ_T,k/N_T (`_expansion`), so the node's path builds the
        vector in one gather and one product, with the products `expand` forms."""
        out = np.array(forces).take(self._expand_index)
        return np.multiply(out, self._expand_scale, out=out)

    def _expansion(self) -> tuple[np.ndarray, np.ndarray]:
        """(position in `Forces` of each element of the layout, its scale): per roller the compact row as it is
        (scale 1); per tooth and flank side ζ_T,k/N_T times the roller's screw (side 0) or nut (side 1) normal
        force; the carrier's quantities as they are."""
        geo = self.geo
        nr, nt, nq = geo.n_rollers, geo.n_teeth, len(PER_ROLLER_QUANTITIES)
        first = len(Forces._fields) - self._compact_size  # `Forces.compact` starts here
        share = self.zeta / nt
        per_roller = np.tile(np.arange(nq), nr)
        per_tooth = np.tile(np.tile(np.arange(2), nt), nr)  # (tooth, side) rows: N_S, N_N
        carrier = np.arange(nq, self._compact_size)
        index = first + np.concatenate([per_roller, per_tooth, carrier])
        scale = np.concatenate([np.ones(nr * nq), np.tile(np.repeat(share, 2), nr), np.ones(len(carrier))])
        return index, scale

    def expand(self, compact: np.ndarray) -> np.ndarray:
        """Compact rows (steps × 26) → the full labelled internal vectors (steps × layout.size).

        Per roller: identical rollers repeat the row. Per tooth: ζ_T,k / N_T times the roller's
        normal forces (docs/model.md §4.2) — the only part that grows with the tooth count.
        """
        geo = self.geo
        steps = compact.shape[0]
        nr, nt, nq = geo.n_rollers, geo.n_teeth, len(PER_ROLLER_QUANTITIES)
        out = np.empty((steps, self.layout.size))
        # written in place, one copy per block: this is the only part that grows with the tooth count
        out[:, :nr * nq].reshape(steps, nr, nq)[:] = compact[:, None, :nq]
        start = nr * nq
        teeth = out[:, start:start + nr * nt * 2].reshape(steps, nr, nt, 2)
        np.multiply((self.zeta / nt)[None, None, :, None], compact[:, None, None, :2], out=teeth)
        out[:, start + nr * nt * 2:] = compact[:, nq:]
        return out


_VX, _VY, _VZ = (Forces._fields.index(name) for name in ("vx", "vy", "vz"))


def slip_speed(f: tuple) -> float:
    """|v_s|, m/s: the screw–roller sliding speed of an evaluation (the `slip_speed_m_s` output); `f` a `Forces` or
    the kernel's 29 floats in its order."""
    return math.sqrt(f[_VX] ** 2 + f[_VY] ** 2 + f[_VZ] ** 2)


JACOBIAN_REFRESH_STEPS = 2  # 10 lost stability in the stiff carrier mode at μ = 0.1 under 20 kN
