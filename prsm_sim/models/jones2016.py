"""The `jones2016` model: 2-DOF Lagrange dynamics with viscous screw–roller friction (docs/model.md §4.1).

Generalised coordinates (θ_S, θ_C). The gear ties roller spin to the carrier (ω_r = −g ω_C),
the threads tie the nut to the screw (v = (L/2π) ω_S). Each of the N_R·N_T screw–roller
contacts carries f = −c v_s with v_s the sliding velocity at the contact (exact tangency
point by default, the line of centres as in Jones 2016 eqs. 20, 28 on request). By virtual
power the friction's generalised force is −c N_R N_T Gᵀ G q̇ with v_s = G q̇, so

    M q̈ = −C q̇ + B (τ, F),   C = c N_R N_T Gᵀ G,   B = [[1, −L/2π], [0, 0]]

(Jones 2016 eqs. 35–36 with eq. 34's friction terms). Linear with constant coefficients:
stepped exactly by zero-order hold (`linear_step`), and run in batch by recursive filters.
"""

from __future__ import annotations

import math
from typing import TypedDict

import numpy as np

from prsm_sim.errors import InputError, ParamError
from prsm_sim.models.linear_step import discretise
from prsm_sim.params import END_STOP_STIFFNESS_N_M, Params
from prsm_sim.physics.contact import ContactPoint, contact_for
from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.stepping.model import Model
from prsm_sim.stepping.records import InternalBlock, InternalLayout, State
from prsm_sim.stepping.trajectory import Trajectory, trajectory_from_columns

PER_ROLLER_QUANTITIES = (
    ("screw_slip_radial_m_s", "m/s"),
    ("screw_slip_tangential_m_s", "m/s"),
    ("screw_slip_axial_m_s", "m/s"),
    ("screw_friction_radial_n", "N"),
    ("screw_friction_tangential_n", "N"),
    ("screw_friction_axial_n", "N"),
)


def input_matrix(params: Params) -> np.ndarray:
    """Generalised forces of (screw torque, nut load): the load resists positive motion."""
    return np.array([[1.0, -params.geometry.lead_per_rad_m], [0.0, 0.0]])


class Jones2016(Model):
    name = "jones2016"
    has_carrier = True
    has_internal_forces = True
    steady_state_inputs = ("screw_speed_rad_s", "torque_nm")

    @classmethod
    def check_params(cls, params: Params) -> None:
        c = params.friction.viscous_n_s_m
        if not c > 0.0:
            # c is this model's only coupling of the carrier to the screw (C = c N_R N_T GᵀG): at c = 0 the
            # carrier row of M q̈ = −C q̇ + B u is unforced and the steady state (C q̇ = B u) has no solution
            raise ParamError(f"friction.viscous_n_s_m = {c!r}: model jones2016 needs c > 0 N·s/m (its only "
                             "friction ties the carrier to the screw; a small c such as 1e-12 approaches the "
                             "frictionless limit)")

    @classmethod
    def closed_form_steady_state(cls, params: Params, *, screw_speed_rad_s: float | None = None,
                                 torque_nm: float | None = None, load_n: float | None = None) -> dict | None:
        """Jones 2016 eqs. 37–41 (`steady_state`): a speed gives the torque, or a torque the speed."""
        return {"method": "closed form (Jones 2016 eqs. 37-41)",
                **steady_state(params, screw_speed_rad_s=screw_speed_rad_s, torque_nm=torque_nm, load_n=load_n)}

    def __init__(self, params: Params, dt_s: float) -> None:
        super().__init__(params, dt_s)
        geo, fr = self.geo, params.friction
        self.contact: ContactPoint = contact_for(geo, "screw", fr.contact_evaluation)
        self.G = self.contact.sliding_matrix(geo)
        n_contacts = geo.n_rollers * geo.n_teeth
        self.M = mass_matrix(params)
        self.kinetic = (float(self.M[0, 0]), float(self.M[0, 1]), float(self.M[1, 1]))  # energy guard
        self.C = fr.viscous_n_s_m * n_contacts * (self.G.T @ self.G)
        self.B = input_matrix(params)
        self.lin = discretise(self.M, self.C, self.B, self.dt_s)
        # ZOH is exact for the free screw, but against an end or stop the step does not resolve
        # (h √(k/m) > 2 for the ends' default 1e8 N/m on the screw's own reflected inertia M₀₀) the
        # position-consistent stop force held over the step reflects the screw's speed (ω₁ ≈ −ω₀, as the
        # trapezoid does), and viscous friction takes many steps to end that ring. At such steps every trial
        # step of a contact's solve (`set_contact`) is backward Euler (L-stable), its numerical dissipation
        # booked (`_make_step`); a free step stays exact. All the trials, not only those that reverse the screw:
        # the end position is then affine in the contact's force and the stop law's root exists, where a switch
        # at the ZOH's own reversal jumps it by ~h v₀/2 and can end the step at rest off the balance of load and
        # drive (envelope seed 47316: 84 µm at 0.1 s)
        omega_end = math.sqrt(END_STOP_STIFFNESS_N_M * geo.lead_per_rad_m**2 / self.M[0, 0])
        self.reverses_l_stable = self.dt_s * omega_end > 2.0
        self._contact = [False]  # `set_contact`: only a contact's trial steps are backward Euler
        self.layout = InternalLayout(blocks=(
            InternalBlock("per_roller", ("roller", "quantity"), (geo.n_rollers, len(PER_ROLLER_QUANTITIES)),
                          PER_ROLLER_QUANTITIES),
        ))

    def _make_step(self):
        """The step: the ZOH step x⁺ = Φ x + Γ u and its dissipated work zᵀ W z, z = (q̇, u)
        (docs/model.md §4.1), unrolled over Python floats (a 4×4 matrix product in numpy costs more than
        the step). The angles do not feed back (discretise makes Φ's angle columns exactly (I, 0)), so
        only Φ's speed columns enter; W is symmetric, so each off-diagonal pair is summed once (×2 is
        exact). The batch form (`_run_impl`) runs the same recursion by recursive filters per mode.
        """
        lin, G = self.lin, self.G
        (_, _, p02, p03), (_, _, p12, p13), (_, _, p22, p23), (_, _, p32, p33) = lin.Phi.tolist()
        (g00, g01), (g10, g11), (g20, g21), (g30, g31) = lin.Gam.tolist()
        W = lin.W.tolist()
        w00, w01, w02, w03 = W[0][0], 2.0 * W[0][1], 2.0 * W[0][2], 2.0 * W[0][3]
        w11, w12, w13 = W[1][1], 2.0 * W[1][2], 2.0 * W[1][3]
        w22, w23, w33 = W[2][2], 2.0 * W[2][3], W[3][3]
        # stored energy ½ (k_ss ω_S² + 2 k_sc ω_S ω_C + k_cc ω_C²) (`stored_energy_j`; ×½ is exact)
        e_ss, e_sc, e_cc = 0.5 * self.kinetic[0], self.kinetic[1], 0.5 * self.kinetic[2]
        g = G.ravel().tolist()
        k = -self.params.friction.viscous_n_s_m * self.geo.n_teeth
        n_rollers = self.geo.n_rollers

        def slip_speed(w_s: float, w_c: float, aux=None) -> float:
            v0, v1, v2 = g[0] * w_s + g[1] * w_c, g[2] * w_s + g[3] * w_c, g[4] * w_s + g[5] * w_c
            return math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)

        def internal(w_s: float, w_c: float, aux=None) -> np.ndarray:
            """`_internal` of one step from plain floats (one row broadcast into the rollers' block:
            half the cost of converting the repeated tuple, a third of np.tile's)."""
            v0, v1, v2 = g[0] * w_s + g[1] * w_c, g[2] * w_s + g[3] * w_c, g[4] * w_s + g[5] * w_c
            block = np.empty((n_rollers, 6))
            block[:] = (v0, v1, v2, k * v0, k * v1, k * v2)
            return block.ravel()

        finish = self.finisher(slip_speed, internal)
        contact_step = self._backward_euler(finish, e_ss, e_sc, e_cc)
        l_stable, contact = self.reverses_l_stable, self._contact

        def step(x, u0: float, u1: float):
            if l_stable and contact[0]:
                return contact_step(x, u0, u1)
            w0, w1 = x[2], x[4]
            n2 = p22 * w0 + p23 * w1 + g20 * u0 + g21 * u1
            n3 = p32 * w0 + p33 * w1 + g30 * u0 + g31 * u1
            diss = (w0 * (w00 * w0 + w01 * w1 + w02 * u0 + w03 * u1) + w1 * (w11 * w1 + w12 * u0 + w13 * u1)
                    + u0 * (w22 * u0 + w23 * u1) + u1 * w33 * u1)
            return finish(x, x[1] + p02 * w0 + p03 * w1 + g00 * u0 + g01 * u1, n2,
                          x[3] + p12 * w0 + p13 * w1 + g10 * u0 + g11 * u1, n3, u0, u1, diss,
                          e_ss * n2 * n2 + e_sc * n2 * n3 + e_cc * n3 * n3)
        return step

    def set_contact(self, on: bool) -> None:
        self._contact[0] = bool(on)

    def _backward_euler(self, finish, e_ss: float, e_sc: float, e_cc: float):
        """A contact's trial step at steps too long for it (`reverses_l_stable`): backward Euler,
        (M + hC) q̇₁ = M q̇₀ + h B u, Δq = h q̇₁. Its books close exactly with the dissipation
        h q̇₁ᵀ C q̇₁ + ½ Δq̇ᵀ M Δq̇ (the friction's, and the scheme's own numerical loss, ≥ 0), from
        ½ q̇₁ᵀMq̇₁ − ½ q̇₀ᵀMq̇₀ = q̇₁ᵀ M Δq̇ − ½ Δq̇ᵀ M Δq̇ with M Δq̇ = h (B u − C q̇₁)."""
        h, M, C = self.dt_s, self.M, self.C
        inv = np.linalg.inv(M + h * C)
        (a00, a01), (a10, a11) = (inv @ M).tolist()
        (b00, b01), (b10, b11) = (h * inv @ self.B).tolist()
        (c00, c01), (_, c11) = (h * C).tolist()
        (m00, m01), (_, m11) = (0.5 * M).tolist()

        def step(x, u0: float, u1: float):
            w0, w1 = x[2], x[4]
            n2 = a00 * w0 + a01 * w1 + b00 * u0 + b01 * u1
            n3 = a10 * w0 + a11 * w1 + b10 * u0 + b11 * u1
            d2, d3 = n2 - w0, n3 - w1
            diss = (n2 * (c00 * n2 + 2.0 * c01 * n3) + c11 * n3 * n3
                    + d2 * (m00 * d2 + 2.0 * m01 * d3) + m11 * d3 * d3)
            return finish(x, x[1] + h * n2, n2, x[3] + h * n3, n3, u0, u1, diss,
                          e_ss * n2 * n2 + e_sc * n2 * n3 + e_cc * n3 * n3)
        return step

    def _internal(self, v_s: np.ndarray) -> np.ndarray:
        """Per roller: sliding velocity and the friction force the screw exerts on it (all N_T teeth).

        `v_s` is 3 × steps (or 3 for one step); identical rollers repeat the row.
        """
        f = -self.params.friction.viscous_n_s_m * self.geo.n_teeth * v_s
        rows = np.concatenate([v_s, f]).T
        return np.tile(rows, (1, self.geo.n_rollers)) if rows.ndim == 2 else np.tile(rows, self.geo.n_rollers)

    def _run_impl(self, state: State, torque_nm: np.ndarray, load_n: np.ndarray) -> Trajectory:
        """The batch form of the step: the same ZOH recursion, evaluated by recursive filters per mode."""
        from scipy.signal import lfilter  # scipy where it is used: `import prsm_sim` stays quick without it

        tau, f, n, lin = torque_nm, load_n, len(torque_nm), self.lin
        u = np.vstack([tau, f])  # 2 × n
        q0 = np.array([state.screw_angle_rad, state.carrier_angle_rad])
        w0 = np.array([state.screw_speed_rad_s, state.carrier_speed_rad_s])
        V, lam = lin.speed_modes, lin.speed_eigvals
        Vi = np.linalg.inv(V)
        drive = Vi @ (lin.Gam[2:] @ u)  # modal input, 2 × n
        z0 = Vi @ w0
        modes = np.empty((2, n))
        for i in range(2):
            # z[k+1] = λ z[k] + drive[k]; filter output is z[1..n]
            modes[i], _ = lfilter([1.0], [1.0, -lam[i]], drive[i], zi=[lam[i] * z0[i]])
        w = V @ modes  # speeds at the end of each step
        w_prev = np.hstack([w0[:, None], w[:, :-1]])
        dq = lin.Phi[:2, 2:] @ w_prev + lin.Gam[:2] @ u
        q = q0[:, None] + np.cumsum(dq, axis=1)
        zz = np.vstack([w_prev, u])
        diss = np.einsum("ik,ij,jk->k", zz, lin.W, zz)
        p, h = self.geo.lead_per_rad_m, self.dt_s
        v_s = self.G @ w  # 3 × n
        final = State(screw_angle_rad=q[0, -1] if n else q0[0], screw_speed_rad_s=w[0, -1] if n else w0[0],
                      carrier_angle_rad=q[1, -1] if n else q0[1], carrier_speed_rad_s=w[1, -1] if n else w0[1])
        return trajectory_from_columns(
            state, final, self.total_stored_energy_j(state), dt_s=h, gear_ratio=self.geo.gear_ratio,
            layout=self.layout, internal=self._internal(v_s), torque_nm=tau, load_n=f, th_s=q[0], w_s=w[0], th_c=q[1],
            w_c=w[1], dtheta=dq[0], nut_x=p * q[0], nut_v=p * w[0],
            nut_force=f + self.params.mass.moved_mass_kg * p * np.diff(w[0], prepend=w0[0]) / h,
            slip=np.linalg.norm(v_s, axis=0), work_out_j=f * p * dq[0], dissipated_j=diss,
            stored_j=self.stored_energy_j(w[0], w[1]))


class SteadyState(TypedDict):
    """`steady_state`'s result, a dict by these keys (speeds rad/s, torque N·m, force N, velocities m/s, the
    entries of C (seed eq. 39) N·m·s, and the friction group's `contact_evaluation` it was found with)."""

    screw_speed_rad_s: float
    carrier_speed_rad_s: float
    speed_ratio_screw_over_carrier: float
    carrier_over_screw: float
    torque_nm: float
    load_force_n: float
    nut_velocity_m_s: float
    slip_speed_m_s: float
    efficiency: float
    steady_a_nm_s: float
    steady_b_nm_s: float
    steady_c_nm_s: float
    steady_d_nm_s: float
    contact_evaluation: str


def steady_state(params: Params, *, screw_speed_rad_s: float | None = None, torque_nm: float | None = None,
                 load_n: float | None = None) -> SteadyState:
    """Closed-form steady state of `jones2016` (Jones 2016 eqs. 37–41 structure).

    C q̇ = B (τ, F): the carrier row gives the speed ratio (independent of c, F, τ, docs/model.md
    §4.1); the screw row gives the torque for a speed, or the speed for a torque. Exactly one
    of `screw_speed_rad_s` and `torque_nm` may be given; default: the preset's screw speed.
    """
    if screw_speed_rad_s is not None and torque_nm is not None:
        raise InputError(f"screw_speed_rad_s = {screw_speed_rad_s!r}, torque_nm = {torque_nm!r}: give one of them, not both")
    Jones2016.check_params(params)
    geo, fr = params.geometry, params.friction
    f = params.loads.nut_load_n if load_n is None else load_n
    contact = contact_for(geo, "screw", fr.contact_evaluation)
    G = contact.sliding_matrix(geo)
    n_contacts = geo.n_rollers * geo.n_teeth
    C = fr.viscous_n_s_m * n_contacts * (G.T @ G)
    a_ss, b_ss, c_ss, d_ss = C[0, 0], C[0, 1], C[1, 0], C[1, 1]  # seed eq. (39): A ω_S + B ω_C = τ − F L/2π
    p = geo.lead_per_rad_m
    if torque_nm is None:
        w_s = params.loads.screw_speed_rad_s if screw_speed_rad_s is None else screw_speed_rad_s
        w_c = -c_ss / d_ss * w_s
        torque_nm = a_ss * w_s + b_ss * w_c + f * p
    else:
        # seed eq. (40)
        det = a_ss * d_ss - b_ss * c_ss
        w_s = d_ss * (torque_nm - f * p) / det
        w_c = -c_ss * (torque_nm - f * p) / det
    v_s = G @ np.array([w_s, w_c])
    p_in, p_out = torque_nm * w_s, f * p * w_s
    return {
        "screw_speed_rad_s": float(w_s),
        "carrier_speed_rad_s": float(w_c),
        "speed_ratio_screw_over_carrier": float(-d_ss / c_ss),
        "carrier_over_screw": float(-c_ss / d_ss),
        "torque_nm": float(torque_nm),
        "load_force_n": float(f),
        "nut_velocity_m_s": float(p * w_s),
        "slip_speed_m_s": float(np.linalg.norm(v_s)),
        "efficiency": float(p_out / p_in) if p_in > 0 and p_out > 0 else math.nan,
        "steady_a_nm_s": float(a_ss), "steady_b_nm_s": float(b_ss),
        "steady_c_nm_s": float(c_ss), "steady_d_nm_s": float(d_ss),
        "contact_evaluation": fr.contact_evaluation,
    }
