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
from typing import NamedTuple

import numpy as np

from prsm_sim.errors import ParamError
from prsm_sim.models import kernels
from prsm_sim.models.kernels import FlankConstants, Fu2018Constants, kernel_memory, memory_from_kernel
from prsm_sim.params import Params
from prsm_sim.physics.contact import ContactPoint, contact_for
from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.stepping.model import Model
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
# Adaptive sub-steps (`Fu2018._step`): where the friction state changes within a step (a speed
# changes sign, the flank pair switches, or the screw–roller slip is within SLIP_ZONE
# regularisation speeds of zero, where the regularised Coulomb law is far from saturated and
# stiff) the step is checked by step doubling and halved, down to dt / 2**MAX_HALVINGS.
MAX_HALVINGS = 10
MIN_REGULARISATION_M_S = 1e-5  # smallest ε fu2018 accepts (`Fu2018.check_params`)
ZONE_HALVINGS = 4  # slow slip alone refines to dt/16
SLIP_ZONE = 10.0
SUBSTEP_TOL = 0.05  # step-doubling agreement in the transition zone, in regularisation speeds ε of slip
SUBSTEP_TOL_FLOOR_M_S = 1e-5  # ... but never tighter than this (≈ 0.01 rad/s of screw speed on s30): below a
# regularisation of 2e-4 m/s the layer is too thin and stiff to resolve, and the L-stable step's quasi-static
# answer is the one wanted
# a step whose own energy balance misses by more than this share of the energy it moved goes to error
# control, and its halves must close their books too. A quarter of the energy guard's own share
# (ENERGY_GUARD_REL): at the guard's share, steps the model accepted under hard acceleration added up to a
# guard trip (and their carrier speed was off by a tenth)
STEP_BALANCE_TOL = 2.5e-4
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
            "compiled": the step and the batch loop run as numba code (`models.kernels`, the same
            arithmetic); "reference": the pure-Python methods of this class, its specification.
        """
        self._kn = kernels.load(kernel)
        self.kernel = kernel
        self.check_params(params)
        super().__init__(params, dt_s)
        geo, fr, m = self.geo, params.friction, params.mass
        self.sides = {s: self._side(s) for s in (1, -1)}
        self.zeta = load_distribution(params)
        self.p = geo.lead_per_rad_m
        self.a = geo.carrier_radius_m
        self.k_mig = geo.pitch_m * (geo.starts - geo.gear_ratio) / (2 * math.pi)
        self.k_drag = 2 * 2 * math.pi * fr.lubricant_density_kg_m3 * fr.lubricant_viscosity_m2_s \
            * fr.drag_width_m * fr.drag_radius_m**3 / fr.drag_gap_m
        self.eps_v = fr.coulomb_regularisation_m_s
        # the same regularisation, as an angular speed at the roller's rolling radius
        self.eps_w = fr.coulomb_regularisation_m_s / geo.roller_radius_m
        nr, nt = geo.n_rollers, geo.n_teeth
        self._coulomb = fr.screw_roller_law == "coulomb"
        self._c_nt = fr.viscous_n_s_m * nt
        self._nr, self._r_r, self._g = nr, geo.roller_radius_m, geo.gear_ratio
        # pitch radius of the roller's gear: its mesh with the fixed ring rolls, a ω_C + (1 − g) ω_C r_g = 0, so
        # r_g = a/(g − 1) (= r_R in the standard design g = r_N/r_R); the gear force's lever about the roller axis
        self._r_gear = self.a / (geo.gear_ratio - 1.0)
        self._mp = m.moved_mass_kg * self.p
        self._i_s, self._i_c = m.screw_inertia_kgm2, m.carrier_inertia_kgm2
        self._mr_p = m.roller_mass_kg * self.p
        self._mr_kmig = m.roller_mass_kg * self.k_mig
        self._mr_a = m.roller_mass_kg * self.a
        self._mu_pin_r = fr.mu_pin * geo.pin_radius_m
        self._mu_rr_r = fr.mu_nut_roller_rolling * geo.roller_radius_m
        self._tan_gear = math.tan(GEAR_PRESSURE_ANGLE_RAD)
        # I_R (1 − g) − r_R m_R a − r_R I_C / (N_R a): the carrier-mode inertia of the spin equation
        self._j_spin = (m.roller_inertia_kgm2 * (1.0 - geo.gear_ratio) - self._r_gear * self._mr_a
                        - self._r_gear * m.carrier_inertia_kgm2 / (nr * self.a))
        self._zeta_share = self.zeta / nt
        self._gather = self._gather_index()
        self._side_k = {sg: flank_constants(side, self.a) for sg, side in self.sides.items()}
        # the nut contact slides only off the standard design (g ≠ r_N/r_R: roller migration)
        nut_slides = max(float(np.abs(side.H).max()) for side in self.sides.values()) > 1e-12 * self.a
        mu_nut = fr.mu_nut_roller_sliding if nut_slides else 0.0
        # sign of the roller's spin relative to the nut, (1 − g) ω_C, per sign of ω_C (g > 0, any side of 1)
        s_1g = 0.0 if geo.gear_ratio == 1.0 else math.copysign(1.0, 1.0 - geo.gear_ratio)
        # pins/gears j = 1, 2 at the two ends of the threaded length (assumed span)
        self._span = geo.roller_length_m
        self._zbar = load_centroid_m(params)
        M = mass_matrix(params)
        self.kinetic = (float(M[0, 0]), float(M[0, 1]), float(M[1, 1]))  # energy guard
        self._h_min = self.dt_s / 2**MAX_HALVINGS
        self._h_zone = self.dt_s / 2**ZONE_HALVINGS
        self._slip_tol = max(SUBSTEP_TOL * self.eps_v, SUBSTEP_TOL_FLOOR_M_S)
        self.layout = InternalLayout(blocks=(
            InternalBlock("per_roller", ("roller", "quantity"), (nr, len(PER_ROLLER_QUANTITIES)), PER_ROLLER_QUANTITIES),
            InternalBlock("per_tooth", ("roller", "tooth", "quantity"), (nr, nt, 2), PER_TOOTH_QUANTITIES),
            InternalBlock("carrier", ("quantity",), (len(CARRIER_QUANTITIES),), CARRIER_QUANTITIES),
        ))
        self.constants = Fu2018Constants(
            coulomb=float(self._coulomb), mu=fr.mu_screw_roller, mu_n=mu_nut, eps_v2=self.eps_v**2,
            eps_w2=self.eps_w**2, c_nt=self._c_nt, mu_pin_r=self._mu_pin_r, k_drag=self.k_drag, mu_rr_r=self._mu_rr_r,
            nr=float(nr), a=self.a, r_g=self._r_gear, mp=self._mp, i_s=self._i_s, i_c=self._i_c, mr_p=self._mr_p,
            mr_kmig=self._mr_kmig, mr_a=self._mr_a, j_spin=self._j_spin, tan_gear=self._tan_gear, g=self._g,
            s_1g=s_1g, span=self._span, zbar=self._zbar, nut_slides=float(nut_slides), h=self.dt_s,
            h_min=self._h_min, h_zone=self._h_zone, slip_tol=self._slip_tol, eps_v=self.eps_v, kss=self.kinetic[0],
            ksc=self.kinetic[1], kcc=self.kinetic[2], jacobian_refresh=float(JACOBIAN_REFRESH_STEPS),
            slip_zone=SLIP_ZONE, balance_tol=STEP_BALANCE_TOL, balance_floor=STEP_BALANCE_FLOOR_J, p=self.p)
        # the compiled kernel's constants (`kernels.Fu2018Constants`, `kernels.FlankConstants` per flank pair)
        self._kernel_k = np.array(self.constants, dtype=float)
        self._kernel_s = np.array([self._side_k[1], self._side_k[-1]], dtype=float)
        if self._kn is not None:
            # one step at rest with no inputs: numba compiles (a fresh install) or loads its disk cache here, when
            # the model is built, rather than in the first step of a realtime loop
            self._kn.step(0.0, 0.0, 1.0, 0.0, 0.0, kernels.NO_MEMORY, 0.0, 0.0, self._kernel_k, self._kernel_s)

    def initial_state(self, nut_position_m: float = 0.0, load_n: float = 0.0) -> State:
        """At rest; under a nut load the friction state (flank pair, pin forces, gear force) is the static
        one that load and its frictionless holding torque (L/2π) F set (`stick_forces`)."""
        s = super().initial_state(nut_position_m)
        if load_n == 0.0:
            return s
        st, _ = self.stick_forces(self.geo.lead_per_rad_m * load_n, load_n, 1 if load_n >= 0.0 else -1, 0.0)
        if st is None:
            return s
        return replace(s, part=s.part._replace(flank_sign=int(st.sign), pin_force_n=st.pin_force_sum_n,
                                                gear_force_n=st.f_gt))

    def _side(self, sign: int) -> _Side:
        ev = self.params.friction.contact_evaluation
        s = contact_for(self.geo, "screw", ev, sign)
        n = contact_for(self.geo, "nut", ev, sign)
        return _Side(sign=sign, screw=s, nut=n, G=s.sliding_matrix(self.geo), H=n.sliding_matrix(self.geo))

    # -- the force system ---------------------------------------------------------------
    def solve_forces(self, u, torque_nm: float, load_n: float, sign: int = 1, pin_abs: float = 0.0,
                     gear_sign: float = 1.0, stick: tuple[float, float, float, float] | None = None) -> Forces:
        """The force system: equations 1–7 (module doc) solved for accelerations and internal forces.

        Contract (what a model built on this force system may rely on):

        - inputs: speeds u = (ω_S, ω_C) in rad/s, screw torque τ (N·m), nut load F (N, resisting
          positive nut motion), and the friction state: `sign` (±1, the flank pair tried first:
          the one of the last step), `pin_abs` = |F_pin,1| + |F_pin,2| of the last step (N,
          scales pin friction) and `gear_sign` (±1, sign of the last tangential gear force);
          `stick`: None while sliding, or at rest (u = 0) the static friction of the screw on
          the roller per unit screw normal force (3-vector, carrier frame), the share σ of
          the pin and rolling moments and the screw normal force N_S, as `stick_forces` solves
          them (the accelerations are then zero).
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
        f = self._solve(u, torque_nm, load_n, sign, pin_abs, gear_sign, True, stick)
        if f[3] < 0.0 or f[4] < 0.0:  # a normal force in tension: the other flank pair carries the load
            g = self._solve(u, torque_nm, load_n, -sign, pin_abs, gear_sign, True, stick)
            if g[3] >= 0.0 and g[4] >= 0.0:
                f = g
        return f

    def _solve(self, u, tau, load, sign, pin_abs, gear_sign, forces: bool = True, stick=None):
        """Equations 1–7 eliminated by hand to a 2×2 system in (ω̇_S, ω̇_C).

        Scalar arithmetic on purpose: this runs several times per step and numpy's per-call
        overhead on 3-vectors would dominate. Nut (2) and screw (1) give N_N and N_S linearly
        in ω̇_S; the carriers (7) give F_pt, the roller tangential balance (5) F_gt; roller
        axial (3) and spin (6) are then two equations in the two accelerations; the radial
        balance (4) gives F_pr, the tilting balance the two pin reactions. Returns the
        accelerations only unless `forces`.
        """
        c, sd = self.constants, self._side_k[sign]
        g00, g01, g10, g11, g20, g21 = sd.g00, sd.g01, sd.g10, sd.g11, sd.g20, sd.g21
        nsx, nsy, nsz, psx, psy, rsx, rsy = sd.nsx, sd.nsy, sd.nsz, sd.psx, sd.psy, sd.rsx, sd.rsy
        nnx, nny, nnz, rnx, rny = sd.nnx, sd.nny, sd.nnz, sd.rnx, sd.rny
        h00, h01, h10, h11, h20, h21 = sd.h00, sd.h01, sd.h10, sd.h11, sd.h20, sd.h21
        coulomb, mu, mu_n, eps_v2, eps_w2, c_nt = c.coulomb, c.mu, c.mu_n, c.eps_v2, c.eps_w2, c.c_nt
        mu_pin_r, k_drag, mu_rr_r, nr, a, r_g = c.mu_pin_r, c.k_drag, c.mu_rr_r, c.nr, c.a, c.r_g
        mp, i_s, i_c, mr_p, mr_kmig, mr_a = c.mp, c.i_s, c.i_c, c.mr_p, c.mr_kmig, c.mr_a
        j_spin, tan_gear, g, s_1g, span, zbar, nut_slides = c.j_spin, c.tan_gear, c.g, c.s_1g, c.span, c.zbar, c.nut_slides
        w_s, w_c = u
        vx = g00 * w_s + g01 * w_c
        vy = g10 * w_s + g11 * w_c
        vz = g20 * w_s + g21 * w_c
        f0x = f0y = f0z = 0.0
        if stick is not None:  # static friction per unit N_S, solved by `stick_forces`
            esx, esy, esz = nsx + stick[0], nsy + stick[1], nsz + stick[2]
        elif coulomb:
            k = mu / math.sqrt(vx * vx + vy * vy + vz * vz + eps_v2)
            esx, esy, esz = nsx - k * vx, nsy - k * vy, nsz - k * vz
        else:
            esx, esy, esz = nsx, nsy, nsz
            f0x, f0y, f0z = -c_nt * vx, -c_nt * vy, -c_nt * vz
        # nut–roller sliding (roller migration, g ≠ r_N/r_R): regularised Coulomb as on the screw side
        if nut_slides:
            wx = h00 * w_s + h01 * w_c
            wy = h10 * w_s + h11 * w_c
            wz = h20 * w_s + h21 * w_c
        else:  # standard design: the nut contact rolls
            wx = wy = wz = 0.0
        if mu_n != 0.0 and stick is None:
            kn = mu_n / math.sqrt(wx * wx + wy * wy + wz * wz + eps_v2)
            enx, eny, enz = nnx - kn * wx, nny - kn * wy, nnz - kn * wz
        else:
            enx, eny, enz = nnx, nny, nnz
        spin_n = rnx * eny - rny * enx
        mom_s = psx * esy - psy * esx
        mom_f0 = psx * f0y - psy * f0x
        spin_s = rsx * esy - rsy * esx
        spin_f0 = rsx * f0y - rsy * f0x
        # regularised sgn(ω_C); at rest the static share σ ∈ [−1, 1] of the pin and rolling moments
        s_c = w_c / math.sqrt(w_c * w_c + eps_w2) if stick is None else stick[3]
        m_pin = mu_pin_r * pin_abs * s_c  # −μ Σ|F_pin,j| r_pin sgn(ω_r), ω_r = −g ω_C, g > 0
        m_drag = -k_drag * w_c
        mu_rr = mu_rr_r * s_c * s_1g  # M_rr = −mu_rr N_N = −μ_NR N_N r_R sgn((1 − g) ω_C)
        # N_N = αN a_S + βN (nut), N_S = αS a_S + βS (screw)
        alpha_n = mp / (nr * enz)
        beta_n = load / (nr * enz)
        rhs7 = -nr * m_pin + m_drag
        if stick is not None:
            # the static state `_stick` solved: no acceleration and its own N_S. The screw's moment
            # equation cannot give N_S here: with no torque the static friction cancels the contact
            # force's moment about the screw axis (mom_s = 0)
            acc_s = acc_c = 0.0
            if not forces:
                return acc_s, acc_c
            n_s = stick[4]
        else:
            alpha_s = -i_s / (nr * mom_s)
            beta_s = (tau - nr * mom_f0) / (nr * mom_s)
            # roller axial (3)
            a11 = -mr_p - esz * alpha_s - enz * alpha_n
            a12 = mr_kmig
            b1 = f0z + esz * beta_s + enz * beta_n
            # roller spin (6) with F_gt from (5) and F_pt from (7)
            cs = r_g * esy - spin_s
            cn = r_g * eny - (spin_n - mu_rr)  # M_rr moved to the left-hand side
            a21 = cs * alpha_s + cn * alpha_n
            a22 = j_spin
            b2 = spin_f0 + m_pin - r_g * f0y - r_g * rhs7 / (nr * a) - cs * beta_s - cn * beta_n
            det = a11 * a22 - a12 * a21
            acc_s = (b1 * a22 - a12 * b2) / det
            acc_c = (a11 * b2 - a21 * b1) / det
            if not forces:
                return acc_s, acc_c
            n_s = alpha_s * acc_s + beta_s
        n_n = alpha_n * acc_s + beta_n
        f_pt = (rhs7 - i_c * acc_c) / (nr * a)
        f_gt = mr_a * acc_c - esy * n_s - eny * n_n - f_pt - f0y
        tan_g = tan_gear * gear_sign
        f_pr = -mr_a * w_c * w_c - f0x - esx * n_s - enx * n_n + tan_g * f_gt
        fx, fy, fz = n_s * (esx - nsx) + f0x, n_s * (esy - nsy) + f0y, n_s * (esz - nsz) + f0z
        fnx, fny, fnz = n_n * (enx - nnx), n_n * (eny - nny), n_n * (enz - nnz)
        m_rr = -n_n * mu_rr
        # tilting: thread forces at their contact points (axial position: the load centroid) about the
        # roller centre; the gear forces act equally at both ends and add no moment; the pins j = 1, 2 at
        # z = ±span/2 react the moment: x1 − x2 = −2 M_y / span, y1 − y2 = 2 M_x / span
        sx, sy, sz = n_s * esx + f0x, n_s * esy + f0y, n_s * esz + f0z
        nx_, ny_, nz_ = n_n * enx, n_n * eny, n_n * enz
        m_x = rsy * sz - zbar * sy + rny * nz_ - zbar * ny_
        m_y = zbar * sx - rsx * sz + zbar * nx_ - rnx * nz_
        dx, dy = -2.0 * m_y / span, 2.0 * m_x / span
        # power lost: friction on the slips, pin and rolling moments on their spins, drag
        diss = nr * (-(fx * vx + fy * vy + fz * vz) - (fnx * wx + fny * wy + fnz * wz) - m_pin * (-g * w_c)
                     - m_rr * ((1.0 - g) * w_c)) - m_drag * w_c
        return Forces(acc_s, acc_c, diss, n_s, n_n, fx, fy, fz, vx, vy, vz, m_rr, f_gt, -tan_g * f_gt, f_pr, f_pt,
                      m_pin, fnx, fny, fnz, math.sqrt(wx * wx + wy * wy + wz * wz), m_y,
                      0.5 * (f_pr + dx), 0.5 * (f_pt + dy), 0.5 * (f_pr - dx), 0.5 * (f_pt - dy),
                      m_drag, nr * n_n * enz, float(sign))

    def stick_forces(self, torque_nm: float, load_n: float, sign: int = 1, pin_abs: float = 0.0,
                     gear_sign: float = 1.0) -> tuple[Forces | None, float]:
        """The static state at rest (u = 0) with set-valued Coulomb friction (as `ideal` treats its loss).

        At rest with zero accelerations, equations 1–7 are linear in the screw normal force N_S and
        the screw–roller friction force q = N_S t (in the plane of the sliding directions, q = G c)
        once the share σ ∈ [−1, 1] of the pin and rolling-resistance moments (which act together
        against ω_C) is fixed: screw torque (1), roller axial (3) and roller spin (6) are three
        equations in (N_S, c₀, c₁), with N_N = F / (N_R n_N,z) from the nut (2). The solution is
        affine in σ, so |q|² − (μ N_S)² is a quadratic in σ: the mechanism sticks iff its minimum
        over [−1, 1] is ≤ 0 (closed form, no iteration). Returns (forces, r) with r = |q| / (μ N_S)
        at that σ (≤ 1: sticks), forces None when no compressive solution exists. The nut contact
        is taken as not slipping at rest (statically indeterminate against the screw side).
        """
        f, r = self._stick(torque_nm, load_n, sign, pin_abs, gear_sign)
        if f is not None and abs(f.pin_force_sum_n - pin_abs) > 0.01 * f.pin_force_sum_n:
            # the pin friction capacity scales with the pin forces the static state itself sets
            f, r = self._stick(torque_nm, load_n, int(f.sign), f.pin_force_sum_n, gear_sign)
        return f, r

    def _stick(self, tau, load, sign, pin_abs, gear_sign):
        c = self.constants
        mu, mu_pin_r, mu_rr_r, nr, a, r_g, s_1g = c.mu, c.mu_pin_r, c.mu_rr_r, c.nr, c.a, c.r_g, c.s_1g
        for sg in (sign, -sign):
            sd = self._side_k[sg]
            g00, g01, g10, g11, g20, g21 = sd.g00, sd.g01, sd.g10, sd.g11, sd.g20, sd.g21
            nsx, nsy, nsz, psx, psy, rsx, rsy = sd.nsx, sd.nsy, sd.nsz, sd.psx, sd.psy, sd.rsx, sd.rsy
            nnx, nny, nnz, rnx, rny = sd.nnx, sd.nny, sd.nnz, sd.rnx, sd.rny
            n_n = load / (nr * nnz)
            spin_n = rnx * nny - rny * nnx
            k = r_g - rsx
            A = ((nr * (psx * nsy - psy * nsx), nr * (psx * g10 - psy * g00), nr * (psx * g11 - psy * g01)),
                 (nsz, g20, g21),
                 (k * nsy + rsy * nsx, k * g10 + rsy * g00, k * g11 + rsy * g01))
            rhs0 = (tau, -nnz * n_n, -(r_g * nny - spin_n) * n_n)
            rhs1 = (0.0, 0.0, mu_pin_r * pin_abs * (1.0 + r_g / a) - mu_rr_r * s_1g * n_n)
            x0, x1 = _solve3(A, rhs0), _solve3(A, rhs1)
            if x0 is None:
                continue
            q0 = (g00 * x0[1] + g01 * x0[2], g10 * x0[1] + g11 * x0[2], g20 * x0[1] + g21 * x0[2])
            q1 = (g00 * x1[1] + g01 * x1[2], g10 * x1[1] + g11 * x1[2], g20 * x1[1] + g21 * x1[2])
            mu2 = mu * mu
            qa = _dot(q1, q1) - mu2 * x1[0] * x1[0]
            qb = 2.0 * (_dot(q0, q1) - mu2 * x0[0] * x1[0])
            # σ: the least friction share |q|/N_S among the ends, the minimum of |q| and the minimum
            # of the quadratic (which decides feasibility: r ≤ 1 there iff the cone can hold)
            cands = [-1.0, 1.0, 0.0]
            q11 = _dot(q1, q1)
            if q11 > 0.0:
                cands.append(max(-1.0, min(1.0, -_dot(q0, q1) / q11)))
            if qa > 0.0:
                cands.append(max(-1.0, min(1.0, -qb / (2.0 * qa))))
            best = math.inf
            for s_ in cands:
                n_ = x0[0] + s_ * x1[0]
                if n_ > 0.0:
                    qq = (q0[0] + s_ * q1[0], q0[1] + s_ * q1[1], q0[2] + s_ * q1[2])
                    # (|q|/N_S)²: N_S may be so small (at rest with no load) that N_S² underflows to zero
                    r_ = math.sqrt(_dot(qq, qq)) / n_
                    r_ *= r_
                    if r_ < best:
                        best, sig, n_s, q = r_, s_, n_, qq
            if best == math.inf:
                continue
            f = self._solve((0.0, 0.0), tau, load, sg, pin_abs, gear_sign, True,
                            (q[0] / n_s, q[1] / n_s, q[2] / n_s, sig, n_s))
            if f.n_s >= 0.0 and f.n_n >= 0.0 and math.isfinite(f.n_s):
                mag = math.sqrt(_dot(q, q)) / n_s
                return f, (mag / mu if mu > 0 else (0.0 if mag == 0.0 else math.inf))
        return None, math.inf

    # -- time stepping ------------------------------------------------------------------
    def _rosenbrock(self, ws, wc, flank_sign, pin_abs, gear_force, mem, tau, load, h):
        """One ROS2 step of length h (module doc): returns (ω_S, ω_C, end forces, start forces, solver memory).

        ROS2 is a W-method: second order with any Jacobian approximation (Verwer et al. 1999),
        so the finite-difference Jacobian is formed every `JACOBIAN_REFRESH_STEPS` steps, on a
        flank change, or when the memory is empty (always, on sub-steps), and kept in between.
        """
        gsign = 1.0 if gear_force >= 0.0 else -1.0
        f0 = self.solve_forces((ws, wc), tau, load, flank_sign, pin_abs, gsign)
        if abs(f0.pin_force_sum_n - pin_abs) > 1e-2 * f0.pin_force_sum_n:
            # the pin forces follow the inputs (the tilting couple scales with the load): take them at this
            # step's inputs rather than the last step's, or the lag is a first-order error in the carrier
            pin_abs = f0.pin_force_sum_n
            f0 = self.solve_forces((ws, wc), tau, load, int(f0.sign), pin_abs, gsign)
        sign = int(f0.sign)
        fs, fc = f0.acc_s, f0.acc_c
        if len(mem) == 6 and mem[4] == sign and mem[5] < JACOBIAN_REFRESH_STEPS:
            j00, j01, j10, j11 = mem[:4]
            age = mem[5] + 1
        else:
            ds = 1e-6 * max(1.0, abs(ws))
            dc = 1e-6 * max(1.0, abs(wc))
            s_s, c_s = self._solve((ws + ds, wc), tau, load, sign, pin_abs, gsign, forces=False)
            s_c, c_c = self._solve((ws, wc + dc), tau, load, sign, pin_abs, gsign, forces=False)
            j00, j10 = (s_s - fs) / ds, (c_s - fc) / ds
            j01, j11 = (s_c - fs) / dc, (c_c - fc) / dc
            age = 0
        gh = (1.0 + 1.0 / math.sqrt(2.0)) * h
        w00, w01, w10, w11 = 1.0 - gh * j00, -gh * j01, -gh * j10, 1.0 - gh * j11
        det = w00 * w11 - w01 * w10
        k1s = (w11 * fs - w01 * fc) / det
        k1c = (w00 * fc - w10 * fs) / det
        f2s, f2c = self._solve((ws + h * k1s, wc + h * k1c), tau, load, sign, pin_abs, gsign, forces=False)
        r_s, r_c = f2s - 2.0 * k1s, f2c - 2.0 * k1c
        k2s = (w11 * r_s - w01 * r_c) / det
        k2c = (w00 * r_c - w10 * r_s) / det
        ws1 = ws + h * (1.5 * k1s + 0.5 * k2s)
        wc1 = wc + h * (1.5 * k1c + 0.5 * k2c)
        f1 = self.solve_forces((ws1, wc1), tau, load, sign, pin_abs, gsign)
        return ws1, wc1, f1, f0, (j00, j01, j10, j11, float(sign), float(age))

    def _in_slip_zone(self, f: Forces) -> bool:
        v2 = f.vx * f.vx + f.vy * f.vy + f.vz * f.vz
        return v2 < (SLIP_ZONE * self.eps_v) ** 2

    def _books_open(self, ws, wc, ws1, wc1, f0, f1, h, tau, load) -> bool:
        """The step's own energy balance misses by more than STEP_BALANCE_TOL of the energy it moved:
        a cheap error indicator (the same ledger as the energy guard, per step) that sends the step
        to error control, where it is halved until its halves close their books."""
        dth = 0.5 * h * (ws + ws1)
        w_in, w_out = tau * dth, load * self.p * dth
        d_e = self.stored_energy_j(ws1, wc1) - self.stored_energy_j(ws, wc)
        diss = 0.5 * h * (f0.dissipated_w + f1.dissipated_w)
        return abs(w_in - w_out - d_e - diss) > (STEP_BALANCE_TOL * (abs(w_in) + abs(w_out) + abs(d_e) + abs(diss))
                                                 + STEP_BALANCE_FLOOR_J)

    def _step(self, ws, wc, sign, pin_abs, gear, mem, tau, load):
        """One output step: error-controlled ROS2 sub-steps where the friction state changes, stick at rest.

        Returns (ω_S, ω_C, Δθ_S, Δθ_C, dissipated J, forces at the end, flank sign, pin force sum,
        gear force, solver memory). Away from friction transitions this is one ROS2 step with a
        frozen Jacobian (the common case, no extra cost). Where a speed changes sign, the flank
        pair switches or the slip is within SLIP_ZONE ε of zero (the regularised Coulomb law is
        stiff and far from saturation there), the step is checked by step doubling and halved
        (down to dt/2**MAX_HALVINGS) until the two answers agree within SUBSTEP_TOL ε of slip.
        At rest, or when the slip reaches zero (or the regularised creep band) while the static
        friction can hold (`stick_forces`, r ≤ 1), the mechanism sticks: speeds are set to zero,
        and the kinetic energy left (slip within a few ε: tiny) is booked as the work of the
        static friction impulse.
        """
        if self._kn is not None:
            ws, wc, dth_s, dth_c, diss, f, sg, pin_abs, gear, m = self._kernel_step(
                ws, wc, sign, pin_abs, gear, mem, tau, load)
            return ws, wc, dth_s, dth_c, diss, Forces(*f), sg, pin_abs, gear, m
        h = self.dt_s
        ros = self._rosenbrock
        zone2 = (SLIP_ZONE * self.eps_v) ** 2
        if ws != 0.0 or wc != 0.0:  # fast path: one plain step when nothing about the friction changes
            ws1, wc1, f1, f0, m1 = ros(ws, wc, sign, pin_abs, gear, mem, tau, load, h)
            if not (ws * ws1 < 0.0 or wc * wc1 < 0.0 or f1.sign != f0.sign or f0.sign != sign
                    or f0.vx * f0.vx + f0.vy * f0.vy + f0.vz * f0.vz < zone2
                    or f1.vx * f1.vx + f1.vy * f1.vy + f1.vz * f1.vz < zone2
                    or ws * (ws + h * f0.acc_s) < 0.0 or wc * (wc + h * f0.acc_c) < 0.0
                    or self._books_open(ws, wc, ws1, wc1, f0, f1, h, tau, load)):
                return (ws1, wc1, 0.5 * h * (ws + ws1), 0.5 * h * (wc + wc1),
                        0.5 * h * (f0.dissipated_w + f1.dissipated_w), f1, int(f1.sign), f1.pin_force_sum_n, f1.f_gt, m1)
        left = h
        hs = h
        dth_s = dth_c = diss = 0.0
        f_end = None
        while left > 1e-9 * h:
            if ws == 0.0 and wc == 0.0:
                st, r = self.stick_forces(tau, load, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0)
                if st is not None and r <= 1.0:  # inputs are held over the step: it stays stuck
                    f_end, sign, gear, pin_abs = st, int(st.sign), st.f_gt, st.pin_force_sum_n
                    break
            hs = min(hs, left)
            full = ros(ws, wc, sign, pin_abs, gear, mem if hs == h else (), tau, load, hs)
            ws1, wc1, f1, f0, _ = full
            subs = ((ws, wc, hs, full),)
            if hs > self._h_min and (ws * ws1 < 0.0 or wc * wc1 < 0.0 or f1.sign != f0.sign or f0.sign != sign
                                     # the start slope carries a speed through zero within the step
                                     or ws * (ws + hs * f0.acc_s) < 0.0 or wc * (wc + hs * f0.acc_c) < 0.0
                                     or self._books_open(ws, wc, ws1, wc1, f0, f1, hs, tau, load)
                                     # slow slip: refined less deep (creep near the stick band's edge can
                                     # last many steps, and the layer is resolved by the checks above)
                                     or (hs > self._h_zone
                                         and (f0.vx * f0.vx + f0.vy * f0.vy + f0.vz * f0.vz < zone2
                                              or f1.vx * f1.vx + f1.vy * f1.vy + f1.vz * f1.vz < zone2))):
                first = ros(ws, wc, sign, pin_abs, gear, (), tau, load, 0.5 * hs)
                fa = first[2]
                second = ros(first[0], first[1], int(fa.sign), fa.pin_force_sum_n, fa.f_gt, (), tau, load, 0.5 * hs)
                fb = second[2]
                err = math.sqrt((fb.vx - f1.vx) ** 2 + (fb.vy - f1.vy) ** 2 + (fb.vz - f1.vz) ** 2)
                if err > self._slip_tol + 1e-6 * math.sqrt(fb.vx ** 2 + fb.vy ** 2 + fb.vz ** 2) \
                        or self._books_open(ws, wc, first[0], first[1], first[3], fa, 0.5 * hs, tau, load) \
                        or self._books_open(first[0], first[1], second[0], second[1], second[3], fb, 0.5 * hs, tau,
                                            load):
                    hs *= 0.5
                    continue
                subs = ((ws, wc, 0.5 * hs, first), (first[0], first[1], 0.5 * hs, second))
            grow = True
            for w0s, w0c, hk, (w1s, w1c, g1, g0, m1) in subs:
                dth_s += 0.5 * hk * (w0s + w1s)
                dth_c += 0.5 * hk * (w0c + w1c)
                diss += 0.5 * hk * (g0.dissipated_w + g1.dissipated_w)
                left -= hk
                ws, wc, sign, pin_abs, gear, mem, f_end = w1s, w1c, int(g1.sign), g1.pin_force_sum_n, g1.f_gt, m1, g1
                v2 = g1.vx * g1.vx + g1.vy * g1.vy + g1.vz * g1.vz
                if w0s * w1s < 0.0 or w0c * w1c < 0.0 or v2 < zone2:
                    st, r = self.stick_forces(tau, load, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0)
                    # capture where the regularised law would creep (v_c = ε r/√(1 − r²)) or the slip
                    # passed through zero: the set-valued law holds the mechanism there
                    if st is not None and r < 1.0 and (w0s * w1s < 0.0 or w0c * w1c < 0.0 or
                                                       v2 <= (2.0 * self.eps_v * (1.0 + r / math.sqrt(1.0 - r * r))) ** 2):
                        diss += self.stored_energy_j(ws, wc)
                        ws = wc = 0.0
                        f_end, sign, gear, pin_abs, mem = st, int(st.sign), st.f_gt, st.pin_force_sum_n, ()
                        grow = False
                        break
            if grow and hs < h:
                hs *= 2.0
        return ws, wc, dth_s, dth_c, diss, f_end, sign, pin_abs, gear, mem

    def _kernel_step(self, ws, wc, sign, pin_abs, gear, mem, tau, load):
        """`_step` by the compiled kernel, the end forces as the kernel's plain tuple (Forces' field order)."""
        ws, wc, dth_s, dth_c, diss, f, sg, pin_abs, gear, m = self._kn.step(
            float(ws), float(wc), float(sign), float(pin_abs), float(gear), kernel_memory(mem), float(tau),
            float(load), self._kernel_k, self._kernel_s)
        return ws, wc, dth_s, dth_c, diss, f, int(sg), pin_abs, gear, memory_from_kernel(m)

    def _make_step(self):
        """The step: `_step` and the ledger. The record keeps the end forces as its aux, from which the slip
        speed and the internal vector (`expand_one`) are derived when read, and their axial thread force as
        the nut force. With the compiled kernel the aux is the kernel's plain tuple: a `Forces` is built only
        when read (it would cost a tenth of the step otherwise).
        """
        stored, expand_one = self.stored_energy_j, self.expand_one
        step = self._kernel_step if self._kn is not None else self._step
        finish = self.finisher(lambda w_s, w_c, f1: slip_speed(Forces(*f1)),
                               lambda w_s, w_c, f1: expand_one(Forces(*f1).compact))

        def step_packed(x, torque_nm: float, load_n: float):
            sign, pin_abs, gear, mem = x[11]
            ws1, wc1, dth_s, dth_c, diss, f1, sign, pin_abs, gear, mem = step(
                x[2], x[4], sign, pin_abs, gear, mem, torque_nm, load_n)
            return finish(x, x[1] + dth_s, ws1, x[3] + dth_c, wc1, torque_nm, load_n, diss, stored(ws1, wc1),
                          (sign, pin_abs, gear, mem), f1, f1[_AXIAL])
        return step_packed

    def _run_impl(self, state: State, torque_nm: np.ndarray, load_n: np.ndarray) -> Trajectory:
        """The batch form of the step: the same arithmetic on local scalars (compiled: one kernel call), the
        per-tooth expansion built when first read."""
        s, n = state, len(torque_nm)
        ws, wc, th_s, th_c = s.screw_speed_rad_s, s.carrier_speed_rad_s, s.screw_angle_rad, s.carrier_angle_rad
        sign, pin_abs, gear, mem = self.pack_state(s)[11]
        cols = np.empty((n, 8))
        compact = np.empty((n, self._compact_size))
        if self._kn is not None:
            ws, wc, th_s, th_c, sign, pin_abs, gear, mem = self._kn.fu2018_run(
                float(ws), float(wc), float(th_s), float(th_c), float(sign), float(pin_abs), float(gear),
                kernel_memory(mem), torque_nm, load_n, self._kernel_k, self._kernel_s, cols, compact)
            sign, mem = int(sign), memory_from_kernel(mem)
        else:
            step = self._step
            for i, (tau, load) in enumerate(zip(torque_nm.tolist(), load_n.tolist())):
                ws, wc, dth, dthc, d, f1, sign, pin_abs, gear, mem = step(ws, wc, sign, pin_abs, gear, mem, tau, load)
                th_s += dth
                th_c += dthc
                cols[i] = (ws, wc, th_s, th_c, dth, d, slip_speed(f1), f1.axial)
                compact[i] = f1.compact
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

    def expand_one(self, compact: tuple) -> np.ndarray:
        """`expand` for one step, as a single gather from [compact, ζ/N_T·N_S, ζ/N_T·N_N] (the node's path)."""
        row = np.array(compact)
        src = np.concatenate((row, self._zeta_share * compact[0], self._zeta_share * compact[1]))
        return src[self._gather]

    def _gather_index(self) -> np.ndarray:
        """Positions in `expand_one`'s source vector of every element of the layout."""
        geo = self.geo
        nr, nt, nq = geo.n_rollers, geo.n_teeth, len(PER_ROLLER_QUANTITIES)
        ncomp = self._compact_size
        per_roller = np.tile(np.arange(nq), nr)
        teeth = np.arange(nt)[:, None] + ncomp + nt * np.arange(2)[None, :]  # (tooth, side)
        per_tooth = np.tile(teeth.ravel(), nr)
        carrier = np.arange(nq, ncomp)
        return np.concatenate([per_roller, per_tooth, carrier])

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


_AXIAL = Forces._fields.index("axial")  # the nut force's place in a Forces or the kernel's tuple


def slip_speed(f: Forces) -> float:
    """|v_s|, m/s: the screw–roller sliding speed of an evaluation (the `slip_speed_m_s` output)."""
    return math.sqrt(f.vx**2 + f.vy**2 + f.vz**2)


JACOBIAN_REFRESH_STEPS = 2  # 10 lost stability in the stiff carrier mode at μ = 0.1 under 20 kN


def _dot(x, y) -> float:
    return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]


def _solve3(A, b):
    """x with A x = b for a 3×3 A (Cramer's rule in scalars; None when singular)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = A
    c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0 or not math.isfinite(det):
        return None
    b0, b1, b2 = b
    x0 = (b0 * c00 + b1 * (a02 * a21 - a01 * a22) + b2 * (a01 * a12 - a02 * a11)) / det
    x1 = (b0 * c01 + b1 * (a00 * a22 - a02 * a20) + b2 * (a02 * a10 - a00 * a12)) / det
    x2 = (b0 * c02 + b1 * (a01 * a20 - a00 * a21) + b2 * (a00 * a11 - a01 * a10)) / det
    return x0, x1, x2
