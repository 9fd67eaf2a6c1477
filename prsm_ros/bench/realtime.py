"""Benchmarks of the realtime loop a controller sees, and the step cost beside MuJoCo's.

    prsm-bench --only realtime [--quick]        # or: python -m prsm_ros.bench.realtime

- Loop: `prsm-node` at its defaults (jones2016, s30, realtime at 1 kHz, recording on, in a
  temporary directory) and the reference controller (`prsm_ros.bench.rt_controller`: rclpy, its
  own process, a distinct torque every 1 ms at normal priority, a reliable state reader) over DDS,
  once on the machine as it is ("unloaded") and once with one busy process per core at normal
  priority ("loaded"). Figures: command-to-state latency p50/p99 (the command's DDS stamp echoed
  on `~/command_echo` to the receipt of the first state of the step that applied it; when the
  node has no echo, the controller's own publish time to the first state carrying that torque),
  states delivered to the reliable reader, the long-run rate error as the reader sees it, and
  the node process's CPU (all its threads) over the measured window, beside the rclpy floor's
  (`rclpy_floor`: two node and floor pairs alternated, `cpu_pairs`) and beside the same floor writing
  what the node records with a native MCAP writer (`rclpy_floor --record`); the same three with the
  step thread (the floor's loop) on a CPU of its own and the rest, the controller included, on the
  others (`step_thread_cpu`, `pinned_cpu_figures`); then the node's CPU with each other model
  (unloaded, shorter runs), since the CPU target holds for every model.
- Step cost: one `Simulator.step` per model, and the same through `Session.step` (gate, load,
  finiteness check: the path the node calls each tick), in the same Python loop form as MuJoCo's `mj_step` on the rigid screw–nut (`mujoco` from the `bench`
  extra): one slide joint for the nut, the rotating inertia reflected as armature, which is
  exact for a rigid lead (a hinge and a slide tied by an equality constraint is a stiff
  spring, ~20,000× too soft at a 1 ms step). Batch `Simulator.run` in simulated s per wall s.
  Each model's `Simulator.step` with the nut held on a thread end (`held_end_figures`), beside its
  free step: what a controller pressing into an end costs each period.
  All paths are timed in interleaved rounds in one run, in this thread's CPU time (wall time on a
  shared machine also counts the other processes' turns); medians with spread.

The machine's load at the time of the run enters every figure: the lead's figures come from a
quiet machine. Nothing here asserts a timing.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from prsm_sim import MODELS, Session, Simulator, preset
from prsm_sim.physics.inertia import reflected_inertia

from prsm_ros.bench.common import BenchError, area_main, figure, tree_cpu_s
from prsm_ros.node.parameters import DEFAULT_MODEL
from prsm_ros.ros_env import isolated_env, start_module

DT = 1e-3
TORQUE_AMPLITUDE_NM = 0.4  # the step-cost and batch workloads: a turning screw (s30 needs 0.22 N·m unloaded)
PRESET = "s30"  # the node's default preset
HOLD_TORQUE_NM = 2.0  # `held_end_figures`: drives s30's nut onto its upper thread end (~0.5 s unloaded) and holds it
HOLD_STEPS_TO_END = 1500  # steps at that torque before the held steps are timed (it rests on the end by ~500)


# -- the loop, node and controller over DDS ------------------------------------------------------
def start_hogs() -> list[subprocess.Popen]:
    """One busy Python process per core, normal priority (the issue's "loaded" condition)."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 1)]


def stop_procs(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        if p.poll() is None:
            p.kill()
    for p in procs:
        p.wait(timeout=10)


NODE_MODULE = "prsm_ros.cli.node"
FLOOR_MODULE = "prsm_ros.bench.rclpy_floor"  # the node's DDS traffic and nothing else (its module doc)


def loop_run(seconds: float, *, loaded: bool, node_params: dict | None = None, module: str = NODE_MODULE,
             module_args: tuple[str, ...] = (), step_thread_cpu: int = -1) -> dict:
    """The node (or `module` in its place, given `module_args`) at its defaults and the reference controller;
    the controller's summary plus the node process's CPU. `step_thread_cpu` >= 0: the node's step thread (the
    floor's loop) on that CPU, its other threads and the controller on the others (`step_thread_cpu`)."""
    from prsm_ros.node.scheduling import other_cpus
    from prsm_ros.ros_env import ros_args
    env = isolated_env(respect_user=False, RERUN="off")
    ctl_args = ["--duration", repr(seconds)]
    if step_thread_cpu >= 0:
        if module == NODE_MODULE:
            node_params = {**(node_params or {}), "step_thread_cpu": step_thread_cpu}
        else:
            module_args = (*module_args, "--step-thread-cpu", str(step_thread_cpu))
        ctl_args += ["--cpus", ",".join(map(str, sorted(other_cpus(step_thread_cpu))))]
    hogs = start_hogs() if loaded else []
    try:
        with tempfile.TemporaryDirectory(prefix="prsm_bench_rt_") as tmp:
            with open(Path(tmp) / "node.log", "wb") as log:
                args = (ros_args(node_params) if node_params else []) + list(module_args)
                node = start_module(module, args, env, cwd=tmp, stdout=log,
                                    stderr=subprocess.STDOUT)
                try:
                    ctl = start_module("prsm_ros.bench.rt_controller", ctl_args, env,
                                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
                    # a hung controller is killed, which ends the reads below
                    watchdog = threading.Timer(180 + 3 * seconds, ctl.kill)
                    watchdog.start()
                    lines, cpu = [], {}
                    try:
                        for raw in ctl.stdout:  # the node's CPU over the measured window only (no start-up)
                            line = raw.decode(errors="replace").strip()
                            lines.append(line)
                            if line in ("measuring", "measured"):
                                cpu[line] = (tree_cpu_s(node.pid), time.perf_counter())  # with its MCAP writer
                        ctl.wait(timeout=30)
                    finally:
                        watchdog.cancel()
                finally:
                    node.send_signal(2)
                    try:
                        node.wait(timeout=30)
                    except subprocess.TimeoutExpired:
                        node.kill()
                        node.wait()
            bags = sorted(p.name for p in Path(tmp).glob("*.mcap"))
            log_text = (Path(tmp) / "node.log").read_text(errors="replace")
    finally:
        stop_procs(hogs)
    try:
        summary = json.loads(lines[-1])
    except (IndexError, json.JSONDecodeError):
        raise BenchError("controller printed no summary: " + " | ".join(lines[-5:]) + " | node: "
                           + log_text[-500:]) from None
    if "error" in summary:
        raise BenchError(f"controller: {summary['error']}; node log: {log_text[-500:]}")
    (c0, w0), (c1, w1) = cpu["measuring"], cpu["measured"]
    summary["node_cpu_pct"] = 100 * (c1 - c0) / (w1 - w0)
    summary["bags"] = bags
    return summary


def loop_figures(quick: bool) -> list[dict]:
    seconds = 5.0 if quick else 30.0
    figs = []
    # the floors run right after the unloaded node, and a second node and floors after that, so each node run
    # has its floors beside it on the same machine (the ratios are the figures: `cpu_pairs`)
    floor: list[dict] | None = None
    pairs: list[tuple[float, float, float]] = []
    for loaded in (False, True):
        cond = "loaded" if loaded else "unloaded"
        try:
            s = loop_run(seconds, loaded=loaded)
        except Exception as e:  # one failed condition must not hide the other's figures
            figs.append(figure(f"realtime loop ({cond})", math.nan, "", "", False, None, f"{type(e).__name__}: {e}"))
            continue
        echo = s["echo_seen"] and s["latency_echo_ms"]["n"] > 0
        lat = s["latency_echo_ms"] if echo else s["latency_value_ms"]
        how = ("command's DDS stamp echoed on ~/command_echo → receipt of that step's joint_states"
               if echo else "no ~/command_echo from the node: controller's publish time → first "
               "joint_states carrying that torque")
        other = s["latency_value_ms"]
        base = (f"jones2016, s30, node defaults (realtime 1 kHz, recording on); controller 1 kHz normal priority; "
                f"{seconds:g} s" + (f"; one busy process per core ({os.cpu_count()})" if loaded else ""))
        p99_target = 3.0 if loaded else 2.0
        figs.append(figure(f"command→state latency p50 ({cond})", lat["p50"], "ms", "≤ 1.2" if not loaded else "(info)",
                           (lat["p50"] is not None and lat["p50"] <= 1.2) if not loaded else None, None,
                           f"{how}; n = {lat['n']}; {base}"))
        cross = (f"; cross-check, publish → first state carrying the torque: p50 {other['p50']:.2f}, "
                 f"p99 {other['p99']:.2f} ms (n = {other['n']})" if echo and other["n"] else "")
        figs.append(figure(f"command→state latency p99 ({cond})", lat["p99"], "ms", f"≤ {p99_target:g}",
                           lat["p99"] is not None and lat["p99"] <= p99_target, None,
                           (f"max {lat['max']:.2f} ms" if lat["max"] is not None else "no samples") + cross))
        delivered = 100 * s["states_received"] / s["states_expected"] if s["states_expected"] else math.nan
        figs.append(figure(f"states delivered to a reliable reader ({cond})", delivered, "%", "≥ 99.9",
                           delivered >= 99.9, None,
                           f"{s['states_received']} distinct joint_states of {s['states_expected']} steps "
                           f"between the first and last received; reader depth 1000"))
        if s["rate_hz"] is not None and s["period_s"]:
            err = abs(100 * (s["rate_hz"] * s["period_s"] - 1))
            figs.append(figure(f"long-run rate error ({cond})", err, "%", "< 0.1", err < 0.1, None,
                               f"slope of state stamps over receipt wall time: {s['rate_hz']:.3f} Hz"))
        if not loaded:
            floor, pairs = cpu_pairs(s["node_cpu_pct"], seconds)
        figs.append(node_cpu_figure(cond, loaded, s["node_cpu_pct"], pairs))
        if not loaded:
            figs.append(recording_ratio_figure(pairs))
    figs.extend(floor if floor is not None else [floor_figure([], seconds), floor_figure([], seconds, recorded=True)])
    figs.extend(pinned_cpu_figures(seconds / 2))
    figs.extend(model_cpu_figures(quick))
    return figs


def pinned_cpu_figures(seconds: float, sets: int = 3) -> list[dict]:
    """The node's CPU with its step thread on a CPU of its own (`step_thread_cpu`: the machine's last CPU, the
    node's other threads and the controller on the rest), beside both floors run the same way: `sets` sets of a
    node run, the floor and the recording floor, alternated (`cpu_pairs`' reason), unloaded. The figures are the
    medians over the sets (of the node's CPU, and of each set's ratios): one set caught by a burst of the host's
    load moves them less than a mean (two sets of one run on 1 December: 17.1 % and 13.1 % for the node)."""
    from prsm_ros.node.scheduling import allowed_cpus
    names = ("node CPU share of one core, step thread on a CPU of its own (unloaded)",
             "node CPU over the rclpy floor, both with the loop on a CPU of its own (unloaded)",
             "node CPU over the rclpy floor with native recording, both with the loop on a CPU of its own (unloaded)")
    cpus = sorted(allowed_cpus())
    if len(cpus) < 2:
        why = f"not measured: this process may run on {len(cpus) or 'an unknown number of'} CPU(s), and a CPU of " \
              "its own for the step thread needs another for the rest"
        return [figure(n, math.nan, u, t, None, None, why) for n, u, t in zip(names, ("%", "×", "×"),
                                                                                ("≤ 15", "≤ 1.5", "≤ 1.5"))]
    cpu = cpus[-1]
    runs: list[tuple[float, float, float]] = []
    errors = []
    for _ in range(sets):
        try:
            n = loop_run(seconds, loaded=False, step_thread_cpu=cpu)["node_cpu_pct"]
            f = loop_run(seconds, loaded=False, module=FLOOR_MODULE, step_thread_cpu=cpu)["node_cpu_pct"]
            r = loop_run(seconds, loaded=False, module=FLOOR_MODULE, module_args=("--record",),
                         step_thread_cpu=cpu)["node_cpu_pct"]
        except Exception as e:  # a failed set is left out; the notes say so
            errors.append(f"{type(e).__name__}: {e}")
            continue
        runs.append((n, f, r))
    failed = f"; failed: {'; '.join(errors)}" if errors else ""
    if not runs:
        return [figure(n, math.nan, u, t, False, None, "not measured" + failed)
                for n, u, t in zip(names, ("%", "×", "×"), ("≤ 15", "≤ 1.5", "≤ 1.5"))]
    how = (f"prsm-node -p step_thread_cpu:={cpu} (its other threads and the controller on "
           f"{', '.join(map(str, cpus[:-1]))}); the floors with --step-thread-cpu {cpu}; {seconds:g} s each, "
           f"{len(runs)} sets alternated: " + "; ".join(f"node {n:.1f} %, floor {f:.1f} %, recording floor {r:.1f} %"
                                                       for n, f, r in runs) + failed)
    cpu_pct = statistics.median(n for n, _, _ in runs)
    bare = statistics.median(n / f for n, f, _ in runs if f > 0)
    rec = statistics.median(n / r for n, _, r in runs if r > 0)
    return [figure(names[0], cpu_pct, "%", "≤ 15", cpu_pct <= 15, None, "the median of the sets; " + how),
            figure(names[1], bare, "×", "≤ 1.5", bare <= 1.5, None, "the median of the sets' ratios; " + how),
            figure(names[2], rec, "×", "≤ 1.5", rec <= 1.5, None, "the median of the sets' ratios; " + how)]


def node_cpu_figure(cond: str, loaded: bool, node_cpu_pct: float, pairs: list[tuple[float, float, float]]) -> dict:
    """The node's CPU figure for condition `cond`: unloaded, the mean of the node runs of `pairs` (node %, floor %,
    recording floor %) and of their ratios to the floor beside each; loaded, this run's `node_cpu_pct` over the
    pairs' mean floor."""
    what = ("all threads of the node process (step loop, executor, middleware, recorder) and its MCAP writer "
            "process over the measured window")
    if not loaded:
        cpu = statistics.fmean(n for n, _, _ in pairs) if pairs else node_cpu_pct
        ratios = [n / f if f > 0 else math.nan for n, f, _ in pairs]
        ratio = statistics.fmean(ratios) if ratios else math.nan
        how = (f"; the mean of {len(pairs)} runs alternated with the rclpy floor ("
               + ", ".join(f"{n:.1f} % = {r:.2f}× its floor's {f:.1f} %" for (n, f, _), r in zip(pairs, ratios))
               + f"): {ratio:.2f}× the floor (aim ≤ 1.5×)")
    else:
        cpu = node_cpu_pct
        mean_floor = statistics.fmean(f for _, f, _ in pairs) if pairs else math.nan
        ratio = cpu / mean_floor if mean_floor > 0 else math.nan
        how = f"; {ratio:.2f}× the unloaded rclpy floor of this run, {mean_floor:.1f} % (aim ≤ 1.5×)"
    return figure(f"node CPU share of one core ({cond})", cpu, "%", "≤ 15", cpu <= 15, None, what + how)


def recording_ratio_figure(pairs: list[tuple[float, float, float]]) -> dict:
    """The unloaded node's CPU over the floor that also records (`rclpy_floor --record`), the mean of the ratios of
    the runs of `pairs` side by side."""
    name = "node CPU over the rclpy floor with native recording (unloaded)"
    ratios = [n / r for n, _, r in pairs if r > 0]
    if not ratios:
        return figure(name, math.nan, "×", "≤ 1.5", None, None, "no recording floor measured")
    ratio = statistics.fmean(ratios)
    return figure(name, ratio, "×", "≤ 1.5", ratio <= 1.5, None,
                  "the node records every message it takes and publishes; the floor under that is the rclpy floor "
                  "writing the same messages with a native writer in its loop: "
                  + ", ".join(f"{n:.1f} % over {r:.1f} %" for n, _, r in pairs))


def cpu_pairs(node_cpu_pct: float, seconds: float) -> tuple[list[dict], list[tuple[float, float, float]]]:
    """The floors' figures and (node CPU %, floor CPU %, recording floor CPU %) triples: the unloaded node's run given,
    the floor and the recording floor right after, then a second node run and floors (`seconds` / 2 each: CPU only).

    The floor alone moved by 40 % between runs of one bench on a quiet machine (7.1–9.8 % of a core), which a ratio
    to one floor run carries whole. Two sets, each a node run and its floors side by side, halve the variance
    one set's timing puts into the ratios' mean. A set whose run fails is left out (the notes say so).
    """
    runs: dict[bool, list[dict]] = {False: [], True: []}
    pairs, errors = [], []
    node = node_cpu_pct
    for i, secs in enumerate((seconds, seconds / 2)):
        if i:  # the second set's node run
            try:
                node = loop_run(secs, loaded=False)["node_cpu_pct"]
            except Exception as e:
                errors.append(f"node: {type(e).__name__}: {e}")
                break
        try:
            f = loop_run(secs, loaded=False, module=FLOOR_MODULE)
            r = loop_run(secs, loaded=False, module=FLOOR_MODULE, module_args=("--record",))
        except Exception as e:
            errors.append(f"{type(e).__name__}: {e}")
            continue
        runs[False].append(f)
        runs[True].append(r)
        pairs.append((node, f["node_cpu_pct"], r["node_cpu_pct"]))
    return [floor_figure(runs[rec], seconds, errors, recorded=rec) for rec in (False, True)], pairs


def floor_figure(runs: list[dict], seconds: float, errors: list[str] | None = None, *, recorded: bool = False) -> dict:
    """The peer of the node's CPU figure: `rclpy_floor` (the node's realtime DDS traffic, nothing else; with
    `recorded`, the same and the node's recorded messages written by a native MCAP writer) with the same
    controller, unloaded: the mean of `runs` (`loop_run` summaries). The node cannot cost less than this
    with rclpy in Python."""
    name = ("rclpy floor with native recording: CPU of a bare loop with the node's DDS traffic, recording what the "
            "node records (unloaded)" if recorded else
            "rclpy floor: CPU of a bare loop with the node's DDS traffic (unloaded)")
    if not runs:
        return figure(name, math.nan, "%", "(peer)", None, None, "; ".join(errors or ["not run"]))
    cpu = [r["node_cpu_pct"] for r in runs]
    delivered = ", ".join(f"{100 * r['states_received'] / max(r['states_expected'], 1):.2f} %" for r in runs)
    what = ("python -m prsm_ros.bench.rclpy_floor --record: the floor below, and each period the commands taken, "
            "joint_states, the echo and a jones2016 step's wrench, internal loads and /clock written by foxglove-sdk's "
            "MCAP writer (native), its chunk finished every 50 ms" if recorded else
            "python -m prsm_ros.bench.rclpy_floor: paced at 1 kHz, takes ~/screw_torque, publishes "
            "joint_states and ~/command_echo (reliable) with the node's encoder; no model, no recording, "
            "no other topic")
    return figure(name, statistics.fmean(cpu), "%", "(peer)", None, None,
                  f"{what}; with the reference controller; the mean of {len(runs)} runs alternated with the "
                  f"node's ({', '.join(f'{c:.1f}' for c in cpu)} %; {seconds:g} s, then {seconds / 2:g} s); "
                  f"states delivered {delivered}" + (f"; failed: {'; '.join(errors)}" if errors else ""))


def model_cpu_figures(quick: bool) -> list[dict]:
    """Node CPU with each other model (the target holds for every model), unloaded, with the controller."""
    seconds = 3.0 if quick else 10.0
    figs = []
    for model in MODELS:
        if model == DEFAULT_MODEL:  # the node's default: measured above
            continue
        try:
            s = loop_run(seconds, loaded=False, node_params={"model": model})
        except Exception as e:
            figs.append(figure(f"node CPU share of one core ({model})", math.nan, "%", "≤ 15", False, None,
                               f"{type(e).__name__}: {e}"))
            continue
        delivered = 100 * s["states_received"] / s["states_expected"] if s["states_expected"] else math.nan
        figs.append(figure(f"node CPU share of one core ({model}, unloaded)", s["node_cpu_pct"], "%", "≤ 15",
                           s["node_cpu_pct"] <= 15, None,
                           f"node defaults but model {model}; controller at 1 kHz; {seconds:g} s; states delivered "
                           f"{delivered:.2f} %"))
    return figs


# -- step cost beside MuJoCo ----------------------------------------------------------------------
def mujoco_screw_nut(params, dt_s: float = DT):
    """The rigid screw–nut in MuJoCo: one slide joint (nut position, m), screw inertia as armature.

    x = (L/2π) θ_S exactly, so the kinetic energy ½ J θ̇² + ½ m ẋ² is ½ (m + J/(L/2π)²) ẋ²:
    the reflected inertia (`ideal.reflected_inertia`, which already holds the moved mass) is the
    slide's total inertia, split into the body mass and the armature. A screw torque τ is the
    axial force τ / (L/2π) (motor gear 1/(L/2π)). Returns (model, data, total inertia kg).
    """
    import mujoco
    p = params.geometry.lead_per_rad_m
    m_total = reflected_inertia(params) / p**2
    m_body = params.mass.moved_mass_kg
    xml = f"""
<mujoco model="prsm_rigid_screw_nut">
  <option timestep="{dt_s!r}" gravity="0 0 0"/>
  <worldbody>
    <body name="nut">
      <joint name="nut_slide" type="slide" axis="1 0 0" armature="{m_total - m_body!r}" damping="0"/>
      <geom type="box" size="0.01 0.01 0.01" mass="{m_body!r}" contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <actuator>
    <motor joint="nut_slide" gear="{1.0 / p!r}" ctrllimited="false"/>
  </actuator>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    return model, mujoco.MjData(model), m_total


def _median_spread(times: list[float]) -> tuple[float, float]:
    med = statistics.median(times)
    return med, (max(times) - min(times)) / med if med > 0 else 0.0


def _mujoco_path(params, torque: list[float], load: float):
    """(MuJoCo's rigid screw–nut run over `torque`, or None without mujoco; a note on its exactness)."""
    try:
        import mujoco
    except ImportError:
        return None, "mujoco not installed (pip install 'prsm[bench]'): no baseline"
    mj_model, mj_data, m_total = mujoco_screw_nut(params)
    p = params.geometry.lead_per_rad_m

    def run_mujoco():
        mujoco.mj_resetData(mj_model, mj_data)
        ctrl, qpos, mj_step = mj_data.ctrl, mj_data.qpos, mujoco.mj_step
        for t in torque:
            ctrl[0] = t - load * p  # net screw torque (the load through the lead), as the models see it
            mj_step(mj_model, mj_data)
            x = qpos[0]
        return x
    # exactness check against the closed form: constant net torque, x = ½ (τ/p / m_total) t²
    mujoco.mj_resetData(mj_model, mj_data)
    mj_data.ctrl[0] = 0.01
    for _ in range(1000):
        mujoco.mj_step(mj_model, mj_data)
    v_exact = 0.01 / p / m_total * 1000 * DT
    return run_mujoco, (f"MuJoCo {mujoco.__version__}, slide + armature; velocity after 1 s of constant torque "
                        f"within {abs(mj_data.qvel[0] / v_exact - 1):.1e} of τ t /(p m_eff)")


def step_cost_figures(quick: bool) -> list[dict]:
    """Per-step cost of every model's `Simulator.step`, its `Session.step` and MuJoCo's `mj_step`, interleaved rounds."""
    n = 2000 if quick else 20000
    rounds = 3 if quick else 7
    params = preset(PRESET)
    # reversals about the start with no load: the nut stays on its threads (a load that back-drives the screw
    # carries it onto a thread end, and the figure would be the end's contact); 0.4 N·m is above s30's
    # no-load torque (0.22 N·m, docs/model.md §4.5), so the screw turns rather than sticking
    torque = (TORQUE_AMPLITUDE_NM * np.cos(np.arange(n) * 0.01)).tolist()
    load = 0.0
    paths = {}
    for name in MODELS:
        sim = Simulator(params, name, DT)

        def run_sim(sim=sim):
            sim.reset()
            step = sim.step
            for t in torque:
                out = step(t, load)
            return out.nut_position_m
        paths[name] = run_sim
        session = Session(params, name, DT, load_n=load)

        def run_session(session=session):
            session.reset()
            step = session.step
            for t in torque:
                out = step(t)  # the gate takes the command at the step's time, the load is held
            return out.nut_position_m
        paths[name, "session"] = run_session
    run_mujoco, mj_note = _mujoco_path(params, torque, load)
    if run_mujoco is not None:
        paths["mujoco"] = run_mujoco
    times = {k: [] for k in paths}
    for _ in range(rounds):
        for k, fn in paths.items():
            # this thread's CPU time: on a shared machine wall time also counts the other processes' turns
            t0 = time.thread_time()
            fn()
            times[k].append((time.thread_time() - t0) / n)
    per = {k: _median_spread(v) for k, v in times.items()}
    mj = per.get("mujoco", (math.nan, 0.0))[0]
    factors = {"ideal": 1.0, "jones2016": 1.0, "fu2018": 1.5, "elastic": 10.0}
    figs = []
    if "mujoco" in per:
        figs.append(figure("MuJoCo mj_step, rigid screw–nut (Python loop)", mj * 1e6, "µs", "(baseline)", None,
                           per["mujoco"][1], mj_note))
    else:
        figs.append(figure("MuJoCo mj_step baseline", math.nan, "µs", "(baseline)", None, None, mj_note))
    for name in MODELS:
        cost, spread = per[name]
        f = factors.get(name)
        target = (f"≤ {'' if f == 1 else f'{f:g}× '}MuJoCo" if f else "(info)")
        ok = (cost <= f * mj) if (f and math.isfinite(mj)) else None
        figs.append(figure(f"{name} per-step path (Simulator.step)", cost * 1e6, "µs", target, ok, spread,
                           (f"{cost / mj:.2f}× MuJoCo's step; " if math.isfinite(mj) else "")
                           + f"{PRESET}; thread CPU time; input checks, state and the Outputs record included"))
        s_cost, s_spread = per[name, "session"]
        figs.append(figure(f"{name} per-step path through Session.step (the node's)", s_cost * 1e6, "µs", "(info)", None,
                           s_spread, f"{s_cost / cost:.2f}× Simulator.step; the command through the gate, the load "
                           "held, the state checked finite; same run"))
    figs.extend(held_end_figures(quick, {name: per[name][0] for name in MODELS}))
    figs.extend(batch_figures(quick))
    return figs


def held_end_figures(quick: bool, free_step_s: dict[str, float]) -> list[dict]:
    """Per-step cost of `Simulator.step` with the nut held at rest on a thread end (a controller pressing into
    the end, a press holding its force there): each step is the free step that runs past the end and the
    end's contact solve (`actuator.stops.solve`, its trials whole model steps), beside the model's free step
    (`free_step_s`, s, from the same run)."""
    n = 300 if quick else 2000
    params = preset(PRESET)
    figs = []
    for name in MODELS:
        sim = Simulator(params, name, DT)
        for _ in range(HOLD_STEPS_TO_END):
            sim.step(HOLD_TORQUE_NM, 0.0)
        if sim.thread_end_force_n == 0.0:
            figs.append(figure(f"{name} per step with the nut held on a thread end", math.nan, "µs", "(info)", None,
                               None, f"the nut was not on its thread end after {HOLD_STEPS_TO_END} steps at "
                                     f"{HOLD_TORQUE_NM:g} N·m"))
            continue
        t0 = time.thread_time()
        for _ in range(n):
            sim.step(HOLD_TORQUE_NM, 0.0)
        cost = (time.thread_time() - t0) / n
        figs.append(figure(f"{name} per step with the nut held on a thread end", cost * 1e6, "µs", "(info)", None,
                           None, f"{cost / free_step_s[name]:.1f}× its free step in this run; {cost / DT * 100:.0f} % "
                                 f"of a 1 ms realtime period; {PRESET} pushed by {HOLD_TORQUE_NM:g} N·m, the end's "
                                 f"force {abs(sim.thread_end_force_n):,.0f} N; thread CPU time"))
    return figs


def batch_figures(quick: bool) -> list[dict]:
    """Batch `Simulator.run` speed per model (simulated s per wall s at a 1 ms step), and `elastic`'s beside its
    floor: its rotating core (`fu2018`) run alone at the elastic sub-step on the same inputs, in the same rounds.

    `elastic` takes `substeps` sub-steps per step (its ~580 Hz axial mode at ω h ≤ 0.5 on `s30`), each a full
    core step: the core's steps alone are what the chain cannot go below without fewer sub-steps."""
    sim_s = 1.0 if quick else 5.0
    n = int(sim_s / DT)
    params = preset(PRESET)
    # reversals about the start, on the threads, above the no-load torque
    torque = TORQUE_AMPLITUDE_NM * np.cos(2 * math.pi * 1.0 * DT * np.arange(n))
    targets = {"fu2018": 1000.0, "elastic": 300.0}
    sims = {name: Simulator(params, name, DT) for name in MODELS}
    runs: dict[str | tuple[str, str], tuple] = {name: (sim, torque) for name, sim in sims.items()}
    # a model that sub-steps a core (`elastic`) is timed beside that core's steps alone
    cores = {name: sim.model.core for name, sim in sims.items() if hasattr(sim.model, "core")}
    for name, core in cores.items():
        runs[name, "core"] = (Simulator(params, core.name, core.dt_s), np.repeat(torque, round(DT / core.dt_s)))
    times: dict[str | tuple[str, str], list[float]] = {key: [] for key in runs}
    for _ in range(2 if quick else 3):
        for key, (sim, inputs) in runs.items():
            sim.reset()
            t0 = time.perf_counter()
            sim.run(inputs, 0.0)
            times[key].append(time.perf_counter() - t0)
    figs = []
    for name in MODELS:
        wall, spread = _median_spread(times[name])
        tgt = targets.get(name)
        note = f"{PRESET}, {sim_s:g} s at 1 ms; {wall / n * 1e6:.2f} µs per step"
        if name in cores:
            core, (core_wall, core_spread) = cores[name], _median_spread(times[name, "core"])
            subs = round(DT / core.dt_s)
            note += (f"; {wall / core_wall:.2f}× the time of its core's {subs} sub-steps per step alone "
                     f"({core.name} at {core.dt_s * 1e3:g} ms on the same inputs, same rounds: "
                     f"{sim_s / core_wall:.0f}×)")
        figs.append(figure(f"{name} batch (Simulator.run) simulated s per wall s", sim_s / wall, "×",
                           f"≥ {tgt:g}" if tgt else "(info)", (sim_s / wall >= tgt) if tgt else None, spread, note))
        if name in cores:
            figs.append(figure(f"{name} batch floor: its core's sub-steps alone ({core.name} at its sub-step)",
                               sim_s / core_wall, "×", "(peer)", None, core_spread,
                               f"{PRESET}, the same {sim_s:g} s of inputs in {subs} steps of {core.dt_s * 1e3:g} ms "
                               f"each; {name} over this time: ≤ 1 means its own work costs nothing above the core "
                               "steps it takes"))
    return figs


def measure(quick: bool = False) -> list[dict]:
    return step_cost_figures(quick) + loop_figures(quick)


def main(argv: list[str] | None = None) -> int:
    return area_main("realtime", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
