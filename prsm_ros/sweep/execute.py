"""One run of a study: spec in, one table row out (inputs, metrics, status, error, wall time).

No Ray here: `runner` ships batches of specs to Ray tasks that call `run_batch`, and `tune`
calls `run_one` inside its trials. A run that raises is a row with status "failed" and its
error; it never stops the batch.
"""

from __future__ import annotations

import math
import time

import numpy as np

from prsm_sim import Session, SessionConfig, Simulator, Trajectory
from prsm_sim.actuator import actuator_params_from_dict
from prsm_sim.control import PositionController, run_position_loop
from prsm_sim.life import life_from_samples
from prsm_sim.models.registry import model_class
from prsm_sim.physics.inertia import mass_matrix, reflected_inertia
from prsm_sim.scenarios import default_spec, run_scenario, run_session_scenario, summarise

from prsm_ros.sweep.study import POSITION, StudyError, base_params, controller_defaults

TAIL_FRACTION = 0.1  # as `prsm-sim run --json` (prsm_sim.scenarios.summarise)
# bare metric → the key `prsm-sim run --json` reports it under
SUMMARY_NAMES = {"efficiency": "tail_efficiency", "speed_ratio": "tail_mean_speed_ratio",
                 "slip_speed_m_s": "tail_mean_slip_speed_m_s"}


def _split(inputs: dict) -> tuple[dict, dict, dict]:
    """Study keys → (parameter overrides, scenario.* options, controller./reference. settings)."""
    params, scen, loop = {}, {}, {}
    for k, v in inputs.items():
        group, name = k.split(".", 1)
        if group == "scenario":
            scen[name] = v
        elif group in ("controller", "reference"):
            loop[k] = v
        else:
            params[k] = v
    return params, scen, loop


def simulate(norm: dict, scenario: str, inputs: dict) -> tuple[Trajectory, dict]:
    """Run one scenario with the study's fixed settings and these inputs → (trajectory, extras)."""
    params_o, scen, loop = _split({**norm["set"], **inputs})
    nominal = base_params(norm)
    params = nominal.with_overrides(params_o) if params_o else nominal
    if norm.get("actuator") is not None:  # stepped through the session, as the node steps it
        session = Session.from_config(SessionConfig(params=params, model=norm["model"], dt_s=norm["dt_s"],
                                                    actuator=actuator_params_from_dict(norm["actuator"])))
        spec = default_spec(params, scenario, **scen)
        return run_session_scenario(session, spec, norm["duration_s"]), {"params": params}
    sim = Simulator(params, norm["model"], norm["dt_s"])
    if scenario != POSITION:
        spec = default_spec(params, scenario, **scen)
        return run_scenario(sim, spec, norm["duration_s"]), {"params": params}
    unknown = sorted(set(scen) - {"load_n"})
    if unknown:
        raise StudyError(f"scenario.{unknown[0]}: the position scenario takes scenario.load_n only")
    settings = {**controller_defaults(), **loop}
    load = float(scen.get("load_n", 0.0))  # the demo's default load
    # the controller is tuned on the nominal design (the demo's model-based tuning); the plant may differ
    ctl = PositionController(reflected_inertia(nominal), nominal.geometry.lead_per_rad_m,
                             bandwidth_hz=settings["controller.bandwidth_hz"], damping=settings["controller.damping"],
                             integral_ratio=settings["controller.integral_ratio"],
                             max_torque_nm=settings["controller.max_torque_nm"],
                             load_n=float(settings.get("controller.load_n", load)))
    traj, track = run_position_loop(sim, ctl, norm["duration_s"], load, settings["reference.amplitude_m"],
                                    settings["reference.frequency_hz"])
    return traj, {"params": params, "tracking_error_rms_m": track.rms_m, "tracking_error_max_m": track.max_abs_m}


def metrics(norm: dict, traj: Trajectory, extras: dict) -> dict:
    """The study's metrics of one run (docs: `prsm_ros.sweep.study`)."""
    summary = summarise(traj, TAIL_FRACTION)
    n = len(traj)
    tail = slice(max(0, n - max(1, int(n * TAIL_FRACTION))), n)  # the tail `summarise` uses
    out = {}
    for m in norm["metrics"]:
        base, _, sel = m.partition("@")
        if base in extras and base != "params":
            out[m] = extras[base]
        elif base.startswith("energy_residual"):
            out[m] = _energy_residual(norm, traj, extras["params"])[base]
        elif base.startswith("l10_"):
            life = life_from_samples(traj.time_s, traj["nut_force_n"], traj["screw_speed_rad_s"],
                                     norm["life"]["dynamic_load_rating_n"])
            out[m] = getattr(life, base)
        elif base.startswith("peak_"):
            out[m] = summary.get(base, math.nan)  # a model without per-tooth loads has none
        elif not sel:
            out[m] = summary[SUMMARY_NAMES[base]] if base in SUMMARY_NAMES else float(np.mean(traj[base][tail]))
        else:
            col = traj[base]
            out[m] = float({"final": lambda c: c[-1], "mean": np.mean, "max": np.max, "min": np.min,
                            "rms": lambda c: np.sqrt(np.mean(c * c))}[sel](col))
    return out


def _energy_residual(norm: dict, traj: Trajectory, params) -> dict:
    """work_in − work_out − kinetic − dissipated at the end of the run (docs/model.md §5 item 5), J and relative."""
    s = traj.final_state
    u = np.array([s.screw_speed_rad_s, s.carrier_speed_rad_s])
    if not model_class(norm["model"]).has_carrier:  # the carrier moves at the ideal ratio: in J
        kinetic = 0.5 * reflected_inertia(params) * s.screw_speed_rad_s ** 2
    else:
        kinetic = 0.5 * float(u @ mass_matrix(params) @ u)
    r = s.work_in_j - s.work_out_j - kinetic - s.dissipated_j
    gross = float(np.sum(np.abs(traj["power_in_w"]))) * norm["dt_s"]
    return {"energy_residual_j": r, "energy_residual_rel": r / gross if gross > 0 else math.nan}


def run_one(norm: dict, spec: dict, decimate: int | None = None) -> tuple[dict, object]:
    """One spec → (row, decimated trajectory DataFrame or None). Never raises for a failed run."""
    t0 = time.perf_counter()
    row = {"run_id": spec["run_id"], "grid_point": spec["grid_point"], "sample": spec["sample"],
           "scenario": spec["scenario"], **spec["inputs"]}
    frame = None
    try:
        traj, extras = simulate(norm, spec["scenario"], spec["inputs"])
        row.update(metrics(norm, traj, extras))
        row["status"], row["error"] = "ok", None
        if decimate:
            frame = traj.to_dataframe().iloc[::decimate].reset_index()
    except Exception as e:  # a failed run is data, not the end of the study
        return failed_row(norm, spec, e, time.perf_counter() - t0), None
    row["wall_time_s"] = time.perf_counter() - t0
    return row, frame


def failed_row(norm: dict, spec: dict, error: BaseException, wall_time_s: float = math.nan) -> dict:
    """The row of a run that did not finish: its inputs, NaN metrics, status "failed" and the error."""
    return {"run_id": spec["run_id"], "grid_point": spec["grid_point"], "sample": spec["sample"],
            "scenario": spec["scenario"], **spec["inputs"], **{m: math.nan for m in norm["metrics"]},
            "status": "failed", "error": f"{type(error).__name__}: {error}".splitlines()[0],
            "wall_time_s": wall_time_s}


# Why a metric of a finished run is NaN (undefined, not failed): by the metric's name (before any @selector)
UNDEFINED_WHY = {
    "efficiency": "no net power reached the load in the run's tail (the screw stood still, e.g. a load held by "
                  "static friction, or a run shorter than the scenario's 0.1 s speed ramp)",
    "speed_ratio": "the screw did not turn in the run's tail",
    "energy_residual_rel": "no work went in",
}
UNDEFINED_PEAK_WHY = "the model has no such internal load"


def undefined(rows: list[dict], metrics: list[str]) -> dict[str, dict]:
    """Metrics that are NaN in finished runs: {metric: {"runs", "of", "why"}}, only those with any.

    A failed run's metrics are NaN because it failed (its error says why); these are runs that
    finished and measured nothing, which a study's statistics would otherwise pass over in silence.
    """
    ok = [r for r in rows if r.get("status") == "ok"]
    out = {}
    for m in metrics:
        n = sum(1 for r in ok if not (isinstance(r.get(m), (int, float)) and math.isfinite(r[m])))
        if n:
            base = m.partition("@")[0]
            why = UNDEFINED_PEAK_WHY if base.startswith("peak_") else UNDEFINED_WHY.get(
                base, "the metric is not defined for these runs")
            out[m] = {"runs": n, "of": len(ok), "why": why}
    return out


def undefined_text(undef: dict[str, dict]) -> list[str]:
    """One line per metric of `undefined`, for the CLI's summary and the report."""
    return [f"{m}: NaN in {u['runs']} of {u['of']} finished runs: {u['why']}" for m, u in undef.items()]


def run_batch(norm: dict, specs: list[dict], decimate: int | None = None) -> list[tuple[dict, object]]:
    """Several runs in one task: amortises the task overhead over runs too short to carry it."""
    return [run_one(norm, s, decimate) for s in specs]
