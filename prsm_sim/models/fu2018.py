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
6. roller spin       I_R (1 − g) ω̇_C = (r_S × F_RS)_z + (r_N × F_RN)_z + r_R F_gt + M_pin + M_rr
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
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from prsm_sim.physics.contact import ContactPoint, contact_for
from prsm_sim.models.base import Model, _inputs, columns_to_trajectory
from prsm_sim.outputs import InternalBlock, InternalLayout, State, Trajectory
from prsm_sim.params import Params

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
)
PER_TOOTH_QUANTITIES = (("screw_normal_force_n", "N"), ("nut_normal_force_n", "N"))
CARRIER_QUANTITIES = (("carrier_drag_torque_nm", "N·m"), ("axial_force_n", "N"), ("load_sign", "1"))
GEAR_PRESSURE_ANGLE_RAD = math.radians(20.0)  # standard involute spur/ring gear


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


@dataclass(frozen=True)
class _Side:
    """Contact geometry for one load sign, flattened to floats for the hot path."""

    sign: int
    screw: ContactPoint
    nut: ContactPoint
    G: np.ndarray  # screw–roller sliding: v_s = G u


def _side_tuple(side: _Side, a: float) -> tuple[float, ...]:
    """One flank pair's geometry as floats for the scalar hot path (`Fu2018._solve` unpacks it):
    G (row major), n_S, P_S (x, y), P_S − axis (x, y), n_N, (r_N × n_N)_z about the roller axis."""
    ns, nn = side.screw.normal_on_roller, side.nut.normal_on_roller
    ps, pn = side.screw.point_m, side.nut.point_m
    spin_n = (pn[0] - a) * nn[1] - pn[1] * nn[0]
    return tuple(float(v) for v in (*side.G.ravel(), *ns, ps[0], ps[1], ps[0] - a, ps[1], *nn, spin_n))


class Forces(NamedTuple):
    """Accelerations and internal forces of one evaluation, per roller where it applies.

    A tuple on purpose (cheap on the hot path); fields from `n_s` on are the compact
    per-step record in layout order: PER_ROLLER_QUANTITIES, then CARRIER_QUANTITIES.
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
    m_drag: float
    axial: float  # axial thread force on the nut, all rollers, along +x_nut
    sign: float

    @property
    def compact(self) -> tuple:
        return self[3:]



class Fu2018(Model):
    name = "fu2018"

    def __init__(self, params: Params, dt_s: float) -> None:
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
        self._mp = m.moved_mass_kg * self.p
        self._i_s, self._i_c = m.screw_inertia_kgm2, m.carrier_inertia_kgm2
        self._mr_p = m.roller_mass_kg * self.p
        self._mr_kmig = m.roller_mass_kg * self.k_mig
        self._mr_a = m.roller_mass_kg * self.a
        self._mu_pin_r = fr.mu_pin * geo.pin_radius_m
        self._mu_rr_r = fr.mu_nut_roller_rolling * geo.roller_radius_m
        self._tan_gear = math.tan(GEAR_PRESSURE_ANGLE_RAD)
        # I_R (1 − g) − r_R m_R a − r_R I_C / (N_R a): the carrier-mode inertia of the spin equation
        self._j_spin = (m.roller_inertia_kgm2 * (1.0 - geo.gear_ratio) - geo.roller_radius_m * self._mr_a
                        - geo.roller_radius_m * m.carrier_inertia_kgm2 / (nr * self.a))
        self._zeta_share = self.zeta / nt
        self._gather = self._gather_index()
        self._side_k = {sg: _side_tuple(side, self.a) for sg, side in self.sides.items()}
        self._k = (self._coulomb, fr.mu_screw_roller, self.eps_v**2, self.eps_w**2, self._c_nt, self._mu_pin_r,
                   self.k_drag, self._mu_rr_r, nr, self.a, self._r_r, self._mp, self._i_s, self._i_c, self._mr_p,
                   self._mr_kmig, self._mr_a, self._j_spin, self._tan_gear, self._g)
        self.layout = InternalLayout(blocks=(
            InternalBlock("per_roller", ("roller", "quantity"), (nr, len(PER_ROLLER_QUANTITIES)), PER_ROLLER_QUANTITIES),
            InternalBlock("per_tooth", ("roller", "tooth", "quantity"), (nr, nt, 2), PER_TOOTH_QUANTITIES),
            InternalBlock("carrier", ("quantity",), (len(CARRIER_QUANTITIES),), CARRIER_QUANTITIES),
        ))

    def _side(self, sign: int) -> _Side:
        ev = self.params.friction.contact_evaluation
        s = contact_for(self.geo, "screw", ev, sign)
        n = contact_for(self.geo, "nut", ev, sign)
        return _Side(sign=sign, screw=s, nut=n, G=s.sliding_matrix(self.geo))

    # -- the force system ---------------------------------------------------------------
    def solve_forces(self, u, torque_nm: float, load_n: float, sign: int = 1,
                     pin_abs: float = 0.0, gear_sign: float = 1.0) -> Forces:
        """Solve equations 1–7 (module doc) at speeds u for accelerations and internal forces.

        The flank pair is the one that carries the load compressively: tried with `sign`
        (the state's last one) and switched if a normal force comes out negative. |F_pin|
        and the gear force sign enter lagged (from the state), which keeps the system
        linear; they only scale the small pin-friction term and the gear's radial part.
        """
        f = self._solve(u, torque_nm, load_n, sign, pin_abs, gear_sign)
        if f[3] < 0.0 or f[4] < 0.0:  # a normal force in tension: the other flank pair carries the load
            g = self._solve(u, torque_nm, load_n, -sign, pin_abs, gear_sign)
            if g[3] >= 0.0 and g[4] >= 0.0:
                f = g
        return f

    def _solve(self, u, tau, load, sign, pin_abs, gear_sign, forces: bool = True):
        """Equations 1–7 eliminated by hand to a 2×2 system in (ω̇_S, ω̇_C).

        Scalar arithmetic on purpose: this runs several times per step and numpy's per-call
        overhead on 3-vectors would dominate. Nut (2) and screw (1) give N_N and N_S linearly
        in ω̇_S; the carriers (7) give F_pt, the roller tangential balance (5) F_gt; roller
        axial (3) and spin (6) are then two equations in the two accelerations; the radial
        balance (4) gives F_pr last. Returns the accelerations only unless `forces`.
        """
        # constants unpacked from two tuples: one bytecode each instead of ~30 attribute lookups
        (g00, g01, g10, g11, g20, g21, nsx, nsy, nsz, psx, psy, rsx, rsy, nnx, nny, nnz, spin_n) = self._side_k[sign]
        (coulomb, mu, eps_v2, eps_w2, c_nt, mu_pin_r, k_drag, mu_rr_r, nr, a, r_r, mp, i_s, i_c, mr_p, mr_kmig, mr_a,
         j_spin, tan_gear, g) = self._k
        w_s, w_c = u
        vx = g00 * w_s + g01 * w_c
        vy = g10 * w_s + g11 * w_c
        vz = g20 * w_s + g21 * w_c
        if coulomb:
            k = mu / math.sqrt(vx * vx + vy * vy + vz * vz + eps_v2)
            esx, esy, esz = nsx - k * vx, nsy - k * vy, nsz - k * vz
            f0x = f0y = f0z = 0.0
        else:
            esx, esy, esz = nsx, nsy, nsz
            f0x, f0y, f0z = -c_nt * vx, -c_nt * vy, -c_nt * vz
        mom_s = psx * esy - psy * esx
        mom_f0 = psx * f0y - psy * f0x
        spin_s = rsx * esy - rsy * esx
        spin_f0 = rsx * f0y - rsy * f0x
        s_c = w_c / math.sqrt(w_c * w_c + eps_w2)  # regularised sgn(ω_C); spins rel. nut and carrier have sign −s_c
        m_pin = mu_pin_r * pin_abs * s_c  # −μ|F|r sgn(−gω_C)
        m_drag = -k_drag * w_c
        mu_rr = -mu_rr_r * s_c  # μ_NR r_R sgn((1−g)ω_C)
        # N_N = αN a_S + βN (nut), N_S = αS a_S + βS (screw)
        alpha_n = mp / (nr * nnz)
        beta_n = load / (nr * nnz)
        alpha_s = -i_s / (nr * mom_s)
        beta_s = (tau - nr * mom_f0) / (nr * mom_s)
        rhs7 = -nr * m_pin + m_drag
        # roller axial (3)
        a11 = -mr_p - esz * alpha_s - nnz * alpha_n
        a12 = mr_kmig
        b1 = f0z + esz * beta_s + nnz * beta_n
        # roller spin (6) with F_gt from (5) and F_pt from (7)
        cs = r_r * esy - spin_s
        cn = r_r * nny - (spin_n - mu_rr)  # M_rr = −mu_rr N_N moved to the left-hand side
        a21 = cs * alpha_s + cn * alpha_n
        a22 = j_spin
        b2 = spin_f0 + m_pin - r_r * f0y - r_r * rhs7 / (nr * a) - cs * beta_s - cn * beta_n
        det = a11 * a22 - a12 * a21
        acc_s = (b1 * a22 - a12 * b2) / det
        acc_c = (a11 * b2 - a21 * b1) / det
        if not forces:
            return acc_s, acc_c
        n_s = alpha_s * acc_s + beta_s
        n_n = alpha_n * acc_s + beta_n
        f_pt = (rhs7 - i_c * acc_c) / (nr * a)
        f_gt = mr_a * acc_c - esy * n_s - nny * n_n - f_pt - f0y
        tan_g = tan_gear * gear_sign
        f_pr = -mr_a * w_c * w_c - f0x - esx * n_s - nnx * n_n + tan_g * f_gt
        fx, fy, fz = n_s * (esx - nsx) + f0x, n_s * (esy - nsy) + f0y, n_s * (esz - nsz) + f0z
        m_rr = -n_n * mu_rr
        # power lost: screw friction on the slip, pin and rolling moments on their spins, drag
        diss = nr * (-(fx * vx + fy * vy + fz * vz) - m_pin * (-g * w_c) - m_rr * ((1.0 - g) * w_c)) - m_drag * w_c
        return Forces(acc_s, acc_c, diss, n_s, n_n, fx, fy, fz, vx, vy, vz, m_rr, f_gt, -tan_g * f_gt, f_pr, f_pt,
                      m_pin, m_drag, nr * n_n * nnz, float(sign))

    # -- time stepping ------------------------------------------------------------------
    def _rosenbrock(self, ws, wc, flank_sign, pin_abs, gear_force, mem, tau, load):
        """One ROS2 step (module doc) in scalars: returns (ω_S, ω_C, end forces, start forces, solver memory).

        ROS2 is a W-method: second order with any Jacobian approximation (Verwer et al. 1999),
        so the finite-difference Jacobian is formed every `JACOBIAN_REFRESH_STEPS` steps, on a
        flank change, or when the state carries none, and kept in the state in between.
        """
        h = self.dt_s
        gsign = 1.0 if gear_force >= 0.0 else -1.0
        f0 = self.solve_forces((ws, wc), tau, load, flank_sign, pin_abs, gsign)
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

    def _advance(self, state: State, torque_nm: float, load_n: float):
        s = state
        ws1, wc1, f1, f0, mem = self._rosenbrock(s.screw_speed_rad_s, s.carrier_speed_rad_s, s.flank_sign,
                                                 s.pin_force_n, s.gear_force_n, s.solver, torque_nm, load_n)
        h = self.dt_s
        after = State(screw_angle_rad=s.screw_angle_rad + 0.5 * h * (s.screw_speed_rad_s + ws1),
                      screw_speed_rad_s=ws1,
                      carrier_angle_rad=s.carrier_angle_rad + 0.5 * h * (s.carrier_speed_rad_s + wc1),
                      carrier_speed_rad_s=wc1, flank_sign=int(f1.sign), pin_force_n=math.hypot(f1.f_pr, f1.f_pt),
                      gear_force_n=f1.f_gt, solver=mem)
        internal = self.expand_one(f1.compact)
        return self.finish_step(s, after, torque_nm, load_n, dissipated_j=0.5 * h * (f0.dissipated_w + f1.dissipated_w),
                                slip_speed_m_s=math.sqrt(f1.vx**2 + f1.vy**2 + f1.vz**2), internal=internal,
                                nut_force_n=f1.axial)

    def run(self, state: State, torque_nm, load_n) -> Trajectory:
        """Batch form of `step`: the same arithmetic on local scalars, per-tooth expansion once at the end."""
        tau_a, load_a = _inputs(torque_nm, load_n)
        h, p = self.dt_s, self.p
        s = state
        ws, wc, th_s, th_c = s.screw_speed_rad_s, s.carrier_speed_rad_s, s.screw_angle_rad, s.carrier_angle_rad
        sign, pin_abs, gear, mem = s.flank_sign, s.pin_force_n, s.gear_force_n, s.solver
        w_in = w_out = diss = 0.0
        rows, comp = [], []
        for tau, load in zip(tau_a.tolist(), load_a.tolist()):
            ws1, wc1, f1, f0, mem = self._rosenbrock(ws, wc, sign, pin_abs, gear, mem, tau, load)
            dth = 0.5 * h * (ws + ws1)
            th_s += dth
            th_c += 0.5 * h * (wc + wc1)
            d = 0.5 * h * (f0.dissipated_w + f1.dissipated_w)
            w_in += tau * dth
            w_out += load * p * dth
            diss += d
            ws, wc = ws1, wc1
            sign, pin_abs, gear = int(f1.sign), math.hypot(f1.f_pr, f1.f_pt), f1.f_gt
            rows.append((ws1, wc1, th_s, th_c, dth, d, math.sqrt(f1.vx**2 + f1.vy**2 + f1.vz**2), f1.axial))
            comp.append(f1.compact)
        n = len(rows)
        final = State(time_s=s.time_s + h * n, screw_angle_rad=th_s, screw_speed_rad_s=ws, carrier_angle_rad=th_c,
                      carrier_speed_rad_s=wc, work_in_j=s.work_in_j + w_in, work_out_j=s.work_out_j + w_out,
                      dissipated_j=s.dissipated_j + diss, flank_sign=sign, pin_force_n=pin_abs, gear_force_n=gear,
                      solver=mem)
        cols = np.array(rows, dtype=float).reshape(n, 8)
        compact = np.array(comp, dtype=float).reshape(n, self._compact_size)
        return columns_to_trajectory(self, tau_a, load_a, cols, lambda: self.expand(compact), final,
                                     state.screw_speed_rad_s)

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
        """Compact rows (steps × 17) → the full labelled internal vectors (steps × layout.size).

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


JACOBIAN_REFRESH_STEPS = 2  # 10 lost stability in the stiff carrier mode at μ = 0.1 under 20 kN


def _sgn(x: float, eps: float) -> float:
    """Regularised sign x/√(x² + ε²): the friction laws' switch at zero speed."""
    return x / math.sqrt(x * x + eps * eps)
