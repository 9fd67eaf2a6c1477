"""Benchmarks of the dynamics core: simulated seconds per wall second at a 1 ms output step.

Each figure is measured at a checked accuracy: the run's nut position and carrier speed
must stay within 0.1 % (of their range) of a tight reference solution of the same
equations. Figures are medians of repeated runs with their spread (max − min) / median.
Nothing here asserts a timing; `prsm-bench` prints the figures beside their targets.
"""

from __future__ import annotations

import math
import statistics
import time

import numpy as np
from scipy.integrate import solve_ivp

from prsm_sim import Simulator, preset
from prsm_sim.models.jones2016 import Jones2016, input_matrix, steady_state

from prsm_ros.bench.common import area_main, figure

DT = 1e-3


def timed(fn, repeats: int):
    """fn() run `repeats` times: median wall time (s), spread (max − min) / median, the last result."""
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    return med, (max(times) - min(times)) / med if med > 0 else 0.0, result


def relative_error(x: np.ndarray, ref: np.ndarray) -> float:
    """Max deviation relative to the reference's range."""
    scale = float(np.max(np.abs(ref))) or 1.0
    return float(np.max(np.abs(x - ref))) / scale


def jones2016_figures(quick: bool = False) -> list[dict]:
    """jones2016 batch speed, the straightforward solve_ivp baseline, and their ratio (side by side)."""
    p = preset("jones2016")
    sim_s = 2.0 if quick else 20.0
    n = int(sim_s / DT)
    tau = steady_state(p)["torque_nm"]
    torque = tau * (1.0 + 0.5 * np.sin(2 * math.pi * 0.5 * DT * np.arange(n)))  # held over each step
    load = p.loads.nut_load_n
    repeats = 3 if quick else 7
    model = Jones2016(p, DT)
    Minv = np.linalg.inv(model.M)
    B = input_matrix(p)

    sim = Simulator(p, "jones2016", DT)  # built once: the figure is about stepping, not set-up

    def ours():
        sim.reset()
        return sim.run(torque, load)

    def rhs(t, x):
        k = min(int(t / DT), n - 1)
        return np.concatenate([x[2:], Minv @ (-model.C @ x[2:] + B @ (torque[k], load))])

    t_eval = DT * np.arange(1, n + 1)

    def baseline(rtol=1e-4):
        # the straightforward way: one stiff solve over the run, inputs read from the step table
        return solve_ivp(rhs, (0.0, sim_s), np.zeros(4), method="Radau", t_eval=t_eval, rtol=rtol, atol=1e-10,
                         max_step=DT)

    ref = np.zeros((4, n))
    x = np.zeros(4)
    for k in range(n):  # tight reference: Radau per held interval at rtol 1e-10
        if quick and k > 500:
            break
        x = solve_ivp(rhs, (k * DT, (k + 1) * DT), x, method="Radau", rtol=1e-10, atol=1e-14).y[:, -1]
        ref[:, k] = x
    m = 501 if quick else n
    ours_s, ours_spread, tr = timed(ours, repeats)
    base_s, base_spread, sol = timed(baseline, max(1, repeats // 2))
    p_lead = p.geometry.lead_per_rad_m
    err_ours = max(relative_error(tr["nut_position_m"][:m], p_lead * ref[0, :m]),
                   relative_error(tr["carrier_speed_rad_s"][:m], ref[3, :m]))
    err_base = max(relative_error(p_lead * sol.y[0, :m], p_lead * ref[0, :m]), relative_error(sol.y[3, :m], ref[3, :m]))
    rt_ours, rt_base = sim_s / ours_s, sim_s / base_s
    return [
        figure("jones2016 simulated s per wall s (1 ms step)", rt_ours, "×", "≥ 1000", rt_ours >= 1000 and err_ours <= 1e-3,
               ours_spread, f"error vs Radau rtol 1e-10: {err_ours:.1e}; exact ZOH step, batch by recursive filters"),
        figure("solve_ivp (Radau, same equations) simulated s per wall s", rt_base, "×", "(baseline)", err_base <= 1e-3,
               base_spread, f"error {err_base:.1e}"),
        figure("jones2016 speed-up over solve_ivp", rt_ours / rt_base, "×", "≥ 20", rt_ours / rt_base >= 20, None,
               "same run, side by side"),
    ]


def fu2018_figures(quick: bool = False) -> list[dict]:
    """fu2018 (10 rollers × 40 teeth) batch speed at checked accuracy, and step cost versus tooth count."""
    p = preset("jones2016")  # 10 rollers × 40 teeth
    sim_s = 0.5 if quick else 3.0
    n = int(sim_s / DT)
    torque = 0.3 * np.sin(2 * math.pi * 1.0 * DT * np.arange(n)) + 0.1  # motion with reversals
    load = 100.0
    repeats = 2 if quick else 5

    sim = Simulator(p, "fu2018", DT)  # the compiled kernel (default)
    sim_ref = Simulator(p, "fu2018", DT, kernel="reference")  # its pure-Python specification, same run

    def ours():
        sim.reset()
        return sim.run(torque, load)

    def reference():
        sim_ref.reset()
        return sim_ref.run(torque, load)

    fine = 20  # reference: the same equations at a 20× finer step, sampled at the output step
    ref = Simulator(p, "fu2018", DT / fine).run(np.repeat(torque, fine), load)
    wall, spread, tr = timed(ours, repeats)
    wall_ref, spread_ref, tr_ref = timed(reference, max(1, repeats // 2))
    same = max(relative_error(tr[k], tr_ref[k]) for k in ("nut_position_m", "carrier_speed_rad_s", "nut_force_n"))
    err = max(relative_error(tr["nut_position_m"], ref["nut_position_m"][fine - 1::fine]),
              relative_error(tr["carrier_speed_rad_s"], ref["carrier_speed_rad_s"][fine - 1::fine]))
    rt = sim_s / wall
    cost, batch = {}, {}
    head = torque[:1000]
    for teeth in (10, 100):
        s_t = Simulator(p.with_overrides({"geometry.n_teeth": teeth}), "fu2018", DT)

        def step_teeth(s_t=s_t):
            s_t.reset()
            for t in head.tolist():
                s_t.step(t, load)  # each step returns the full labelled vector, per-tooth loads included

        def batch_teeth(s_t=s_t):
            s_t.reset()
            return s_t.run(head, load).internal  # materialise every step's per-tooth loads

        cost[teeth] = timed(step_teeth, repeats)[0] / len(head)
        batch[teeth] = timed(batch_teeth, repeats)[0] / len(head)
    ratio = cost[100] / cost[10]
    rev = _fu2018_reversal_case(quick, repeats)
    rt_ref = sim_s / wall_ref
    return [
        figure("fu2018 (10 rollers × 40 teeth) simulated s per wall s", rt, "×", "≥ 1000",
               rt >= 1000 and err <= 1e-3, spread, f"error vs 20× finer step: {err:.1e}; {wall / n * 1e6:.2f} µs per step (compiled kernel); "
               "per-tooth array built on first read"),
        figure("fu2018 reference path (pure Python, same run) simulated s per wall s", rt_ref, "×", "(peer)",
               same <= 1e-12, spread_ref,
               f"{wall_ref / n * 1e6:.1f} µs per step; compiled {rt / rt_ref:.0f}× faster, "
               f"results within {same:.1e} of it (relative to range)"),
        figure("fu2018 step cost 100 teeth / 10 teeth", ratio, "", "≤ 1.2", ratio <= 1.2, None,
               f"Simulator.step: {cost[10] * 1e6:.1f} vs {cost[100] * 1e6:.1f} µs; batch run with every step's "
               f"per-tooth array materialised: {batch[10] * 1e6:.1f} vs {batch[100] * 1e6:.1f} µs"),
        *rev,
    ]


def _fu2018_reversal_case(quick: bool, repeats: int) -> list[dict]:
    """s30 at 20 kN, τ = F·L/2π + 8 sin(2π 3t): stick, break-away and reversals, where fu2018 sub-steps
    (at 1 Hz the same torque drove the nut onto both thread ends).

    Accuracy against the same model at a 10 µs step with the same held input; cost per step on
    the node's path (`Simulator.step`) and in batch (`Simulator.run`).
    """
    p = preset("s30")
    load = 20_000.0
    sim_s = 0.3 if quick else 1.0
    n = int(round(sim_s / DT))
    torque = load * p.geometry.lead_per_rad_m + 8.0 * np.sin(2 * math.pi * 3.0 * DT * np.arange(n))
    sim = Simulator(p, "fu2018", DT)

    def batch():
        sim.reset()
        return sim.run(torque, load)

    def steps():
        sim.reset()
        for t in torque.tolist():
            sim.step(t, load)

    fine = 100
    ref = Simulator(p, "fu2018", DT / fine).run(np.repeat(torque, fine), load)["screw_speed_rad_s"][fine - 1::fine]
    wall_b, spread_b, tr = timed(batch, repeats)
    wall_s, spread_s, _ = timed(steps, repeats)
    w = tr["screw_speed_rad_s"]
    err = float(np.max(np.abs(w - ref)))
    peak = float(np.max(np.abs(ref))) or 1.0
    slow = np.abs(ref) < 1.0
    err_slow = float(np.max(np.abs(w - ref)[slow])) if slow.any() else 0.0
    ok = err <= 1e-3 * peak and err_slow <= 0.5
    return [
        figure("fu2018 s30 20 kN stick/reversal case: simulated s per wall s (batch)", sim_s / wall_b, "×", "(info)",
               ok, spread_b, f"{wall_b / n * 1e6:.1f} µs per step; error vs 10 µs step {err:.2g} rad/s "
               f"({err / peak:.1e} of the {peak:.0f} rad/s peak), {err_slow:.2g} rad/s where it turns < 1 rad/s; "
               f"{int(np.sum(w == 0.0))} of {n} steps stuck"),
        figure("fu2018 s30 20 kN stick/reversal case: per-step path (Simulator.step)", sim_s / wall_s, "×", "(info)",
               ok, spread_s, f"{wall_s / n * 1e6:.1f} µs per step incl. outputs"),
    ]


def step_path_figures(quick: bool = False) -> list[dict]:
    """Cost of one `Simulator.step` per model: the path the node takes at every tick (1 kHz budget 1000 µs)."""
    out = []
    n = 500 if quick else 5000
    for model, name in (("ideal", "s30"), ("jones2016", "jones2016"), ("fu2018", "jones2016")):
        sim = Simulator(preset(name), model, DT)
        torque = 0.2 * np.cos(np.arange(n) * 0.01)  # reversals about the start: the nut stays on its threads

        def steps(sim=sim, torque=torque):
            sim.reset()
            for t in torque.tolist():
                sim.step(t, 0.0)

        wall, spread, _ = timed(steps, 3)
        rt = n * DT / wall
        out.append(figure(f"{model} per-step path (Simulator.step) simulated s per wall s", rt, "×", "(info)", True,
                          spread, f"{wall / n * 1e6:.1f} µs per step incl. outputs"))
    return out


def measure(quick: bool = False) -> list[dict]:
    return jones2016_figures(quick) + fu2018_figures(quick) + step_path_figures(quick)


def main(argv: list[str] | None = None) -> int:
    return area_main("core", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
