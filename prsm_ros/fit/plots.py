"""Measured against fitted: one PNG per recording, nut position and screw speed with their residuals.

The fitted curve is the prediction of every horizon, each started from the measured state, so what
the plot shows is exactly what the fit compared.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from prsm_sim.identify.shooting import measured


def plot_recording(problem, params, base, rec, delay_steps: int, path: Path, title: str) -> None:
    """Write `path`: measured, fitted and base predictions of `rec` over the horizons, and the residuals."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    prob = replace(problem, recordings=(rec,))
    h = prob.horizons(rec)
    idx = h.indices()
    t = rec.time_s[idx] - rec.time_s[0]
    meas = measured(rec, h)
    fitted = prob.predictions(params, delay_steps)[0]
    based = prob.predictions(base, 0)[0]
    fig, ax = plt.subplots(4, 1, figsize=(10, 9), sharex=True, constrained_layout=True)
    tg = _gapped(t, h.steps)
    for k, (sig, scale, unit) in enumerate((("nut_position_m", 1e3, "mm"), ("screw_speed_rad_s", 1.0, "rad/s"))):
        a, r = ax[2 * k], ax[2 * k + 1]
        a.plot(tg, _gapped(meas[sig], h.steps) * scale, color="k", lw=1.0, label="measured")
        for pred, style, label in ((based, dict(color="tab:red", lw=0.8, alpha=0.7), "base"),
                                   (fitted, dict(color="tab:blue", lw=1.0), "fitted")):
            a.plot(tg, _gapped(pred[sig], h.steps) * scale, label=label, **style)
            r.plot(tg, _gapped(pred[sig] - meas[sig], h.steps) * scale, **style)
        a.set_ylabel(f"{'nut position' if k == 0 else 'screw speed'} ({unit})")
        r.set_ylabel(f"residual ({unit})")
        r.axhline(0.0, color="k", lw=0.5)
        a.legend(loc="upper right", fontsize=8)
    ax[-1].set_xlabel("time (s)")
    fig.suptitle(f"{title}: {rec.name} (horizons of {h.steps} steps from the measured state)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _gapped(y: np.ndarray, steps: int) -> np.ndarray:
    """`y` (horizon after horizon) with a NaN after each horizon, so the lines do not join across a restart."""
    m = np.asarray(y, dtype=float).reshape(-1, steps)
    return np.hstack([m, np.full((len(m), 1), np.nan)]).ravel()
