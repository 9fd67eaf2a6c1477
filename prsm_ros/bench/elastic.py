"""Benchmark of the `elastic` level: simulated seconds per wall second at a 1 ms output step.

Batch path (`Simulator.run`) and per-step path (`Simulator.step`, the node's), `s30` under a
5 kN load with a torque that reverses (backlash-free chain, so the run is about stepping cost),
each beside its floor (issue 13: ≥ 100× batch, ≥ 20× per step). The accuracy figure is the
run's deviation from the same equations at a 10× finer output step (inputs held per 1 ms),
relative to the reference's range, on the nut position and the carrier speed. Nothing here
asserts a timing; `prsm-bench --only elastic` prints the figures.

Self-contained on purpose (the figure helpers are `prsm_ros.bench.core`'s).
"""

from __future__ import annotations

import math

import numpy as np

from prsm_sim import Simulator, preset
from prsm_ros.bench.common import area_main, figure
from prsm_ros.bench.core import DT, _error, _timed


def measure(quick: bool = False) -> list[dict]:
    p = preset("s30")
    sim_s = 0.3 if quick else 2.0
    n = int(sim_s / DT)
    t = DT * np.arange(n)
    ramp = np.clip(t / 0.05, 0, 1)
    torque = ramp * (4.3 + 3.0 * np.sin(2 * math.pi * 2.0 * t))  # around the 5 kN holding torque: reversals
    load = 5000.0 * ramp
    repeats = 2 if quick else 3
    sim = Simulator(p, "elastic", DT)

    def batch():
        sim.reset()
        return sim.run(torque, load)

    def steps():
        sim.reset()
        for tau, f in zip(torque.tolist(), load.tolist()):
            sim.step(tau, f)

    fine = 10
    ref = Simulator(p, "elastic", DT / fine).run(np.repeat(torque, fine), np.repeat(load, fine))
    wall_b, spread_b, tr = _timed(batch, repeats)
    wall_s, spread_s, _ = _timed(steps, repeats)
    err = max(_error(tr["nut_position_m"], ref["nut_position_m"][fine - 1::fine]),
              _error(tr["carrier_speed_rad_s"], ref["carrier_speed_rad_s"][fine - 1::fine]))
    rt_b, rt_s = sim_s / wall_b, sim_s / wall_s
    note = (f"{sim.model.substeps} sub-steps per 1 ms (axial mode ~580 Hz); fu2018 core in pure Python; "
            f"error vs 10× finer step: {err:.1e}")
    return [
        figure("elastic (s30) batch simulated s per wall s", rt_b, "×", "≥ 100", rt_b >= 100 and err <= 1e-3,
               spread_b, f"{wall_b / n * 1e6:.0f} µs per step; " + note),
        figure("elastic (s30) per-step path (Simulator.step) simulated s per wall s", rt_s, "×", "≥ 20", rt_s >= 20,
               spread_s, f"{wall_s / n * 1e6:.0f} µs per step incl. outputs"),
        figure("elastic (s30) error vs 10× finer step", err, "", "≤ 1e-3", err <= 1e-3, None,
               "max deviation of nut position and carrier speed, relative to their range"),
    ]


def main(argv: list[str] | None = None) -> int:
    return area_main("elastic", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
