"""Rating life L10 of a roller screw over a duty cycle (docs/model.md §5 item 10).

Vendor catalogues (the ISO 281 / ISO 3408-5 form used for ball and roller screws) give the
basic rating life, reached or exceeded by 90 % of identical screws, as

    L10 = (C_a / F_m)³ · 10⁶  revolutions,

with C_a the basic dynamic axial load rating and F_m the cubic mean axial load over the duty
cycle, each load weighted by the revolutions made under it:

    F_m = (Σ |F_i|³ n_i / Σ n_i)^(1/3).

Pure functions (numpy only); loads in N, revolutions counted without sign.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prsm_sim.errors import InputError

LIFE_EXPONENT = 3.0  # catalogue exponent for screws with line/point contact as rated by vendors
MILLION_REVOLUTIONS = 1e6


def cubic_mean_load(load_n, revolutions) -> float:
    """F_m = (Σ |F_i|³ n_i / Σ n_i)^(1/3): the constant load with the same fatigue effect (N).

    `load_n[i]` acts during `revolutions[i]` (≥ 0). NaN when no revolution is made.
    """
    f = np.abs(np.asarray(load_n, dtype=float))
    n = np.abs(np.asarray(revolutions, dtype=float))
    if f.shape != n.shape:
        raise InputError(f"load_n has shape {f.shape}, revolutions {n.shape}: they must match")
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(n))):
        raise InputError("load_n and revolutions must be finite")
    total = float(n.sum())
    if total <= 0.0:
        return math.nan
    return float((np.sum(f**LIFE_EXPONENT * n) / total) ** (1.0 / LIFE_EXPONENT))


def l10_revolutions(dynamic_load_rating_n: float, mean_load_n: float) -> float:
    """L10 = (C_a / F_m)³ · 10⁶ revolutions; infinite for F_m = 0, NaN for an undefined F_m."""
    c = float(dynamic_load_rating_n)
    if not (math.isfinite(c) and c > 0):
        raise InputError(f"dynamic_load_rating_n = {dynamic_load_rating_n!r}: must be a finite number > 0")
    if math.isnan(mean_load_n):
        return math.nan
    if mean_load_n <= 0.0:
        return math.inf
    return (c / mean_load_n) ** LIFE_EXPONENT * MILLION_REVOLUTIONS


@dataclass(frozen=True)
class LifeEstimate:
    """L10 over a recorded duty cycle, repeated as recorded."""

    dynamic_load_rating_n: float
    mean_load_n: float          # F_m
    cycle_revolutions: float    # revolutions of the screw in one recorded cycle
    cycle_duration_s: float
    l10_revolutions: float
    l10_hours: float            # at the cycle's mean speed (revolutions per hour of the cycle)
    l10_cycles: float           # repetitions of the recorded cycle

    def to_dict(self) -> dict[str, float]:
        return {k: float(getattr(self, k)) for k in self.__dataclass_fields__}


def life_from_samples(time_s, axial_load_n, screw_speed_rad_s, dynamic_load_rating_n: float) -> LifeEstimate:
    """L10 from sampled axial load and screw speed, each sample held until the next one.

    Interval i runs from time_s[i] to time_s[i+1]; the screw makes |ω_i| Δt_i / 2π revolutions in it
    under |F_i|. The last sample has no interval and is not counted.
    """
    t = np.asarray(time_s, dtype=float)
    f = np.asarray(axial_load_n, dtype=float)
    w = np.asarray(screw_speed_rad_s, dtype=float)
    if not (t.shape == f.shape == w.shape) or t.ndim != 1:
        raise InputError(f"time_s, axial_load_n, screw_speed_rad_s must be 1-D of one length; "
                         f"got {t.shape}, {f.shape}, {w.shape}")
    if t.size < 2:
        raise InputError("at least two samples are needed to count revolutions")
    dt = np.diff(t)
    if np.any(dt < 0):
        raise InputError("time_s must not decrease")
    revs = np.abs(w[:-1]) * dt / (2 * math.pi)
    fm = cubic_mean_load(f[:-1], revs)
    l10 = l10_revolutions(dynamic_load_rating_n, fm)
    cycle_revs = float(revs.sum())
    duration = float(t[-1] - t[0])
    per_hour = cycle_revs / duration * 3600.0 if duration > 0 else math.nan
    return LifeEstimate(
        dynamic_load_rating_n=float(dynamic_load_rating_n), mean_load_n=fm,
        cycle_revolutions=cycle_revs, cycle_duration_s=duration, l10_revolutions=l10,
        l10_hours=l10 / per_hour if per_hour and per_hour > 0 else math.nan,
        l10_cycles=l10 / cycle_revs if cycle_revs > 0 else math.nan,
    )
