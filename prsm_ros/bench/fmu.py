"""Benchmark of the FMU: one step through fmpy beside the library's `Session.step`, in the same run.

s30 with fu2018 (the bare screw, effort input), built as an FMI 2.0 (pythonfmu) and an FMI 3.0
(pythonfmu3) FMU. Per model step: `Session.step` (the library object the FMU wraps), `doStep`
alone (inputs held) and a full exchange (set the two inputs, doStep, get every output), each run
interleaved with the library's loop on the same inputs, repeated; the ratios to the library step
are medians with their spread. `Simulator.step` (no command gate, no session checks) is a peer. Aim: doStep within 3× of the library step; the full exchange adds fmpy's own
per-call cost (ctypes and the Python FMI wrapper on the importer's side), which sets its floor.
Nothing here asserts a timing; `prsm-bench --only fmu` prints the figures.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from prsm_sim import Simulator, preset

from prsm_ros.bench.common import area_main, figure

DT = 1e-3
# ±TORQUE_NM in blocks of BLOCK steps (the first half a block) and no load: the screw reverses about its start
# and the nut stays on its threads (a constant torque carried it onto a thread end within 0.4 s, and the
# figures were the end's contact); the inputs change once a block, so doStep is still timed nearly alone
TORQUE_NM, LOAD_N, BLOCK = 1.0, 0.0, 100


def torque_at(k: int) -> float:
    return TORQUE_NM if ((k + BLOCK // 2) // BLOCK) % 2 == 0 else -TORQUE_NM


def _ratio_stats(ours: list[float], lib: list[float]) -> tuple[float, float]:
    ratios = [a / b for a, b in zip(ours, lib)]
    med = statistics.median(ratios)
    return med, (max(ratios) - min(ratios)) / med if med > 0 else 0.0


def measure(quick: bool = False) -> list[dict]:
    from prsm_ros.fmu.build import build_fmu  # pythonfmu, pythonfmu3 and fmpy: the `fmu` extra
    from prsm_ros.fmu.config import make_config, session_from_config
    from prsm_ros.fmu.driver import FmuDriver

    n = 1000 if quick else 5000
    repeats = 3 if quick else 7
    figures = []
    with tempfile.TemporaryDirectory(prefix="prsm_bench_fmu_") as tmp:
        for fmi in (2, 3):
            config = make_config(preset("s30"), "fu2018", DT, None, interface="effort", load_n=LOAD_N, fmi=fmi)
            path = build_fmu(config, Path(tmp) / f"fu2018_fmi{fmi}.fmu")
            session = session_from_config(config)
            with FmuDriver(path) as drv:
                inputs = drv.refs(["screw_torque_nm", "load_force_n"])
                outputs = drv.refs([v.name for v in drv.description.modelVariables if v.causality == "output"])
                do_step, set_, get = drv.fmu.doStep, drv.set, drv.get

                simulator = Simulator(preset("s30"), "fu2018", DT)

                torques = [torque_at(k) for k in range(n)]
                changes = {k for k in range(n) if k == 0 or torques[k] != torques[k - 1]}

                def library():
                    step = session.step
                    for t in torques:
                        step(t, LOAD_N)

                def bare_library():
                    step = simulator.step
                    for t in torques:
                        step(t, LOAD_N)

                def steps_alone():
                    for k in range(n):
                        if k in changes:
                            set_(inputs, [torques[k], LOAD_N])
                        do_step(k * DT, DT)

                def exchange():
                    for k in range(n):
                        set_(inputs, [torques[k], LOAD_N])
                        do_step(k * DT, DT)
                        get(outputs)

                lib_t, alone_t, lib2_t, full_t, sim_t = [], [], [], [], []
                for _ in range(repeats):  # side by side: each FMU run beside a library run from the same state
                    for fn, times, lib_times in ((steps_alone, alone_t, lib_t), (exchange, full_t, lib2_t)):
                        session.reset()
                        drv.reset()
                        t0 = time.perf_counter()
                        library()
                        lib_times.append(time.perf_counter() - t0)
                        t0 = time.perf_counter()
                        fn()
                        times.append(time.perf_counter() - t0)
                    simulator.reset()
                    t0 = time.perf_counter()
                    bare_library()
                    sim_t.append(time.perf_counter() - t0)
            lib_us = statistics.median(lib_t) / n * 1e6
            r_alone, s_alone = _ratio_stats(alone_t, lib_t)
            r_full, s_full = _ratio_stats(full_t, lib2_t)
            r_sim, s_sim = _ratio_stats(alone_t, sim_t)
            tag = f"FMI {fmi}.0 ({'pythonfmu' if fmi == 2 else 'pythonfmu3'})"
            figures += [
                figure(f"fmu {tag} fu2018 (s30) doStep / Session.step", r_alone, "×", "≤ 3", r_alone <= 3,
                       s_alone, f"{statistics.median(alone_t) / n * 1e6:.1f} µs per doStep through fmpy vs "
                                f"{lib_us:.1f} µs per Session.step, one model step each"),
                figure(f"fmu {tag} fu2018 (s30) doStep / Simulator.step", r_sim, "×", "(peer)", None, s_sim,
                       f"{statistics.median(sim_t) / n * 1e6:.1f} µs per Simulator.step (no command gate, no "
                       f"session checks): the FMU's slave is a Session"),
                figure(f"fmu {tag} fu2018 (s30) full exchange / Session.step", r_full, "×", "(fmpy floor)", None,
                       s_full, f"{statistics.median(full_t) / n * 1e6:.1f} µs per set 2 inputs + doStep + get "
                               f"{len(outputs)} outputs through fmpy; fmpy's per-call cost sets the floor"),
            ]
    return figures


def main(argv: list[str] | None = None) -> int:
    return area_main("fmu", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
