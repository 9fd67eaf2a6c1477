"""The energy ledger, its guard and the mechanism's efficiency: each rule written once.

Every step's port work (screw torque × screw angle, load × nut travel), its dissipation and the
change of the stored energy must balance (docs/model.md §4, "The energy ledger"). `ledger_step`
is that balance and the guard's verdict for one step; it takes floats (the per-step path,
`stepping.packed.make_finisher`) or arrays of per-step values (the batch path, `ledger_columns`,
which accumulates it with cumulative sums in the per-step path's order). `fu2018`'s compiled
per-step record (`models.kernels.step_record`) runs the same source compiled.

Energy guard (every model): the cumulative residual and the energy that has flowed through the
mechanism (each step's larger port work: the screw's while it drives, the load's while it drives the
screw back) travel in the state; `energy_fault` flags a run whose books do not close (|residual| >
ENERGY_GUARD_REL of the flow once the flow exceeds ENERGY_GUARD_MIN_FLOW_J). A few flops per step;
stepping goes on (the caller decides what a fault means).
"""

from __future__ import annotations

import math

import numpy as np

ENERGY_GUARD_REL = 1e-3  # residual allowed, as a fraction of the energy that has flowed
ENERGY_GUARD_MIN_FLOW_J = 1.0  # below this flow the ratio is not judged (start-up, standstill)


def ledger_step(flow0_j, residual0_j, torque_nm, dtheta_rad, work_out_j, dissipated_j, stored0_j, stored1_j):
    """One step of the energy ledger and the guard's verdict: (W_in, flow, residual, fault).

    W_in = τ Δθ_S is exact for a torque held over the step; the flow grows by max(|W_in|, |W_out|) (the
    energy enters by the port that does the larger work) and the residual by
    the step's miss W_in − W_out − (E₁ − E₀) − W_diss (zero for books that close); the verdict is
    |residual| > ENERGY_GUARD_REL · flow once the flow exceeds ENERGY_GUARD_MIN_FLOW_J. Floats (the
    per-step path), or arrays of steps element by element (`ledger_columns`: from zero books, the
    increments).
    """
    work_in_j = torque_nm * dtheta_rad
    a, b = abs(work_in_j), abs(work_out_j)
    # max(a, b) to rounding, in arithmetic that runs on floats and arrays alike (and costs less per step
    # than the builtin max)
    flow_j = flow0_j + 0.5 * (a + b + abs(a - b))
    residual_j = residual0_j + (work_in_j - work_out_j - (stored1_j - stored0_j) - dissipated_j)
    fault = (flow_j > ENERGY_GUARD_MIN_FLOW_J) & (abs(residual_j) > ENERGY_GUARD_REL * flow_j)
    return work_in_j, flow_j, residual_j, fault


def energy_fault(flow_j, residual_j):
    """The guard's verdict on books as they stand (scalars or arrays): `ledger_step`'s after a step that
    moves nothing."""
    return ledger_step(flow_j, residual_j, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)[3]


def over_static_rating(load_n, static_rating_n):
    """1.0 where the nut load exceeds the static load rating C₀a (|F| > C₀a), else 0.0 (scalars or arrays):
    past C₀a the threads deform permanently (ISO 76), which no model here represents."""
    return (abs(load_n) > static_rating_n) * 1.0


def energy_guard_summary(columns) -> dict:
    """The energy guard over a run (a Trajectory or its columns): final residual, flow, their ratio,
    whether and when the guard tripped (`energy_fault` first 1.0), and the limit it judges by."""
    res, flow, fault = columns["energy_residual_j"], columns["energy_flow_j"], columns["energy_fault"]
    hit = np.flatnonzero(fault > 0.0)
    return {"fault": bool(hit.size), "first_fault_time_s": float(columns["time_s"][hit[0]]) if hit.size else None,
            "residual_j": float(res[-1]), "flow_j": float(flow[-1]),
            "relative_residual": float(res[-1] / flow[-1]) if flow[-1] > 0 else None,
            "limit": ENERGY_GUARD_REL}


def ledger_columns(flow0_j: float, residual0_j: float, stored0_j: float, torque_nm, dtheta_rad, work_out_j,
                   dissipated_j, stored_j):
    """The ledger of a batch run from its per-step arrays: (W_in per step, flow, residual, fault), the flow and
    residual cumulative from the state the run started in (its flow, residual and stored energy)."""
    stored_before = np.concatenate(([stored0_j], stored_j[:-1]))
    work_in_j, d_flow, miss, _ = ledger_step(0.0, 0.0, torque_nm, dtheta_rad, work_out_j, dissipated_j, stored_before,
                                             stored_j)
    flow_j, residual_j = accumulate(flow0_j, d_flow), accumulate(residual0_j, miss)
    return work_in_j, flow_j, residual_j, energy_fault(flow_j, residual_j)


def accumulate(start: float, increments: np.ndarray) -> np.ndarray:
    """start + increments[0], then + increments[1], …: the running totals, summed in the per-step path's order."""
    return np.cumsum(np.concatenate(([start], increments)))[1:]


EFFICIENCY_MIN_POWER_W = 1e-6  # below this power through the mechanism the efficiency is not defined
EFFICIENCY_MAX_STORED_RATE = 0.05  # nor while the stored energy changes by more than this of the power through


def efficiency(power_in_w: float, power_out_w: float, power_dissipated_w: float) -> float:
    """Efficiency of the mechanism itself, from the power through it; NaN where it is not defined.

    Defined only while power flows through the mechanism (in at one port, out at the other:
    P_in P_out > 0), the power through, min(|P_in|, |P_out|), exceeds EFFICIENCY_MIN_POWER_W, the
    stored energy changes by at most EFFICIENCY_MAX_STORED_RATE of it (|dE/dt| = |P_in − P_out −
    P_diss|, the ledger's balance) and the friction absorbs power (P_diss ≥ 0: a reversal inside
    a step can make its net friction work negative). Then forward (P_out > 0):
    P_out / (P_out + P_diss); backward (P_out < 0): (|P_out| − P_diss) / |P_out|; both lie in
    [0, 1] and equal the port ratios P_out/P_in and P_in/P_out at constant speed. NaN means
    "undefined" (start-up, reversals, standstill, a self-locking screw driven back), not a fault.
    `efficiency_columns` is the same rule over arrays.
    """
    through = min(abs(power_in_w), abs(power_out_w))
    if not (power_in_w * power_out_w > 0.0 and through > EFFICIENCY_MIN_POWER_W and power_dissipated_w >= 0.0
            and abs(power_in_w - power_out_w - power_dissipated_w) <= EFFICIENCY_MAX_STORED_RATE * through):
        return math.nan
    if power_out_w > 0.0:
        return power_out_w / (power_out_w + power_dissipated_w)
    return max(0.0, 1.0 - power_dissipated_w / -power_out_w)  # ≥ 0.95 |P_in|/|P_out| > 0 by the balance


def efficiency_columns(power_in_w: np.ndarray, power_out_w: np.ndarray, power_dissipated_w: np.ndarray) -> np.ndarray:
    """`efficiency` of every step of a run (arrays)."""
    p_in, p_out, p_d = power_in_w, power_out_w, power_dissipated_w
    through = np.minimum(np.abs(p_in), np.abs(p_out))
    ok = ((p_in * p_out > 0) & (through > EFFICIENCY_MIN_POWER_W) & (p_d >= 0)
          & (np.abs(p_in - p_out - p_d) <= EFFICIENCY_MAX_STORED_RATE * through))
    with np.errstate(divide="ignore", invalid="ignore"):
        eff = np.where(p_out > 0, p_out / (p_out + p_d), np.maximum(0.0, 1.0 - p_d / -p_out))
    return np.where(ok, eff, np.nan)


def speed_ratio(screw_speed_rad_s: float, carrier_speed_rad_s: float) -> float:
    """ζ_PS = ω_C / ω_S, NaN at ω_S = 0 (`speed_ratio_columns` over arrays)."""
    return carrier_speed_rad_s / screw_speed_rad_s if screw_speed_rad_s != 0.0 else math.nan


def speed_ratio_columns(screw_speed_rad_s: np.ndarray, carrier_speed_rad_s: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(screw_speed_rad_s != 0, carrier_speed_rad_s / screw_speed_rad_s, np.nan)
