"""Torques solved implicitly on a screw model's own step: the inertia a torque sees, the model's local
linear response to a torque, and a compliant coupling's torque made consistent with the model.

The actuator solves its dry friction (brake, jams), end stops and compliant coupling on these,
so each stays stable at the step whatever the screw model (`actuator.Actuator._advance`).
"""

from __future__ import annotations

import math

from prsm_sim.errors import ModelError
from prsm_sim.stepping.model import Model
from prsm_sim.stepping.packed import PackedOutputs
from prsm_sim.stepping.records import State


PROBE_TORQUE_NM = 10.0  # the inertia probe's torque step, N·m: well above an unpreloaded screw's no-load torque
PROBE_RAISES = 24  # doublings of the probe torque at most (10 N·m × 2²⁴ ≈ 1.7e8 N·m)


def probe_inertia(model: Model, h_s: float) -> float:
    """Screw-side inertia seen by a torque over one sub-step, J = h / (∂ω1/∂τ), probed from rest.

    Exact for the linear models; for `fu2018` its value at rest. Used only to solve the
    implicit stop, coupling and dry-friction torques; the step itself is the model's. The two probe
    torques must both lie well above the no-load torque (the seals and idle flanks of docs/model.md §4.5
    hold a screw at rest up to the torque it runs with, and take a constant torque once it turns), so their
    difference sees the inertia alone: from PROBE_TORQUE_NM, they are doubled until a quarter of the smaller
    turns the screw (a heavily preloaded nut holds tens of N·m; an unpreloaded one a few tenths).

    Raises
    ------
    ModelError
        The screw does not turn from rest under any probe torque up to PROBE_TORQUE_NM · 2^PROBE_RAISES.
    """
    s0 = model.initial_state(0.0)
    tau = PROBE_TORQUE_NM
    for _ in range(PROBE_RAISES):
        if model.step(s0, 0.25 * tau, 0.0)[0].screw_speed_rad_s > 0.0:
            break
        tau *= 2.0
    else:
        raise ModelError(f"the screw does not turn from rest under {0.25 * tau:.3g} N·m: no inertia to probe "
                         f"(model {model.name}; its no-load torque holds it)")
    w2 = model.step(s0, 2.0 * tau, 0.0)[0].screw_speed_rad_s
    w1 = model.step(s0, tau, 0.0)[0].screw_speed_rad_s
    return h_s * tau / (w2 - w1)


def linear_response(model: Model, x: tuple, tau_nm: float, load_n: float, h_s: float,
                    inertia_kgm2: float) -> tuple[float, float, float, float]:
    """End speed ω1 and angle θ1 at (τ, F) and their sensitivities to τ, by two steps from the packed
    state `x` (`Model.pack_state`).

    Returns (ω1, ∂ω1/∂τ, θ1, ∂θ1/∂τ); a load acts as τ = −(L/2π) F. `inertia_kgm2`: the probed
    inertia (`probe_inertia`), whose response stands in where the model's is stuck. Exact for the linear
    models; for fu2018 the local slope (its effective inertia moves with the friction regime).
    """
    step = model.step_from
    a = step(x, tau_nm, load_n)  # a packed record: θ_S at item 1, ω_S at 2
    d = 1e-3 * max(1.0, abs(tau_nm))
    b = step(x, tau_nm + d, load_n)
    w_a, th_a = a[2], a[1]
    s_w = (b[2] - w_a) / d
    s_th = (b[1] - th_a) / d
    if not (math.isfinite(s_w) and s_w > 0.0 and math.isfinite(s_th) and s_th > 0.0):
        s_w, s_th = h_s / inertia_kgm2, 0.5 * h_s**2 / inertia_kgm2  # a stuck response: the probed inertia's
    return w_a, s_w, th_a, s_th


def coupling_torque(model: Model, x: tuple, tau_st: float, load_n: float, th_r_free: float, tau_d: float,
                    phi0: float, k: float, c: float, th_sfree: float, s_th: float, h_s: float,
                    rotor_inertia_kgm2: float) -> tuple[float, State, PackedOutputs]:
    """The compliant coupling's torque held over the step, solved to consistency with the screw model.

    τ_c = k (φ0 + φ1)/2 + c (φ1 − φ0)/h, φ1 = θ_r1(τ_c) − θ_s1(τ_c): the motor at constant
    acceleration, the screw by the model itself. The residual is strictly increasing in τ_c
    (the screw turns further, the motor less, the more torque the coupling carries), so the
    root is unique: Newton from the linear estimate, then secant steps, to 1e-12 of the
    torque scale (one model step for the linear models). Its work is then ΔV + c Δφ²/h:
    the ledger stays exact and the scheme cannot gain energy, so a stiff coupling stays
    stable at the step (trapezoidal rule). `th_r_free`: the rotor's end angle with no coupling torque;
    `h_s`, `rotor_inertia_kgm2`: the sub-step and the rotor's inertia on the screw side. `x`: the screw's
    state packed (`Model.pack_state`). Returns (τ_c, the screw's next state, the step's packed record).
    """
    h, jr = h_s, rotor_inertia_kgm2
    G, H = 0.5 * k + c / h, 0.5 * k - c / h
    q_r = 0.5 * h * h / jr
    step = model.step_from

    def residual(tau):
        rec = step(x, tau + tau_st, load_n)
        phi1 = th_r_free + q_r * (tau_d - tau) - rec[1]  # θ_S at the step's end
        return tau - (G * phi1 + H * phi0), rec

    slope = 1.0 + G * (q_r + s_th)
    t0 = (G * (th_r_free + q_r * tau_d - th_sfree) + H * phi0) / slope  # the linear solution
    r0, rec = residual(t0)
    scale = 1e-12 * max(1.0, abs(t0), abs(tau_d))
    if abs(r0) <= scale:
        return t0, model.unpack_state(rec), rec
    t1 = t0 - r0 / slope
    for _ in range(30):
        r1, rec = residual(t1)
        if abs(r1) <= scale or r1 == r0:
            break
        t0, t1, r0 = t1, t1 - r1 * (t1 - t0) / (r1 - r0), r1
    return t1, model.unpack_state(rec), rec
