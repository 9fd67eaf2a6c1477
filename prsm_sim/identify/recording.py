"""A bench recording as the fit reads it: time, the screw torque command, the measured motion, the load.

Only what a bench measures enters: the command, the screw and nut positions, the screw speed where
an encoder reports it, the nut load. `Recording` checks itself where it is built (one line naming
the field and what is wrong), so nothing downstream meets a NaN, time going back or a recording
too short to fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from prsm_sim.errors import InputError

MIN_SAMPLES = 50  # fewer samples than this hold no horizon worth fitting
# the step may vary by this much around the median before the recording is refused as irregular
STEP_TOLERANCE = 0.25
# the screw must turn by more than this over the recording (rad) for the command to have moved it:
# a few counts of a 4096-count encoder
MIN_TRAVEL_RAD = 0.01


@dataclass(frozen=True)
class Recording:
    """One recorded run, sampled at a fixed step.

    Attributes
    ----------
    name : str
        What the recording is called in reports (its file name).
    time_s : ndarray
        Sample times, s, strictly increasing at a near-constant step.
    screw_torque_nm : ndarray
        The screw torque commanded over the interval that starts at each sample, N·m.
    screw_position_rad, nut_position_m : ndarray
        Measured screw angle (rad) and nut position (m), any offset.
    screw_speed_rad_s : ndarray or None
        Measured screw speed, rad/s; None: derived from the screw angle where needed.
    load_n : ndarray
        Nut load, N (positive resisting positive nut motion), one per sample.
    """

    name: str
    time_s: np.ndarray
    screw_torque_nm: np.ndarray
    screw_position_rad: np.ndarray
    nut_position_m: np.ndarray
    load_n: np.ndarray
    screw_speed_rad_s: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = None
        for field in ("time_s", "screw_torque_nm", "screw_position_rad", "nut_position_m", "load_n",
                      "screw_speed_rad_s"):
            v = getattr(self, field)
            if v is None and field == "screw_speed_rad_s":
                continue
            arr = np.asarray(v, dtype=float)
            if field == "load_n" and arr.ndim == 0:
                arr = np.full(n if n is not None else 1, float(arr))
            if arr.ndim != 1:
                raise InputError(f"{self.name}: {field} has shape {arr.shape}: expected one value per sample")
            n = len(arr) if n is None else n
            if len(arr) != n:
                raise InputError(f"{self.name}: {field} has {len(arr)} samples, time_s has {n}")
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise InputError(f"{self.name}: {field}[{bad[0]}] = {arr[bad[0]]!r}: samples must be finite numbers")
            object.__setattr__(self, field, arr)
        self._check_time()
        travel = float(np.ptp(self.screw_position_rad))
        if travel <= MIN_TRAVEL_RAD or not np.any(self.screw_torque_nm != 0.0):
            raise InputError(f"{self.name}: the command never moves the screw (screw_position_rad spans "
                             f"{travel:.3g} rad, at most {MIN_TRAVEL_RAD} rad): nothing to fit")

    def _check_time(self) -> None:
        t = self.time_s
        if len(t) < MIN_SAMPLES:
            raise InputError(f"{self.name}: {len(t)} samples: too short, at least {MIN_SAMPLES} are needed")
        dt = np.diff(t)
        back = np.flatnonzero(dt <= 0.0)
        if back.size:
            k = int(back[0]) + 1
            raise InputError(f"{self.name}: time_s goes back or stands at sample {k} "
                             f"({t[k - 1]!r} s then {t[k]!r} s): must increase")
        step = float(np.median(dt))
        off = np.flatnonzero(np.abs(dt - step) > STEP_TOLERANCE * step)
        if off.size:
            k = int(off[0]) + 1
            raise InputError(f"{self.name}: time_s steps {dt[k - 1]:.6g} s at sample {k}, the median step is "
                             f"{step:.6g} s: a recording at a fixed step is needed (within {STEP_TOLERANCE:.0%})")
        if not 0.0 < step <= 0.1:
            raise InputError(f"{self.name}: time_s step {step:g} s: must lie in (0, 0.1] s")

    @property
    def dt_s(self) -> float:
        """The recording's step (the median of its sample intervals), s."""
        return float(np.median(np.diff(self.time_s)))

    @property
    def samples(self) -> int:
        return len(self.time_s)

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    def speed(self) -> np.ndarray:
        """Screw speed, rad/s: as measured, or the screw angle's derivative by a local quadratic fit
        (Savitzky–Golay over about 10 ms, so an encoder's counts do not turn into speed spikes)."""
        if self.screw_speed_rad_s is not None:
            return self.screw_speed_rad_s
        from scipy.signal import savgol_filter  # type: ignore[import-untyped]
        window = max(5, int(round(0.01 / self.dt_s)) | 1)
        window = min(window, (self.samples - 1) | 1 if (self.samples - 1) % 2 else self.samples - 2)
        return savgol_filter(self.screw_position_rad, window, 2, deriv=1, delta=self.dt_s)

    def head(self, duration_s: float) -> Recording:
        """The first `duration_s` of the recording (itself when it is no longer); InputError where that part
        does not move the screw."""
        n = max(MIN_SAMPLES, int(round(duration_s / self.dt_s)) + 1)
        if n >= self.samples:
            return self
        cut = lambda a: None if a is None else a[:n]
        return Recording(name=self.name, time_s=self.time_s[:n], screw_torque_nm=self.screw_torque_nm[:n],
                         screw_position_rad=self.screw_position_rad[:n], nut_position_m=self.nut_position_m[:n],
                         load_n=self.load_n[:n], screw_speed_rad_s=cut(self.screw_speed_rad_s))

    def loads(self) -> list[float]:
        """The distinct constant loads or the load's range, N, for reports."""
        lo, hi = float(self.load_n.min()), float(self.load_n.max())
        return [lo] if math.isclose(lo, hi) else [lo, hi]
