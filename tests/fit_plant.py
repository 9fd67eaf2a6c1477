"""A hidden plant recorded the way a bench would be: a PID hold plus a torque excitation, run on a Session.

Used by the fit tests: the recording carries only what a bench measures (time, the torque command,
screw angle, nut position, optionally screw speed, the load).
"""

from __future__ import annotations

import numpy as np

from prsm_sim.identify import Recording
from prsm_sim.identify.excite import excitation
from prsm_sim.session import Session, SessionConfig


def record(params, model: str, *, load_n: float, duration_s: float = 2.0, dt_s: float = 1e-3, amplitude_nm: float = 2.0,
           kp: float = 3000.0, kd: float = 60.0, seed: int = 0, counts_per_rev: int | None = None,
           nut_noise_m: float = 0.0, speed: bool = True, name: str = "run", kind: str = "multisine") -> Recording:
    """A closed-loop recording of `params` on `model` at a constant load (torque = PD hold + excitation +
    the load's holding torque), quantised and noised as asked."""
    s = Session.from_config(SessionConfig(params=params, model=model, dt_s=dt_s, initial_load_n=load_n,
                                          max_effort_nm=1e6))
    p = params.geometry.lead_per_rad_m
    t, u_ex = excitation(kind, duration_s, dt_s, amplitude_nm, seed=seed)
    rng = np.random.default_rng(seed + 1)
    n = len(t)
    theta, x, w, u = (np.zeros(n) for _ in range(4))
    o = s.last
    for k in range(n):
        theta[k], x[k], w[k] = o.screw_angle_rad, o.nut_position_m, o.screw_speed_rad_s
        u[k] = u_ex[k] + p * load_n - kp * x[k] - kd * o.nut_velocity_m_s
        o = s.step(float(u[k]), load_n)
    if counts_per_rev:
        q = 2 * np.pi / counts_per_rev
        theta = np.round(theta / q) * q
    x = x + rng.normal(0.0, nut_noise_m, n) if nut_noise_m else x
    return Recording(name=name, time_s=t, screw_torque_nm=u, screw_position_rad=theta, nut_position_m=x,
                     load_n=np.full(n, float(load_n)), screw_speed_rad_s=w if speed else None)


def write_csv(path, rec: Recording, speed: bool = True) -> None:
    """`rec` as a bench's table (prsm-fit's CSV columns; the load is given on the command line as FILE@LOAD_N)."""
    cols = {"time_s": rec.time_s, "screw_torque_nm": rec.screw_torque_nm, "screw_position_rad": rec.screw_position_rad,
            "nut_position_m": rec.nut_position_m}
    if speed and rec.screw_speed_rad_s is not None:
        cols["screw_speed_rad_s"] = rec.screw_speed_rad_s
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        for row in zip(*cols.values()):
            f.write(",".join(repr(float(v)) for v in row) + "\n")
