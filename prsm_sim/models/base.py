"""The one stepping contract every model shares, and the bookkeeping they have in common.

A model is built from parameters and a fixed step `dt_s`; `step(state, torque, load)`
returns the next state and the step's outputs and never mutates anything (SciPy's
OdeSolver habit: the counters live in `Simulator`). `run` advances through input arrays and
returns a columnar `Trajectory`; models with a faster batch form override it.

Energy guard (every model): each step's port work (screw torque × screw angle, load × nut
travel), its dissipation and the change of the stored energy (`Model.stored_energy_j`) must
balance. The cumulative residual and the energy that has flowed (∫|P_in| dt) travel in the
state; `energy_fault` flags a run whose books do not close (|residual| > ENERGY_GUARD_REL of
the flow once the flow exceeds ENERGY_GUARD_MIN_FLOW_J). A few flops per step; stepping goes on
(the caller decides what a fault means).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from prsm_sim.errors import InputError, ParamError
from prsm_sim.outputs import (OUTPUT_FIELDS, InternalLayout, Outputs, PackedConstants, PackedOutputs, State,
                              Trajectory)
from prsm_sim.params import Params


ENERGY_GUARD_REL = 1e-3  # residual allowed, as a fraction of the energy that has flowed
ENERGY_GUARD_MIN_FLOW_J = 1.0  # below this flow the ratio is not judged (start-up, standstill)


def energy_fault(flow_j, residual_j):
    """The guard's verdict (scalar or array): |residual| > ENERGY_GUARD_REL · flow once flow > 1 J."""
    return (flow_j > ENERGY_GUARD_MIN_FLOW_J) & (abs(residual_j) > ENERGY_GUARD_REL * flow_j)


def energy_guard_summary(columns) -> dict:
    """The energy guard over a run (a Trajectory or its columns): final residual, flow, their ratio,
    whether and when the guard tripped (`energy_fault` first 1.0)."""
    res, flow, fault = columns["energy_residual_j"], columns["energy_flow_j"], columns["energy_fault"]
    hit = np.flatnonzero(fault > 0.0)
    return {"fault": bool(hit.size), "first_fault_time_s": float(columns["time_s"][hit[0]]) if hit.size else None,
            "residual_j": float(res[-1]), "flow_j": float(flow[-1]),
            "relative_residual": float(res[-1] / flow[-1]) if flow[-1] > 0 else None,
            "limit": ENERGY_GUARD_REL}


class Model:
    """Base class: subclasses set `name`, `layout`, `kinetic` and implement `_advance`."""

    name = "base"
    compiled_kernel = False  # True: the constructor takes kernel="compiled"|"reference" (`load_kernels`)
    # kinetic energy T = ½ (k_ss ω_S² + 2 k_sc ω_S ω_C + k_cc ω_C²): the model's mass matrix in
    # (ω_S, ω_C), set by every subclass; `stored_energy_j` uses it (models with springs add theirs)
    kinetic: tuple[float, float, float] = (math.nan, math.nan, math.nan)

    @classmethod
    def check_params(cls, params: Params) -> None:
        """Refuse (ParamError, one line) a parameter combination this model cannot honour."""

    def __init__(self, params: Params, dt_s: float) -> None:
        if not (isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and 0 < dt_s <= 0.1):
            raise ParamError(f"dt_s = {dt_s!r}: the step must be a finite number in (0, 0.1] s")
        self.params = params
        self.geo = params.geometry
        self.dt_s = float(dt_s)
        self.layout = InternalLayout(blocks=())

    def initial_state(self, nut_position_m: float = 0.0) -> State:
        """At rest, nut at `nut_position_m` (x_nut = (L/2π) θ_S fixes the screw angle)."""
        return State(screw_angle_rad=nut_position_m / self.geo.lead_per_rad_m)

    def step(self, state: State, torque_nm: float, load_n: float) -> tuple[State, Outputs]:
        """Advance one fixed step with screw torque and nut load held over the step."""
        return self._advance(state, float(torque_nm), float(load_n))

    def _advance(self, state: State, torque_nm: float, load_n: float) -> tuple[State, Outputs]:
        raise NotImplementedError

    def stored_energy_j(self, screw_speed_rad_s, carrier_speed_rad_s):
        """Energy the model stores at these speeds, J (scalars or arrays): kinetic here; a model
        with potential energy overrides this (and must then be given the state it needs)."""
        kss, ksc, kcc = self.kinetic
        ws, wc = screw_speed_rad_s, carrier_speed_rad_s
        return 0.5 * (kss * ws * ws + 2.0 * ksc * ws * wc + kcc * wc * wc)

    def total_stored_energy_j(self, state: State) -> float:
        """Energy the model stores in `state`, J (`stored_energy_j` at its speeds; `elastic` adds the
        nut and the chain, which need more of the state)."""
        return self.stored_energy_j(state.screw_speed_rad_s, state.carrier_speed_rad_s)

    # -- per-step fast path (optional) ------------------------------------------------------
    # A model that sets `packed = True` provides `advance_packed(x, torque, load) -> PackedOutputs`
    # on the packed state x = (time, θ_S, ω_S, θ_C, ω_C, W_in, W_out, W_diss, energy flow, energy
    # residual, stored energy, extra) (`pack_state`; extra: the values of the State fields named in
    # `extra_state_fields`, the model's own memory: fu2018's flank sign, lagged forces and solver
    # memory), ending in the function `packed_finisher` makes. The record it returns is the step's
    # outputs and, in its first PACKED_STATE_SIZE items, the next packed state: `Simulator.step`
    # keeps it as the state between steps. The ledger and the energy guard (accumulators and
    # verdict) run every step as in `finish_step`; of the other outputs the record holds what the
    # node reads every step and derives the rest when read (outputs.PackedOutputs) with the model's
    # own code. Results match `step` to rounding (tests/test_step_paths.py). The models build these
    # functions as closures: a step of a few dozen flops costs less than the attribute look-ups of a
    # method, and a model with a costlier step saves the State and Outputs it no longer builds.
    packed = False
    extra_state_fields: tuple[str, ...] = ()

    def pack_state(self, s: State) -> tuple:
        return (s.time_s, s.screw_angle_rad, s.screw_speed_rad_s, s.carrier_angle_rad, s.carrier_speed_rad_s,
                s.work_in_j, s.work_out_j, s.dissipated_j, s.energy_flow_j, s.energy_residual_j,
                self.total_stored_energy_j(s), tuple(getattr(s, f) for f in self.extra_state_fields))

    def unpack_state(self, x: tuple) -> State:
        return State(time_s=x[0], screw_angle_rad=x[1], screw_speed_rad_s=x[2], carrier_angle_rad=x[3],
                     carrier_speed_rad_s=x[4], work_in_j=x[5], work_out_j=x[6], dissipated_j=x[7],
                     energy_flow_j=x[8], energy_residual_j=x[9], **dict(zip(self.extra_state_fields, x[11])))

    def advance_packed(self, x: tuple, torque_nm: float, load_n: float) -> PackedOutputs:
        raise NotImplementedError

    def packed_finisher(self, slip_speed, internal):
        """`finish_step` for the packed path: a function
        ``finish(x, θ_S, ω_S, θ_C, ω_C, torque, load, dissipated, stored, extra=(), aux=None,
        nut_force=None, nut=None) -> PackedOutputs``
        from the state before the step and the model's results at its end (stored: the stored
        energy there, `stored_energy_j`; extra: the model's own next state, `extra_state_fields`).
        The same ledger, energy guard (accumulators and verdict) and nut force as `finish_step`
        (or the model's `nut_force`, as `finish_step` takes it), and the nut's position and
        velocity (what the node reads every step): (L/2π) θ_S and its rate, or for a nut with an
        axial state of its own (`elastic`) `nut` = (x_N, v_N, the load's work over the step). The
        record derives the other outputs when read, with `slip_speed` and `internal` (functions of
        ω_S, ω_C at the step's end and the step's `aux`) for the model's own.
        """
        h, p = self.dt_s, self.geo.lead_per_rad_m
        mp = self.params.mass.moved_mass_kg * p
        k = PackedConstants(h, self.geo.gear_ratio, slip_speed, internal, efficiency)
        min_flow, rel = ENERGY_GUARD_MIN_FLOW_J, ENERGY_GUARD_REL

        def finish(x, th_s, w_s, th_c, w_c, torque_nm, load_n, dissipated_j, stored_j, extra=(), aux=None,
                   nut_force=None, nut=None):
            dtheta = th_s - x[1]
            w_in = torque_nm * dtheta
            if nut is None:  # the nut rides the threads: x_nut = (L/2π) θ_S
                w_out = load_n * p * dtheta
                nut_x, nut_v = p * th_s, p * w_s
            else:
                nut_x, nut_v, w_out = nut
            if nut_force is None:
                nut_force = load_n + mp * (w_s - x[2]) / h
            flow = x[8] + abs(w_in)
            residual = x[9] + (w_in - w_out - (stored_j - x[10]) - dissipated_j)
            return PackedOutputs((
                x[0] + h, th_s, w_s, th_c, w_c, x[5] + w_in, x[6] + w_out, x[7] + dissipated_j, flow, residual,
                stored_j, extra, torque_nm, load_n, dissipated_j, w_in, w_out, nut_force, nut_x, nut_v,
                1.0 if flow > min_flow and abs(residual) > rel * flow else 0.0,  # energy_fault's verdict
                k, aux))
        return finish

    def run(self, state: State, torque_nm: np.ndarray, load_n: np.ndarray) -> Trajectory:
        """Advance len(torque_nm) steps; input k is held over step k, output k is at its end."""
        torque_nm, load_n = _inputs(torque_nm, load_n)
        if self.packed:  # the packed step; columns from its records
            x, outs = self.pack_state(state), []
            for tau, f in zip(torque_nm.tolist(), load_n.tolist()):
                x = self.advance_packed(x, tau, f)
                outs.append(x)
            n = len(outs)
            table = np.array([o.scalar_values() for o in outs], dtype=float).reshape(n, len(OUTPUT_FIELDS))
            cols = {name: table[:, i].copy() for i, (name, _) in enumerate(OUTPUT_FIELDS)}
            size = self.layout.size
            return Trajectory(columns=cols, layout=self.layout, final_state=self.unpack_state(x),
                              internal=lambda: np.array([o.internal for o in outs], dtype=float).reshape(n, size))
        rows = []
        for tau, f in zip(torque_nm.tolist(), load_n.tolist()):
            state, out = self._advance(state, tau, f)
            rows.append(out)
        return trajectory_from_rows(rows, self.layout, state)

    # -- shared bookkeeping -------------------------------------------------------------
    def finish_step(self, before: State, after: State, torque_nm: float, load_n: float, *,
                    dissipated_j: float, slip_speed_m_s: float, internal: np.ndarray,
                    nut_force_n: float | None = None) -> tuple[State, Outputs]:
        """Energy ledger and the common outputs from the state before and after a step.

        Work over the step is exact for inputs held over it: W_in = τ Δθ_S, W_out = F (L/2π) Δθ_S.
        """
        h = self.dt_s
        p = self.geo.lead_per_rad_m
        dtheta = after.screw_angle_rad - before.screw_angle_rad
        w_in = torque_nm * dtheta
        w_out = load_n * p * dtheta
        e0 = self.stored_energy_j(before.screw_speed_rad_s, before.carrier_speed_rad_s)
        e1 = self.stored_energy_j(after.screw_speed_rad_s, after.carrier_speed_rad_s)
        flow = before.energy_flow_j + abs(w_in)
        residual = before.energy_residual_j + (w_in - w_out - (e1 - e0) - dissipated_j)
        state = replace(after, time_s=before.time_s + h, work_in_j=before.work_in_j + w_in,
                        work_out_j=before.work_out_j + w_out, dissipated_j=before.dissipated_j + dissipated_j,
                        energy_flow_j=flow, energy_residual_j=residual)
        if nut_force_n is None:
            m = self.params.mass.moved_mass_kg
            nut_force_n = load_n + m * p * (after.screw_speed_rad_s - before.screw_speed_rad_s) / h
        p_in, p_out = w_in / h, w_out / h
        w_s, w_c = state.screw_speed_rad_s, state.carrier_speed_rad_s
        out = Outputs(
            time_s=state.time_s,
            screw_angle_rad=state.screw_angle_rad,
            screw_speed_rad_s=w_s,
            screw_torque_nm=torque_nm,
            carrier_angle_rad=state.carrier_angle_rad,
            carrier_speed_rad_s=w_c,
            roller_spin_rad_s=-self.geo.gear_ratio * w_c,
            nut_position_m=p * state.screw_angle_rad,
            nut_velocity_m_s=p * w_s,
            nut_force_n=nut_force_n,
            load_force_n=load_n,
            slip_speed_m_s=slip_speed_m_s,
            power_in_w=p_in,
            power_out_w=p_out,
            power_dissipated_w=dissipated_j / h,
            efficiency=efficiency(p_out, dissipated_j / h),
            speed_ratio=w_c / w_s if w_s != 0.0 else math.nan,
            stored_energy_j=e1,
            energy_flow_j=flow,
            energy_residual_j=residual,
            energy_fault=1.0 if energy_fault(flow, residual) else 0.0,
            internal=internal,
        )
        return state, out


KERNELS = ("compiled", "reference")


def check_kernel(kernel) -> None:
    """ParamError (one line: field, value, allowed values) unless `kernel` is one of KERNELS."""
    if kernel not in KERNELS:
        raise ParamError(f"kernel = {kernel!r}: allowed values are {', '.join(map(repr, KERNELS))}")


def load_kernels(kernel: str):
    """The compiled step functions (`models._kernels`, numba) for ``kernel="compiled"``, None for
    ``"reference"`` (the pure-Python path, the specification the compiled one is tested against).

    numba is imported here, on first use, so that `import prsm_sim` stays light; compiled code is
    cached on disk (the first run of a fresh install compiles once).
    """
    check_kernel(kernel)
    if kernel == "reference":
        return None
    from prsm_sim.models import _kernels
    return _kernels


def efficiency(power_out_w: float, power_dissipated_w: float) -> float:
    """Efficiency of the mechanism itself, from the power through it (inertia excluded).

    Forward (the screw delivers power to the load, P_out > 0): P_out / (P_out + P_diss).
    Backward (the load drives the screw, P_out < 0): (|P_out| − P_diss) / |P_out|, which is ≤ 0
    for a screw that must be driven even when back-driven (self-locking). NaN when no power
    reaches the load. At constant speed these equal the port ratios P_out/P_in and P_in/P_out;
    unlike the port ratios they never exceed 1 while the rotor's kinetic energy changes.
    """
    if power_out_w > 0.0:
        return power_out_w / (power_out_w + power_dissipated_w)
    if power_out_w < 0.0:
        return 1.0 - power_dissipated_w / -power_out_w
    return math.nan


def _inputs(torque_nm, load_n) -> tuple[np.ndarray, np.ndarray]:
    tau = np.asarray(torque_nm, dtype=float).ravel()
    f = np.broadcast_to(np.asarray(load_n, dtype=float), tau.shape).ravel()
    for name, arr in (("torque_nm", tau), ("load_n", f)):
        if not np.all(np.isfinite(arr)):
            k = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise InputError(f"{name}[{k}] = {arr[k]!r}: inputs must be finite numbers")
    return tau, f


def trajectory_from_rows(rows: list[Outputs], layout: InternalLayout, final: State) -> Trajectory:
    cols = {n: np.fromiter((getattr(r, n) for r in rows), dtype=float, count=len(rows)) for n, _ in OUTPUT_FIELDS}
    internal = np.array([r.internal for r in rows], dtype=float).reshape(len(rows), layout.size)
    return Trajectory(columns=cols, internal=internal, layout=layout, final_state=final)


def columns_to_trajectory(model: Model, tau: np.ndarray, load: np.ndarray, cols: np.ndarray, internal: np.ndarray,
                          final: State, initial: State) -> Trajectory:
    """The common output columns of a batch run, vectorised (the batch twin of `finish_step`).

    `cols` rows: ω_S, ω_C, θ_S, θ_C at the end of each step, Δθ_S over it, dissipated work,
    slip speed, nut force (NaN: derive it from the load and the moved mass's acceleration).
    `initial` is the state the run started from; the energy guard's accumulators of `final`
    are filled here.
    """
    h = model.dt_s
    geo = model.geo
    p = geo.lead_per_rad_m
    n = len(tau)
    w_s, w_c, th_s, th_c, dth, diss, slip, nut_force = (cols[:, i] for i in range(8))
    w_prev = np.concatenate([[initial.screw_speed_rad_s], w_s[:-1]])
    w_in, w_out = tau * dth, load * p * dth
    stored = model.stored_energy_j(w_s, w_c)
    e0 = model.stored_energy_j(initial.screw_speed_rad_s, initial.carrier_speed_rad_s)
    flow = initial.energy_flow_j + np.cumsum(np.abs(w_in))
    # cumulative sums of the step residuals; Δstored telescopes to stored − e0
    residual = initial.energy_residual_j + np.cumsum(w_in - w_out - diss) - (stored - e0)
    if n:
        final = replace(final, energy_flow_j=float(flow[-1]), energy_residual_j=float(residual[-1]))
    if np.isnan(nut_force).any():
        nut_force = np.where(np.isnan(nut_force), load + model.params.mass.moved_mass_kg * p * (w_s - w_prev) / h,
                             nut_force)
    columns = output_columns(model, tau, load, final.time_s, th_s=th_s, w_s=w_s, th_c=th_c, w_c=w_c,
                             nut_x=p * th_s, nut_v=p * w_s, nut_force=nut_force, slip=slip, w_in=w_in, w_out=w_out,
                             diss=diss, stored=stored, flow=flow, residual=residual)
    return Trajectory(columns=columns, internal=internal, layout=model.layout, final_state=final)


def output_columns(model: Model, tau: np.ndarray, load: np.ndarray, end_time_s: float, *, th_s, w_s, th_c, w_c,
                   nut_x, nut_v, nut_force, slip, w_in, w_out, diss, stored, flow, residual) -> dict:
    """Every scalar output column of a batch run, in `OUTPUT_FIELDS` order, from its per-step
    kinematics, works (J over each step) and ledger: the powers, efficiency (`efficiency`'s rule,
    vectorised), speed ratio, time and the energy guard's verdict are derived here."""
    h = model.dt_s
    with np.errstate(divide="ignore", invalid="ignore"):
        p_out, p_d = w_out / h, diss / h
        eff = np.where(p_out > 0, p_out / (p_out + p_d), np.where(p_out < 0, 1.0 - p_d / -p_out, np.nan))
        ratio = np.where(w_s != 0, w_c / w_s, np.nan)
    columns = {
        "time_s": end_time_s - h * np.arange(len(tau) - 1, -1, -1),
        "screw_angle_rad": th_s, "screw_speed_rad_s": w_s, "screw_torque_nm": tau.copy(),
        "carrier_angle_rad": th_c, "carrier_speed_rad_s": w_c, "roller_spin_rad_s": -model.geo.gear_ratio * w_c,
        "nut_position_m": nut_x, "nut_velocity_m_s": nut_v, "nut_force_n": nut_force,
        "load_force_n": load.copy(), "slip_speed_m_s": slip, "power_in_w": w_in / h, "power_out_w": p_out,
        "power_dissipated_w": p_d, "efficiency": eff, "speed_ratio": ratio,
        "stored_energy_j": stored, "energy_flow_j": flow, "energy_residual_j": residual,
        "energy_fault": energy_fault(flow, residual).astype(float),
    }
    return {name: np.ascontiguousarray(columns[name]) for name, _ in OUTPUT_FIELDS}
