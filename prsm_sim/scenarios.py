"""Named input scenarios for offline runs, and the summary figures a run is judged by.

Open-loop scenarios drive the screw with a torque profile (`step`, `ramp`, `sine`). The
Coulomb-friction models have no steady speed under a constant torque (their loss does not
grow with speed), so the load cases run speed-controlled: a PI loop with feed-forward of
the load torque tracks a screw-speed reference, as a test rig would (`heavy`, `light`,
`sine-motion`, the Fu 2018 cases).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from prsm_sim.errors import InputError, ParamError
from prsm_sim.models.registry import MODELS, model_class
from prsm_sim.models.jones2016 import steady_state
from prsm_sim.params import Params
from prsm_sim.physics.inertia import reflected_inertia
from prsm_sim.simulator import Simulator
from prsm_sim.stepping.ledger import efficiency, energy_guard_summary
from prsm_sim.stepping.trajectory import Trajectory, trajectory_from_rows

if TYPE_CHECKING:  # for the annotation only: the session sits a layer above the scenarios
    from prsm_sim.session import Session

SCENARIOS = ("step", "ramp", "sine", "heavy", "light", "sine-motion")
HEAVY_LOAD_N = 20_000.0  # Fu 2018 heavy-load case, docs/model.md §4.2 ("e.g. 20 kN")
LIGHT_LOAD_N = 100.0  # Fu 2018 light-load case ("e.g. 100 N")


@dataclass(frozen=True)
class ScenarioSpec:
    """What a scenario applies: a torque profile, or a speed reference under PI control."""

    name: str
    load_n: float
    torque_nm: float | None = None  # open-loop amplitude
    speed_rad_s: float | None = None  # closed-loop reference amplitude
    frequency_hz: float = 1.0


def default_spec(params: Params, name: str, *, load_n: float | None = None, torque_nm: float | None = None,
                 speed_rad_s: float | None = None, frequency_hz: float = 1.0) -> ScenarioSpec:
    """A scenario's defaults from the preset's operating point (`params.loads`)."""
    if name not in SCENARIOS:
        raise ParamError(f"unknown scenario {name!r}; known scenarios: {', '.join(SCENARIOS)}")
    if not (math.isfinite(frequency_hz) and frequency_hz > 0):
        raise ParamError(f"frequency_hz = {frequency_hz!r}: must be a finite number > 0")
    speed = params.loads.screw_speed_rad_s if speed_rad_s is None else speed_rad_s
    if name in ("heavy", "light", "sine-motion"):
        load = {"heavy": HEAVY_LOAD_N, "light": LIGHT_LOAD_N}.get(name, params.loads.nut_load_n)
        return ScenarioSpec(name, load if load_n is None else load_n, speed_rad_s=speed, frequency_hz=frequency_hz)
    load = params.loads.nut_load_n if load_n is None else load_n
    if torque_nm is None:
        # the torque that holds the preset's speed in the jones2016 steady state (seed example)
        torque_nm = steady_state(params, screw_speed_rad_s=speed, load_n=load)["torque_nm"]
    return ScenarioSpec(name, load, torque_nm=torque_nm, frequency_hz=frequency_hz)


def torque_profile(spec: ScenarioSpec, n_steps: int, dt_s: float) -> np.ndarray:
    """Open-loop torque held over each step k (t = k dt)."""
    t = dt_s * np.arange(n_steps)
    if spec.name not in ("step", "ramp", "sine"):
        raise InputError(f"scenario {spec.name!r} is speed-controlled, not a torque profile")
    amp = spec.torque_nm
    if amp is None:
        raise InputError(f"scenario {spec.name!r}: torque_nm = None: an open-loop scenario needs its torque (N·m)")
    if spec.name == "step":
        return np.full(n_steps, amp)
    if spec.name == "ramp":
        return amp * t / max(t[-1], dt_s) if n_steps else t
    return amp * np.sin(2 * math.pi * spec.frequency_hz * t)


def speed_reference(spec: ScenarioSpec, t_s: float) -> float:
    """Screw-speed reference: a 0.1 s ramp to the speed (heavy, light) or a sine (motion reversals)."""
    w = spec.speed_rad_s
    if w is None:
        raise InputError(f"scenario {spec.name!r}: speed_rad_s = None: a speed-controlled scenario needs its speed "
                         "(rad/s)")
    if spec.name == "sine-motion":
        return w * math.sin(2 * math.pi * spec.frequency_hz * t_s)
    return w * min(1.0, t_s / 0.1)


def run_scenario(sim: Simulator, spec: ScenarioSpec, duration_s: float, progress=None) -> Trajectory:
    """Run `spec` for `duration_s`; `progress(steps_done)` is called now and then on long runs."""
    n = _steps(duration_s, sim.dt_s)
    if spec.torque_nm is not None:
        tau = torque_profile(spec, n, sim.dt_s)
        parts = []
        for k in range(0, n, CHUNK_STEPS):
            parts.append(sim.run(tau[k:k + CHUNK_STEPS], spec.load_n))
            if progress:
                progress(min(n, k + CHUNK_STEPS))
        return concatenate(parts)
    rows = _closed_loop(sim, spec, n, progress, lambda u: sim.step(u, spec.load_n),
                        lambda: sim.state.screw_speed_rad_s)
    return trajectory_from_rows(rows, sim.layout, sim.state)


def run_session_scenario(session: Session, spec: ScenarioSpec, duration_s: float, progress=None) -> Trajectory:
    """Run `spec` through a `prsm_sim.Session` for `duration_s`, as a controller drives the node.

    One `Session.step(command, load)` per step: the screw torque (the effort interface) goes
    through the session's gate at the step's time (saturated at its limit, counted), and with an
    actuator its drive, sensors, stops, brake and faults act as they do live. The speed-controlled
    scenarios close their loop on what a controller reads: the measured screw speed (the
    actuator's sensors; the state itself on the bare model). `progress` as for `run_scenario`.
    """
    if session.interface != "effort":
        raise InputError(f"command interface = {session.interface!r}: the scenarios command the screw torque "
                         "(effort)")
    n = _steps(duration_s, session.dt_s)
    load = spec.load_n
    if spec.torque_nm is not None:
        rows = []
        for k, u in enumerate(torque_profile(spec, n, session.dt_s).tolist(), 1):
            rows.append(session.step(u, load))
            if progress and (k % CHUNK_STEPS == 0 or k == n):
                progress(k)
    else:
        act = session.actuator
        measured = act.measured if act is not None else (lambda out: out)
        rows = _closed_loop(session, spec, n, progress, lambda u: session.step(u, load),
                            lambda: measured(session.last).screw_speed_rad_s)
    return trajectory_from_rows(rows, session.layout, session.simulator.state)


CHUNK_STEPS = 5000  # steps between progress calls (and per batch run)


def _steps(duration_s: float, dt_s: float) -> int:
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"duration_s = {duration_s!r}: must be a finite number > 0")
    n = int(round(duration_s / dt_s))
    if n < 1:
        raise InputError(f"duration_s = {duration_s} is shorter than one step ({dt_s} s)")
    return n


def _closed_loop(driver, spec: ScenarioSpec, n: int, progress, step, speed) -> list:
    """PI speed loop with load feed-forward, sampled every step (1 kHz at the default step): the
    rows of `step(torque)` on `driver` (a `Simulator` or a `Session`), `speed()` the screw speed it reads.

    Gains place the loop at min(100 rad/s, 1/(20 dt)) on the reflected screw inertia, well
    inside the sampling limit, so the controller does not colour the mechanism's response.
    """
    params, dt = driver.params, driver.dt_s
    j = reflected_inertia(params)
    bw = min(100.0, 1.0 / (20.0 * dt))
    model = getattr(driver, "model", None)  # a Session names its screw model; a Simulator's model (or actuator)
    name = getattr(driver, "model_name", None) or getattr(model, "model_name", None) or getattr(model, "name", "")
    if name in MODELS and model_class(name).has_axial_chain:
        # above its axial mode the chain decouples the nut: the loop then acts on the screw side alone,
        # and a gain set on the whole inertia would make the sampled loop ring at the Nyquist rate
        # (kp dt / J_core > 2). Kept at kp dt / J_core ≤ 1/2, the bandwidth lowered to match.
        j_core = reflected_inertia(params.with_overrides({"mass.moved_mass_kg": 1e-9 * params.mass.moved_mass_kg}))
        bw = min(bw, 0.25 * j_core / (j * dt))
    kp, ki = 2.0 * j * bw, j * bw * bw
    ff = spec.load_n * params.geometry.lead_per_rad_m
    integ = 0.0
    rows = []
    for k in range(n):
        t = driver.time_s
        err = speed_reference(spec, t) - speed()
        integ += err * dt
        rows.append(step(ff + kp * err + ki * integ))
        if progress and (k + 1) % CHUNK_STEPS == 0:
            progress(k + 1)
    if progress:
        progress(n)
    return rows


def concatenate(parts: list[Trajectory]) -> Trajectory:
    """Join consecutive batch runs into one trajectory."""
    cols = {k: np.concatenate([p.columns[k] for p in parts]) for k in parts[0].columns}
    return Trajectory(columns=cols, internal=np.concatenate([p.internal for p in parts]), layout=parts[0].layout,
                      final_state=parts[-1].final_state)


def summarise(traj: Trajectory, tail_fraction: float = 0.1) -> dict:
    """Figures of a run: final state, tail means (last `tail_fraction`), peaks of the internal loads.

    Tail efficiency is the mechanism efficiency (`model_base.efficiency`) of the tail's mean
    powers, not the mean of step values, which NaN and reversals would bias.
    """
    n = len(traj)
    tail = slice(max(0, n - max(1, int(n * tail_fraction))), n)
    c = traj.columns
    eff = efficiency(float(np.mean(c["power_in_w"][tail])), float(np.mean(c["power_out_w"][tail])),
                     float(np.mean(c["power_dissipated_w"][tail])))
    w_s, w_c = c["screw_speed_rad_s"][tail], c["carrier_speed_rad_s"][tail]
    moving = np.abs(w_s) > 1e-9
    # the screw's books; an actuator's state holds its screw's (and its own ledger beside them)
    screw = getattr(traj.final_state, "screw", traj.final_state)
    out = {
        "steps": n,
        "duration_s": float(c["time_s"][-1] - c["time_s"][0] + (c["time_s"][1] - c["time_s"][0] if n > 1 else 0.0)),
        "final": {k: float(v[-1]) for k, v in c.items()},
        "tail_mean_speed_ratio": float(np.mean(w_c[moving] / w_s[moving])) if moving.any() else math.nan,
        "tail_efficiency": eff,
        "tail_mean_slip_speed_m_s": float(np.mean(c["slip_speed_m_s"][tail])),
        "peak_nut_force_n": float(np.max(np.abs(c["nut_force_n"]))),
        "peak_screw_speed_rad_s": float(np.max(np.abs(c["screw_speed_rad_s"]))),
        "energy": {"work_in_j": screw.work_in_j, "work_out_j": screw.work_out_j, "dissipated_j": screw.dissipated_j},
        "energy_guard": energy_guard_summary(c),
    }
    names = {b.name for b in traj.layout.blocks}
    if "per_tooth" in names:
        blk = next(b for b in traj.layout.blocks if b.name == "per_tooth")
        start = traj.layout.offsets()["per_tooth"]
        out["peak_tooth_normal_force_n"] = float(np.max(np.abs(traj.internal[:, start:start + blk.size])))
    if "per_roller" in names:
        blk = next(b for b in traj.layout.blocks if b.name == "per_roller")
        q = [n for n, _ in blk.quantities]
        start = traj.layout.offsets()["per_roller"]
        rows = traj.internal[:, start:start + blk.size].reshape(n, *blk.shape)
        for name in ("screw_normal_force_n", "nut_normal_force_n"):
            if name in q:
                out[f"peak_roller_{name}"] = float(np.max(np.abs(rows[:, :, q.index(name)])))
    return out
