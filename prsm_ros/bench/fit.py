"""Benchmark of `prsm-fit`: the wall time to fit 20 s of 1 kHz data (target ≤ 5 minutes on two cores).

Two 10 s recordings of a hidden `fu2018` plant (s30 with another moved mass, screw–roller friction
and seal drag), held by a PD loop around a multisine at 1 and 3 kN, fitted with the model's
default free set (moved mass, μ_SR, seal drag, command delay) from 4 starts on an embedded Ray with
two workers, as `prsm-fit` runs by default (the starts on each recording's first seconds, the best
polished on the whole). `--quick` fits 2 s. Nothing here asserts a timing.
"""

from __future__ import annotations

import time

import numpy as np

from prsm_sim import preset
from prsm_sim.identify import Recording, fit_recordings
from prsm_sim.identify.excite import excitation
from prsm_sim.session import Session, SessionConfig
from prsm_ros.bench.common import area_main, figure

HIDDEN = {"mass.moved_mass_kg": 80.0, "friction.mu_screw_roller": 0.08, "drag.enabled": True,
          "drag.seal_friction_n_per_m": 60.0}


def recording(params, load_n: float, duration_s: float, seed: int) -> Recording:
    """A PD hold plus a multisine on `params` (fu2018), at 1 kHz."""
    s = Session.from_config(SessionConfig(params=params, model="fu2018", initial_load_n=load_n, max_effort_nm=1e6))
    p = params.geometry.lead_per_rad_m
    t, wiggle = excitation("multisine", duration_s, 1e-3, 3.0, seed=seed)
    cols = np.zeros((4, len(t)))
    o = s.last
    for k in range(len(t)):
        u = wiggle[k] + p * load_n - 3000.0 * o.nut_position_m - 60.0 * o.nut_velocity_m_s
        cols[:, k] = (u, o.screw_angle_rad, o.nut_position_m, o.screw_speed_rad_s)
        o = s.step(float(u), load_n)
    return Recording(name=f"bench{load_n:g}", time_s=t, screw_torque_nm=cols[0], screw_position_rad=cols[1],
                     nut_position_m=cols[2], screw_speed_rad_s=cols[3], load_n=np.full(len(t), load_n))


def measure(quick: bool = False) -> list[dict]:
    from prsm_ros.fit.cli import ray_map
    base = preset("s30")
    hidden = base.with_overrides(HIDDEN)
    each_s = 1.0 if quick else 10.0
    recs = [recording(hidden, f, each_s, i) for i, f in enumerate((1000.0, 3000.0))]
    t0 = time.perf_counter()
    res = fit_recordings(recs, base, "fu2018", starts=4, map_fn=ray_map(None, 2))
    wall = time.perf_counter() - t0
    mass = res.parameters["mass.moved_mass_kg"]["value"]
    total_s = 2 * each_s
    return [figure(f"prsm-fit: {total_s:g} s of 1 kHz data (fu2018, 3 parameters + delay, 4 starts on Ray)", wall, "s",
                   "≤ 300" if not quick else "(quick)", wall <= 300 if not quick else None, None,
                   f"moved mass {mass:.4g} kg (hidden 80); evaluations per start on each recording's first "
                   f"{res.starts[0].data_s / len(recs):.3g} s: {', '.join(str(s.nfev) for s in res.starts)}; polish on "
                   f"the whole: {res.polish.nfev if res.polish else 0}; Ray start-up included")]


if __name__ == "__main__":
    raise SystemExit(area_main("fit", measure))
