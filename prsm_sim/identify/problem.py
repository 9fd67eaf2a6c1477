"""The least-squares problem of a fit: free parameters in a unit box → weighted residuals over horizons.

Residuals are the predicted minus the measured signals over every horizon of every recording
(`shooting`), each signal divided by its sensor resolution (`resolution`), so a nut position in
metres and a screw angle in radians weigh by what the sensors can tell apart.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from prsm_sim.actuator import ActuatorParams
from prsm_sim.errors import InputError, ParamError
from prsm_sim.identify.free import DELAY_KEY, FreeParameter
from prsm_sim.identify.recording import Recording
from prsm_sim.identify.shooting import HORIZON_S, Horizons, measured, simulate
from prsm_sim.params import Params
from prsm_sim.session import SessionConfig

# The finest a bench's sensors resolve unless the data show coarser: a 16-bit screw encoder
# (2π/65536 rad), a 0.1 µm nut scale, 1 mrad/s of speed. The residual's scale is never below these,
# so a noise-free (simulated) recording does not give intervals of zero width.
RESOLUTION_FLOOR = {"nut_position_m": 1e-7, "screw_position_rad": 2 * math.pi / 65536, "screw_speed_rad_s": 1e-3}
NAN_RESIDUAL = 1e3  # a prediction the model could not run, in resolutions


def quantum(x: np.ndarray) -> float:
    """The smallest step between distinct samples of `x` (an encoder's count), 0 when none."""
    d = np.abs(np.diff(np.unique(x)))
    return float(d.min()) if d.size else 0.0


def noise(x: np.ndarray, dt_s: float) -> float:
    """The sensor noise of `x` (one standard deviation): its scatter about a local cubic over ~10 ms
    (Savitzky–Golay), which follows the motion and leaves the noise, taken as the median absolute
    deviation × 1.4826 (σ of a normal distribution): the noise is in every sample, while the motion
    the cubic cannot follow (a stick, a reversal, an elastic chain's ringing after one) is in few,
    and a standard deviation would count it as noise and weigh the signal down."""
    from scipy.signal import savgol_filter  # type: ignore[import-untyped]
    w = max(7, int(round(0.01 / dt_s)) | 1)
    if len(x) <= w:
        return 0.0
    e = x - savgol_filter(x, w, 3)
    mad = float(np.median(np.abs(e - np.median(e))))
    return 1.4826 * mad / math.sqrt(1.0 - 4.0 / w)  # the fit takes ~4 of the window's w degrees of freedom


def resolution(recs: tuple[Recording, ...], signal: str) -> float:
    """A signal's scale (one standard deviation): the larger of its noise, a quantum q found in the data
    as q/√12 (uniform rounding error) and `RESOLUTION_FLOOR`."""
    s = RESOLUTION_FLOOR[signal]
    for r in recs:
        x = r.speed() if signal == "screw_speed_rad_s" else getattr(r, signal)
        s = max(s, quantum(x) / math.sqrt(12.0), noise(x, r.dt_s))
    return s


def free_start(r: np.ndarray, steps: int, signal: str) -> np.ndarray:
    """Residuals of one signal with each horizon's start error taken out (rows: horizons).

    The start of a horizon is measured, not known: an encoder count or the noise of the nut scale
    offsets the whole horizon, an error in the start speed tilts it. Both are removed by least squares
    per horizon (an offset and a slope in time for a position, an offset for a speed), the way
    multiple shooting frees each horizon's start, so they neither bias the fit nor count as its misfit.
    """
    m = r.reshape(-1, steps)
    t = np.arange(1, steps + 1, dtype=float)
    basis = np.stack([np.ones(steps), t]) if signal != "screw_speed_rad_s" else np.ones((1, steps))
    q, _ = np.linalg.qr(basis.T)
    return (m - (m @ q) @ q.T).ravel()


@dataclass(frozen=True)
class FitProblem:
    """What a fit holds fixed: recordings, base parameters, model, actuator, the free parameters (the
    delay aside), the delay, the signals compared and their scales."""

    recordings: tuple[Recording, ...]
    base: Params
    model: str
    free: tuple[FreeParameter, ...]
    actuator: ActuatorParams | None = None
    delay_steps: int = 0
    horizon_s: float = HORIZON_S
    kernel: str = "compiled"
    signals: tuple[str, ...] = ()
    scale: dict = field(default_factory=dict)
    free_start: bool = True

    @classmethod
    def build(cls, recordings, base: Params, model: str, free, **kw) -> FitProblem:
        recs = tuple(recordings)
        signals = ("nut_position_m", "screw_position_rad") + (
            ("screw_speed_rad_s",) if all(r.screw_speed_rad_s is not None for r in recs) else ())
        free = tuple(p for p in free if p.name != DELAY_KEY)
        return cls(recs, base, model, free, signals=signals, scale={s: resolution(recs, s) for s in signals}, **kw)

    def head(self, duration_s: float) -> FitProblem:
        """The same problem on the first `duration_s` of each recording (the signals' scales kept: they are
        the sensors'), or itself where every recording is that short or a head would not move the screw."""
        try:
            recs = tuple(r.head(duration_s) for r in self.recordings)
        except InputError:
            return self
        return self if all(a is b for a, b in zip(recs, self.recordings, strict=True)) else replace(self, recordings=recs)

    def unit_of(self, params: Params) -> np.ndarray:
        """`params`' free values as a point of the unit box."""
        return np.array([p.to_unit(_get(params, p.name)) for p in self.free])

    def params_at(self, u) -> Params:
        """The base with the free parameters at unit-box point `u` (a backward efficiency above the
        forward one is held at it: the ideal model's law needs η′ ≤ η)."""
        over = {p.name: p.from_unit(float(x)) for p, x in zip(self.free, u)}
        ef = over.get("ideal.efficiency_forward", self.base.ideal.efficiency_forward)
        if "ideal.efficiency_backward" in over or "ideal.efficiency_forward" in over:
            over["ideal.efficiency_backward"] = min(over.get("ideal.efficiency_backward",
                                                             self.base.ideal.efficiency_backward), ef)
        return self.base.with_overrides(over) if over else self.base

    def config(self, params: Params, rec: Recording) -> SessionConfig:
        limit = 2.0 * float(np.max(np.abs(rec.screw_torque_nm))) + 1.0  # the gate never saturates the record
        return SessionConfig(params=params, model=self.model, dt_s=rec.dt_s, actuator=self.actuator,
                             kernel=self.kernel, max_effort_nm=limit)

    def horizons(self, rec: Recording) -> Horizons:
        return Horizons.of(rec, self.horizon_s)

    def predictions(self, params: Params, delay_steps: int | None = None) -> list[dict[str, np.ndarray]]:
        d = self.delay_steps if delay_steps is None else delay_steps
        return [simulate(self.config(params, r), r, self.horizons(r), d) for r in self.recordings]

    def residuals_of(self, params: Params, delay_steps: int | None = None) -> np.ndarray:
        """Weighted residuals (prediction − measurement) / resolution, recording by recording, signal by
        signal, horizon by horizon (`cluster_ids` labels them by horizon)."""
        parts = []
        for rec, pred in zip(self.recordings, self.predictions(params, delay_steps)):
            meas = measured(rec, self.horizons(rec))
            steps = self.horizons(rec).steps
            for s in self.signals:
                r = (pred[s] - meas[s]) / self.scale[s]
                r = np.where(np.isfinite(r), r, NAN_RESIDUAL)
                parts.append(free_start(r, steps, s) if self.free_start else r)
        return np.concatenate(parts)

    def residuals(self, u) -> np.ndarray:
        """`residuals_of` at unit-box point `u` (the least-squares function)."""
        try:
            params = self.params_at(u)
        except ParamError:  # a combination the parameter checks refuse: as far from the data as can be
            return np.full(self.size, NAN_RESIDUAL)
        return self.residuals_of(params)

    @property
    def size(self) -> int:
        return sum(len(self.horizons(r).indices()) for r in self.recordings) * len(self.signals)

    def cluster_ids(self) -> np.ndarray:
        """The horizon each residual belongs to (one id per recording and horizon, over all signals)."""
        ids, first = [], 0
        for rec in self.recordings:
            h = self.horizons(rec)
            one = first + np.repeat(np.arange(len(h.starts)), h.steps)
            ids += [one] * len(self.signals)
            first += len(h.starts)
        return np.concatenate(ids)

    def signal_rms(self, params: Params, recordings=None, delay_steps: int | None = None) -> dict[str, float]:
        """RMS of prediction − measurement per signal, in the signal's unit, over `recordings` (default: the fit's)."""
        prob = self if recordings is None else replace(self, recordings=tuple(recordings))
        out = {}
        preds = prob.predictions(params, delay_steps)
        for s in ("nut_position_m", "screw_position_rad", "screw_speed_rad_s"):
            err = np.concatenate([p[s] - measured(r, prob.horizons(r))[s] for r, p in zip(prob.recordings, preds)])
            err = err[np.isfinite(err)]
            out[s] = float(np.sqrt(np.mean(err**2))) if err.size else math.nan
        return out


def _get(params: Params, name: str) -> float:
    group, key = name.split(".")
    return float(getattr(getattr(params, group), key))
