"""Benchmark of the `elastic` level: simulated seconds per wall second at a 1 ms output step.

Batch path (`Simulator.run`) and per-step path (`Simulator.step`, the node's), `s30` under a
5 kN load with a torque that reverses (backlash-free chain, so the run is about stepping cost),
each beside its floor (≥ 100× batch, goal ≥ 300×; ≥ 20× per step), with the compiled
kernel (the default) and, side by side on the head of the same run, the pure-Python reference path.
The accuracy figure is the run's deviation from the same equations at a 10× finer output step
(inputs held per 1 ms), relative to the reference's range, on the nut position and the carrier speed. Nothing here
asserts a timing; `prsm-bench --only elastic` prints the figures.

Self-contained on purpose (the figure helpers are `prsm_ros.bench.core`'s).
"""

from __future__ import annotations

import math

import numpy as np

from prsm_sim import Simulator, preset
from prsm_ros.bench.common import area_main, figure
from prsm_ros.bench.core import DT, relative_error, timed


def measure(quick: bool = False) -> list[dict]:
    p = preset("s30")
    sim_s = 0.3 if quick else 2.0
    n = int(sim_s / DT)
    t = DT * np.arange(n)
    ramp = np.clip(t / 0.05, 0, 1)
    # around the 5 kN holding torque: reversals (4.3 N·m drifted the nut onto the upper thread end in 2 s)
    torque = ramp * (4.0 + 3.0 * np.sin(2 * math.pi * 2.0 * t))
    load = 5000.0 * ramp
    repeats = 2 if quick else 3
    sim = Simulator(p, "elastic", DT)  # the compiled kernel (default)
    sim_ref = Simulator(p, "elastic", DT, kernel="reference")  # its pure-Python specification
    n_ref = min(n, 300)  # the reference is ~100× slower: a shorter head of the same run

    def batch():
        sim.reset()
        return sim.run(torque, load)

    def steps():
        sim.reset()
        for tau, f in zip(torque.tolist(), load.tolist()):
            sim.step(tau, f)

    def batch_ref():
        sim_ref.reset()
        return sim_ref.run(torque[:n_ref], load[:n_ref])

    def steps_ref():
        sim_ref.reset()
        for tau, f in zip(torque[:n_ref].tolist(), load[:n_ref].tolist()):
            sim_ref.step(tau, f)

    fine = 10
    ref = Simulator(p, "elastic", DT / fine).run(np.repeat(torque, fine), np.repeat(load, fine))
    wall_b, spread_b, tr = timed(batch, repeats)
    wall_s, spread_s, _ = timed(steps, repeats)
    wall_rb, spread_rb, tr_ref = timed(batch_ref, 1)
    wall_rs, spread_rs, _ = timed(steps_ref, 1)
    same = max(relative_error(tr[k][:n_ref], tr_ref[k]) for k in ("nut_position_m", "carrier_speed_rad_s", "nut_force_n"))
    rt_rb, rt_rs = n_ref * DT / wall_rb, n_ref * DT / wall_rs
    err = max(relative_error(tr["nut_position_m"], ref["nut_position_m"][fine - 1::fine]),
              relative_error(tr["carrier_speed_rad_s"], ref["carrier_speed_rad_s"][fine - 1::fine]))
    rt_b, rt_s = sim_s / wall_b, sim_s / wall_s
    note = (f"{sim.model.substeps} sub-steps per 1 ms (axial mode ~580 Hz); compiled kernel (fu2018 core "
            f"included); goal ≥ 300; error vs 10× finer step: {err:.1e}")
    return [
        figure("elastic (s30) batch simulated s per wall s", rt_b, "×", "≥ 100", rt_b >= 100 and err <= 1e-3,
               spread_b, f"{wall_b / n * 1e6:.1f} µs per step; " + note),
        figure("elastic (s30) per-step path (Simulator.step) simulated s per wall s", rt_s, "×", "≥ 20", rt_s >= 20,
               spread_s, f"{wall_s / n * 1e6:.0f} µs per step incl. outputs (compiled kernel)"),
        figure("elastic (s30) reference path (pure Python) batch simulated s per wall s", rt_rb, "×", "(peer)",
               same <= 1e-12, spread_rb, f"first {n_ref} steps of the same run; compiled {rt_b / rt_rb:.0f}× faster, "
               f"results within {same:.1e} of it (relative to range)"),
        figure("elastic (s30) reference path (pure Python) per-step simulated s per wall s", rt_rs, "×", "(peer)",
               None, spread_rs, f"compiled {rt_s / rt_rs:.0f}× faster"),
        figure("elastic (s30) error vs 10× finer step", err, "", "≤ 1e-3", err <= 1e-3, None,
               "max deviation of nut position and carrier speed, relative to their range"),
    ]


def main(argv: list[str] | None = None) -> int:
    return area_main("elastic", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
