"""Identify an actuator from bench recordings: the parameters, how sure, how well it predicts.

    from prsm_sim.identify import Recording, fit_recordings, validate
    result = fit_recordings([rec_low, rec_high], base, "ideal")      # free: the model's defaults
    result.parameters["mass.moved_mass_kg"]     # {"value", "ci95", "unit", "identifiable", "base"}
    validate(result, held_out)                  # rms of the fitted and the base plant on another run

docs/fit.md describes the experiment and how the intervals are computed.
"""

from __future__ import annotations

from prsm_sim.identify.free import DELAY_KEY, FreeParameter, default_free, free_parameter
from prsm_sim.identify.problem import FitProblem
from prsm_sim.identify.recording import Recording
from prsm_sim.identify.solve import FitResult, fit, serial_map

__all__ = ["DELAY_KEY", "FitProblem", "FitResult", "FreeParameter", "Recording", "default_free", "fit",
           "fit_recordings", "free_parameter", "serial_map", "validate"]


def fit_recordings(recordings, base, model: str, free: list[str] | None = None, **kw) -> FitResult:
    """`fit` with the free parameters by dotted name (None: `default_free` for the model)."""
    names = default_free(base, model) if free is None else list(free)
    return fit(recordings, base, model, [free_parameter(base, n) for n in names], **kw)


def validate(result: FitResult, recording: Recording) -> dict:
    """The fitted and the base plant on `recording` (not fitted on): RMS nut position (m) and screw speed (rad/s)."""
    prob = result.problem
    fitted = prob.signal_rms(result.params, [recording], result.delay_steps)
    base = prob.signal_rms(result.base, [recording], 0)
    pick = lambda d: {"rms_nut_position_m": d["nut_position_m"], "rms_screw_speed_rad_s": d["screw_speed_rad_s"]}
    return pick(fitted) | {"base": pick(base)}
