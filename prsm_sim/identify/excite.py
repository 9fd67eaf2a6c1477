"""Identification signals: multisine, chirp or PRBS, bounded, for `prsm-fit excite` and the tests.

A signal excites what the fit has to tell apart: accelerations (the inertia), motion in both directions
(the friction against the load and with it) and speeds across the range (drag against load-dependent
loss). It is played around a holding controller (`hold_torque_nm`) so the nut stays on its travel.
"""

from __future__ import annotations

import math

import numpy as np

from prsm_sim.errors import InputError

KINDS = ("multisine", "chirp", "prbs")


def excitation(kind: str, duration_s: float, dt_s: float, amplitude: float, *, f_low_hz: float = 0.5,
               f_high_hz: float = 20.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(time_s, signal) of `kind` with peak |signal| = `amplitude` (the unit is the caller's: N·m or rad/s).

    multisine: Schroeder-phased sines on a log grid over [f_low, f_high] (low crest factor, Schroeder
    1970); chirp: a logarithmic sweep over the band; prbs: a ±amplitude random binary sequence held
    for 1/(2 f_high), smoothed by nothing.
    """
    if kind not in KINDS:
        raise InputError(f"--kind {kind!r}: must be one of {', '.join(KINDS)}")
    for name, v in (("duration_s", duration_s), ("dt_s", dt_s), ("amplitude", amplitude), ("f_low_hz", f_low_hz),
                    ("f_high_hz", f_high_hz)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise InputError(f"{name} = {v!r}: must be a finite number > 0")
    if not f_low_hz < f_high_hz <= 0.5 / dt_s:
        raise InputError(f"band [{f_low_hz:g}, {f_high_hz:g}] Hz: needs f_low < f_high <= "
                         f"the Nyquist {0.5 / dt_s:g} Hz")
    t = np.arange(int(round(duration_s / dt_s)) + 1) * dt_s
    if kind == "multisine":
        f = np.geomspace(f_low_hz, f_high_hz, 12)
        k = np.arange(1, len(f) + 1)
        phase = -math.pi * k * (k - 1) / len(f)  # Schroeder phases
        x = np.sin(2 * math.pi * f[None, :] * t[:, None] + phase[None, :]).sum(axis=1)
    elif kind == "chirp":
        from scipy.signal import chirp  # type: ignore[import-untyped]
        x = chirp(t, f_low_hz, t[-1], f_high_hz, method="logarithmic")
    else:
        hold = max(1, int(round(0.5 / (f_high_hz * dt_s))))
        bits = np.random.default_rng(seed).integers(0, 2, len(t) // hold + 1) * 2.0 - 1.0
        x = np.repeat(bits, hold)[:len(t)]
    peak = float(np.max(np.abs(x)))
    return t, amplitude * x / peak if peak > 0 else x


def hold_torque_nm(position_error_m: float, speed_error_m_s: float, integral_m_s: float, *, kp: float, kd: float,
                   ki: float = 0.0) -> float:
    """The holding controller's torque, N·m: a PID on the nut position (gains in N·m per m, per m/s, per m·s)."""
    return kp * position_error_m + kd * speed_error_m_s + ki * integral_m_s
