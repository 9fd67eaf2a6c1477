"""`prsm-sim`: offline simulation from the command line (no ROS graph is started).

    prsm-sim presets
    prsm-sim params --preset s30
    prsm-sim params --datasheet SHEET.yaml [--base PARAMS.yaml] [--model fu2018] [-o OUT.yaml]
    prsm-sim datasheet --preset s30 --model fu2018 [--load N] [--speed RAD_S] --json
    prsm-sim contact --preset jones2016
    prsm-sim steady-state --preset jones2016 --model jones2016 --json
    prsm-sim run --preset s30 --model fu2018 --scenario heavy --duration 1 --json [--csv F] [--mcap F]
    prsm-sim run --preset s30 --model jones2016 --actuator actuator.yaml --json   # through prsm_sim.Session
    prsm-sim stiffness --preset s30 [--max-load 40000 --points 9 | --load 20000 ...] --json
    prsm-sim modes --preset s30 --model elastic [--load 20000] --json

Every command takes --preset P or --params FILE.yaml, --set group.name=value overrides and
--json. Errors print one line and exit 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

import numpy as np

from prsm_sim.errors import PrsmError
from prsm_sim import MODELS, OUTPUT_FIELDS, PRESETS, Params, Session, SessionConfig, Simulator
from prsm_sim.physics.contact import contact_for, predicted_screw_offset_rad
from prsm_sim.physics.kinematics import ideal_speed_ratio
from prsm_sim.models.registry import model_class
from prsm_sim.scenarios import SCENARIOS, default_spec, run_scenario, run_session_scenario, summarise

from prsm_ros.cli import sim_datasheet
from prsm_ros.json_out import dumps
from prsm_ros.param_files import load_actuator_file, params_to_yaml, resolve_params
from prsm_ros.limits import run_memory, run_steps
from prsm_ros.interrupts import import_native, interrupt_handled

PROGRESS_MIN_STEPS = 20_000
PROBE_STEPS = 400  # a run longer than this first measures what a step of it holds (`bytes_per_step`)


def bytes_per_step(build, runner, spec, dt_s: float) -> float:
    """Memory a step of this run adds to its trajectory (bytes), measured as the growth in traced peak
    memory from a run of PROBE_STEPS/2 to one of PROBE_STEPS steps (the fixed part cancels)."""
    import tracemalloc

    peaks = []
    for k in (PROBE_STEPS // 2, PROBE_STEPS):
        sim = build()
        tracemalloc.start()
        try:
            runner(sim, spec, k * dt_s)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
    return max(peaks[1] - peaks[0], 0) / (PROBE_STEPS - PROBE_STEPS // 2)


class CliError(PrsmError):
    """A user error: printed as one line, exit status 2."""


def _overrides(items: list[str]) -> dict[str, Any]:
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise CliError(f"--set {item!r}: expected group.name=value, e.g. friction.mu_screw_roller=0.1")
        from prsm_ros.limits import load_yaml
        out[key] = load_yaml(value, source=f"--set {key[:80]}", error=CliError)
    return out


def _params(args) -> Params:
    return resolve_params(args.preset, args.params, _overrides(args.set))


def _refuse_params(args, why: str) -> None:
    """CliError naming the parameter options given to a command that takes no parameter set (never ignored)."""
    given = [f"--{n}" for n in ("preset", "params", "set") if getattr(args, n)]
    if given:
        raise CliError(f"{'/'.join(given)}: {why}")


def _emit(args, data: dict, text: str) -> None:
    print(dumps(data) if args.json else text)


def cmd_presets(args) -> None:
    _refuse_params(args, "prsm-sim presets lists every preset; `prsm-sim params --preset P` shows one")
    rows = {}
    for name in PRESETS:
        p = resolve_params(name, None)
        g = p.geometry
        rows[name] = {"screw_radius_m": g.screw_radius_m, "roller_radius_m": g.roller_radius_m, "starts": g.starts,
                      "pitch_m": g.pitch_m, "lead_m": g.lead_m, "n_rollers": g.n_rollers, "n_teeth": g.n_teeth,
                      "ideal_speed_ratio": ideal_speed_ratio(g)}
    text = "\n".join(f"{n:18s} r_S={r['screw_radius_m'] * 1e3:.2f} mm  r_R={r['roller_radius_m'] * 1e3:.2f} mm  "
                     f"n={r['starts']}  L={r['lead_m'] * 1e3:.1f} mm  {r['n_rollers']} rollers × {r['n_teeth']} teeth  "
                     f"ideal ω_S/ω_C={r['ideal_speed_ratio']:.4f}" for n, r in rows.items())
    _emit(args, {"presets": rows}, text)


def cmd_params(args) -> None:
    p = _params(args)
    if args.json:
        print(dumps(p.to_dict()))
    else:
        print(params_to_yaml(p), end="")


def cmd_contact(args) -> None:
    p = _params(args)
    geo = p.geometry
    w_c = 1.0 / ideal_speed_ratio(geo)
    data: dict[str, Any] = {
        "lead_m": geo.lead_m, "ideal_speed_ratio": ideal_speed_ratio(geo), "roller_spin_per_carrier": -geo.gear_ratio,
        "screw_lead_angle_deg": math.degrees(geo.screw_lead_angle_rad),
        "roller_lead_angle_deg": math.degrees(geo.roller_lead_angle_rad),
        "predicted_screw_offset_deg": -math.degrees(predicted_screw_offset_rad(geo)),
        "contacts": {},
    }
    lines = [f"lead {geo.lead_m * 1e3:.3f} mm, ideal ω_S/ω_C {ideal_speed_ratio(geo):.5f}, roller spin {-geo.gear_ratio:.3f} ω_C",
             f"predicted screw offset (λ_S − λ_R)/tan β: {data['predicted_screw_offset_deg']:.3f}°"]
    for ev in ("exact", "line_of_centres"):
        for side in ("screw", "nut"):
            c = contact_for(geo, side, ev)
            v = c.sliding_matrix(geo) @ np.array([1.0, w_c])
            v_nut = geo.lead_per_rad_m
            entry = {"body_radius_m": c.body_radius_m, "roller_contact_radius_m": c.roller_contact_radius_m,
                     "offset_deg": math.degrees(c.body_angle_rad), "roller_angle_deg": math.degrees(c.roller_angle_rad),
                     "point_m": c.point_m, "normal_on_roller": c.normal_on_roller,
                     "sliding_speed_per_nut_speed": float(np.linalg.norm(v)) / v_nut,
                     "normal_sliding_per_nut_speed": float(v @ c.normal_on_roller) / v_nut}
            data["contacts"][f"{side}_{ev}"] = entry
            lines.append(f"{side:5s} {ev:15s} r={c.body_radius_m * 1e3:.5f} mm  offset={entry['offset_deg']:+.4f}°  "
                         f"|v_s|/v_N={entry['sliding_speed_per_nut_speed']:.4f} at ideal kinematics")
    data["sliding_per_nut_speed_model_md"] = 1.0 / math.sin(geo.flank_angle_rad)
    lines.append(f"docs/model.md §3: screw sliding |v_N|/sin β = {data['sliding_per_nut_speed_model_md']:.4f} |v_N|")
    _emit(args, data, "\n".join(lines))


def cmd_steady_state(args) -> None:
    p = _params(args)
    cls = model_class(args.model)
    closed = cls.closed_form_steady_state(p, screw_speed_rad_s=args.speed, torque_nm=args.torque, load_n=args.load)
    if closed is not None:
        ss = {"model": args.model, **closed}
    else:
        spec = default_spec(p, "light", load_n=args.load if args.load is not None else p.loads.nut_load_n,
                            speed_rad_s=args.speed)
        for name, v in (("duration_s", args.duration), ("dt_s", args.dt)):
            if not (math.isfinite(v) and v > 0):
                raise CliError(f"{name} = {v!r}: must be a finite number > 0")
        run_steps(args.duration, args.dt, error=CliError)
        sim = Simulator(p, args.model, args.dt)
        s = summarise(run_scenario(sim, spec, args.duration))
        w = s["final"]["screw_speed_rad_s"]
        ss = {"model": args.model, "method": f"simulation: PI speed loop, tail of {args.duration} s",
              "screw_speed_rad_s": w, "carrier_speed_rad_s": s["final"]["carrier_speed_rad_s"],
              "carrier_over_screw": s["tail_mean_speed_ratio"],
              "speed_ratio_screw_over_carrier": 1.0 / s["tail_mean_speed_ratio"],
              "torque_nm": s["final"]["screw_torque_nm"], "load_force_n": spec.load_n,
              "efficiency": s["tail_efficiency"], "slip_speed_m_s": s["tail_mean_slip_speed_m_s"]}
    ss = _defined_only(ss)
    text = "\n".join(f"{k}: {'undefined (a ratio over zero or reversed power)' if v is None else v}"
                     for k, v in ss.items())
    _emit(args, ss, text)


# ratios of powers or speeds: undefined where their denominator is zero (at zero load, at rest), so None (JSON null)
_RATIOS = ("efficiency", "speed_ratio_screw_over_carrier", "carrier_over_screw")


def _defined_only(ss: dict) -> dict:
    """`ss` with an undefined ratio as None; any other non-finite figure a CliError naming it (never NaN, exit 0)."""
    out = {}
    for k, v in ss.items():
        if isinstance(v, float) and not math.isfinite(v):
            if k not in _RATIOS:
                raise CliError(f"steady state: {k} = {v!r}: not finite for these parameters and inputs")
            v = None
        out[k] = v
    return out


def cmd_run(args) -> None:
    p = _params(args)
    spec = default_spec(p, args.scenario, load_n=args.load, torque_nm=args.torque, speed_rad_s=args.speed,
                        frequency_hz=args.frequency)
    for name, v in (("duration_s", args.duration), ("dt_s", args.dt)):
        if not (math.isfinite(v) and v > 0):
            raise CliError(f"{name} = {v!r}: must be a finite number > 0")
    n = run_steps(args.duration, args.dt, error=CliError)
    actuator = _actuator(args)

    def build():  # with an actuator, stepped as the node steps it: gate, drive, sensors, brake and faults
        return Simulator(p, args.model, args.dt) if actuator is None else \
            Session.from_config(SessionConfig(params=p, model=args.model, dt_s=args.dt, actuator=actuator))
    runner = run_scenario if actuator is None else run_session_scenario
    if n > PROBE_STEPS:
        run_memory(n, bytes_per_step(build, runner, spec, args.dt), error=CliError)
    sim = build()
    bar = None
    done = [0]

    def progress(k: int) -> None:
        if bar is not None:
            bar.update(k - done[0])
        done[0] = k

    try:
        if n >= PROGRESS_MIN_STEPS and not args.no_progress:
            from tqdm import tqdm
            bar = tqdm(total=n, unit="step", file=sys.stderr, desc=f"{args.model} {args.scenario}")
        traj = runner(sim, spec, args.duration, progress)
    except KeyboardInterrupt:
        interrupt_handled()
        _interrupted(f"at step {done[0]} of {n}: nothing written (a run's outputs are written when it ends; "
                     "a shorter --duration ends sooner)")
    finally:
        if bar is not None:
            bar.close()
    summary = {"preset": p.name, "model": args.model, "scenario": args.scenario, "dt_s": args.dt,
               "load_n": spec.load_n, "torque_nm": spec.torque_nm, "speed_reference_rad_s": spec.speed_rad_s,
               **summarise(traj)}
    summary.update(_write_outputs(args, traj, p, n))
    f = summary["final"]
    text = "\n".join([
        f"{p.name} / {args.model} / {args.scenario}: {summary['steps']} steps of {args.dt} s",
        f"final: screw {f['screw_speed_rad_s']:.4f} rad/s, carrier {f['carrier_speed_rad_s']:.4f} rad/s, "
        f"nut {f['nut_position_m'] * 1e3:.4f} mm at {f['nut_velocity_m_s'] * 1e3:.4f} mm/s, "
        f"nut force {f['nut_force_n']:.2f} N, torque {f['screw_torque_nm']:.5f} N·m",
        f"tail: ζ_PS = ω_C/ω_S {summary['tail_mean_speed_ratio']:.5f}, efficiency {summary['tail_efficiency']:.4f}, "
        f"slip {summary['tail_mean_slip_speed_m_s']:.5f} m/s",
    ] + ([f"peak tooth normal force {summary['peak_tooth_normal_force_n']:.2f} N"]
         if "peak_tooth_normal_force_n" in summary else [])
      + ([f"ENERGY GUARD: the energy balance was violated from t = {summary['energy_guard']['first_fault_time_s']:.6f} s "
          f"(residual {summary['energy_guard']['residual_j']:.6g} J of {summary['energy_guard']['flow_j']:.6g} J); "
          "do not trust these results"] if summary["energy_guard"]["fault"] else []))
    _emit(args, summary, text)


def _write_outputs(args, traj, p: Params, n: int) -> dict:
    """Write the run's --csv and --mcap files; {"csv": path, "mcap": path} of those written."""
    written: dict[str, str] = {}
    if args.csv:
        try:
            _write_csv(args.csv, traj)
        except KeyboardInterrupt:
            interrupt_handled()
            _interrupted(f"while writing {args.csv}: the run ended ({len(traj)} steps) but the CSV is incomplete")
        written["csv"] = args.csv
    if args.mcap:
        from prsm_ros.mcap.offline import write_trajectory_mcap  # no ROS needed: pip install 'prsm[bag]'
        try:
            write_trajectory_mcap(args.mcap, traj, p, args.model, preset_name=args.preset or p.name,
                                  progress=not args.no_progress and n >= PROGRESS_MIN_STEPS)
        except OSError as e:
            raise CliError(f"cannot write MCAP {args.mcap}: {e.strerror or e}") from None
        except KeyboardInterrupt:
            interrupt_handled()
            kept = f"{args.csv} is complete; " if args.csv else ""
            _interrupted(f"while writing {args.mcap}: {kept}the MCAP holds the steps written so far, without its "
                         f"index (prsm-bag repair {args.mcap} rebuilds it)")
        written["mcap"] = args.mcap
    return written


def _interrupted(what: str) -> None:
    """Ctrl-C: say what was kept, in one line, and exit 130 (128 + SIGINT, as a shell reports it)."""
    print(f"prsm-sim: interrupted {what}", file=sys.stderr)
    raise SystemExit(130)


def _actuator(args):
    """The `--actuator` file's actuator, or None; refused where the run could not use it as given."""
    if not args.actuator:
        return None
    a = load_actuator_file(args.actuator)
    if a.drive.mode != "effort":
        raise CliError(f"{args.actuator}: drive.mode = {a.drive.mode!r}: the scenarios command the screw torque "
                       "(effort)")
    if args.mcap:
        raise CliError("--mcap with --actuator: the offline MCAP writer records the bare model's topics only "
                       "(no measured joint_states, ground truth or fault events); record the actuator with prsm-node")
    return a


def _load_points(args, p: Params) -> list[float]:
    if args.load:
        loads = list(args.load)
    else:
        top = args.max_load if args.max_load is not None else 0.25 * p.ratings.static_load_rating_n
        if not (math.isfinite(top) and top > 0):
            raise CliError(f"max_load = {top!r}: must be a finite number > 0 (N)")
        if args.points < 2:
            raise CliError(f"points = {args.points}: must be at least 2")
        loads = np.linspace(0.0, top, args.points).tolist()
    for f in loads:
        if not math.isfinite(f):
            raise CliError(f"load = {f!r}: must be a finite number (N)")
    return loads


def cmd_stiffness(args) -> None:
    """Axial load → deflection, stiffness and per-thread load shares (docs/model.md §4.3)."""
    from prsm_sim.physics.load_sharing import AxialChain
    p = _params(args)
    el = p.elastic
    chain = AxialChain(p, args.nut_position)
    records = []
    for f in _load_points(args, p):
        pt = chain.at(f)
        records.append({
            "load_n": f, "deflection_m": pt.deflection_m, "nut_deflection_m": pt.nut_deflection_m,
            "shaft_deflection_m": pt.shaft_deflection_m, "housing_deflection_m": pt.housing_deflection_m,
            "stiffness_n_per_um": pt.stiffness_n_per_m * 1e-6, "nut_stiffness_n_per_um": pt.nut_stiffness_n_per_m * 1e-6,
            "shaft_stiffness_n_per_um": pt.shaft_stiffness_n_per_m * 1e-6,
            "housing_stiffness_n_per_um": pt.housing_stiffness_n_per_m * 1e-6,
            "unloaded_side_force_n": pt.unloaded_side_n,
            "thread_load_shares": pt.shares, "thread_loads_n": pt.row_loads_n,
        })
    data = {"preset": p.name, "mounting": el.mounting, "preload_n": el.preload_n, "preload_kind": el.preload_kind,
            "lost_motion_m": el.axial_clearance_m, "nut_position_m": args.nut_position,
            "static_load_rating_n": p.ratings.static_load_rating_n,
            "method": "static load distribution from compatibility, Hertz contacts (docs/model.md §4.3)",
            "records": records}
    lines = [f"{p.name}: {el.mounting} mounting, preload {el.preload_n:g} N ({el.preload_kind}), "
             f"clearance {el.axial_clearance_m * 1e6:g} µm, C0a {p.ratings.static_load_rating_n / 1e3:.1f} kN",
             f"{'load N':>10} {'defl µm':>9} {'nut µm':>8} {'K N/µm':>8} {'K_nut':>8} {'K_shaft':>8}  ζ_T first … last"]
    for r in records:
        z = r["thread_load_shares"]
        lines.append(f"{r['load_n']:10.0f} {r['deflection_m'] * 1e6:9.3f} {r['nut_deflection_m'] * 1e6:8.3f} "
                     f"{r['stiffness_n_per_um']:8.1f} {r['nut_stiffness_n_per_um']:8.1f} "
                     f"{r['shaft_stiffness_n_per_um']:8.1f}  {z[0]:.3f} … {z[-1]:.3f}")
    _emit(args, data, "\n".join(lines))


def cmd_modes(args) -> None:
    """Linearised axial natural frequencies and damping about an operating load (docs/model.md §4.3)."""
    from prsm_sim.physics.load_sharing import axial_modes
    if not model_class(args.model).has_axial_chain:
        raise CliError(f"model = {args.model!r}: modes need the elastic level; use --model elastic "
                       "(the rigid models have no axial compliance)")
    p = _params(args)
    f = p.loads.nut_load_n if args.load is None else args.load
    if not math.isfinite(f):
        raise CliError(f"load = {f!r}: must be a finite number (N)")
    ma = axial_modes(p, f, args.nut_position)
    ms = lambda modes: [{"frequency_hz": m.frequency_hz, "undamped_frequency_hz": m.undamped_frequency_hz,
                         "damping_ratio": m.damping_ratio} for m in modes]
    data = {"preset": p.name, "model": "elastic", "load_n": f, "nut_position_m": args.nut_position,
            "axial_stiffness_n_per_um": ma.stiffness_n_per_m * 1e-6, "damping_n_s_per_m": ma.damping_n_s_per_m,
            "screw_side_mass_kg": ma.screw_side_mass_kg, "nut_side_mass_kg": ma.nut_side_mass_kg,
            "modes": ms(ma.free), "modes_screw_held": ms(ma.held)}
    lines = [f"{p.name} / elastic about {f:g} N: K = {ma.stiffness_n_per_m * 1e-6:.1f} N/µm, "
             f"M_S = {ma.screw_side_mass_kg:.1f} kg (screw side, reflected), m = {ma.nut_side_mass_kg:.2f} kg"]
    lines += [f"  free screw : {m.frequency_hz:9.2f} Hz  ζ = {m.damping_ratio:.4f}" for m in ma.free]
    lines += [f"  screw held : {m.frequency_hz:9.2f} Hz  ζ = {m.damping_ratio:.4f}" for m in ma.held]
    _emit(args, data, "\n".join(lines))


def _write_csv(path: str, traj) -> None:
    names = [n for n, _ in OUTPUT_FIELDS]
    header = ",".join(f"{n} [{u}]" for n, u in OUTPUT_FIELDS)
    labels = traj.layout.labels()
    if labels:
        header += "," + ",".join(f'"{lab}"' for lab in labels)
    data = np.column_stack([traj[n] for n in names] + ([traj.internal] if labels else []))
    try:
        np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.10g")
    except OSError as e:
        raise CliError(f"cannot write CSV {path}: {e.strerror or e}") from None


def _envelope_on_node(case: dict, args) -> dict:
    """The case replayed into prsm-node in lockstep (prsm_ros.node.replay); the node's output in -o."""
    from pathlib import Path

    from prsm_ros.node.replay import ReplayError, replay_on_node
    try:
        return replay_on_node(case, Path(args.output) / f"node-{case.get('seed')}")
    except ReplayError as e:
        raise CliError(f"--node: {e}") from None


def cmd_envelope(args) -> None:
    from pathlib import Path

    from prsm_ros.sweep.envelope import merge_results, run_envelope
    # each case carries its own screw (`preset` and `overrides` in the case, drawn from its seed): a screw
    # given here would not be the one tested, so it is refused rather than ignored
    _refuse_params(args, "prsm-sim envelope draws each case's parameters from its seed; to run your screw, write "
                         "its preset and overrides into a case file (`preset:`, `overrides:`) and run it with --case FILE")
    campaign = [f"--{n.replace('_', '-')}" for n in ("runs", "first_seed", "address", "workers")
                if getattr(args, n) is not None]
    if args.seed is not None or args.case is not None:
        if campaign or args.merge:
            raise CliError(f"{'/'.join(campaign or ['--merge'])}: --seed/--case run one case here; a campaign is "
                           "--runs N [--first-seed S] [--address A] [--workers W]")
        _envelope_one(args)
        return
    if args.node:
        raise CliError("--node: replays one case; give --seed N or --case FILE")
    if args.merge:
        if campaign:
            raise CliError(f"{'/'.join(campaign)}: --merge runs nothing, it reports the results already in its "
                           "directories")
        summary = merge_results([Path(d) for d in args.merge], Path(args.output))
        _envelope_report(args, summary)
        return
    args.runs = 1000 if args.runs is None else args.runs
    args.first_seed = 0 if args.first_seed is None else args.first_seed
    if not (isinstance(args.runs, int) and args.runs >= 1):
        raise CliError(f"--runs {args.runs!r}: must be a whole number >= 1")
    bar = None
    if not args.no_progress:
        from tqdm import tqdm
        bar = tqdm(total=args.runs, unit="run", file=sys.stderr, desc="envelope")

    def progress(done: int, total: int) -> None:
        if bar is not None:
            bar.update(done - bar.n)

    try:
        summary = run_envelope(args.runs, Path(args.output), first_seed=args.first_seed, address=args.address,
                               workers=args.workers, progress=progress)
    finally:
        if bar is not None:
            bar.close()
    if summary.get("interrupted"):
        req = summary["requested"]
        print(f"prsm-sim: interrupted: {req['done']} of {req['runs']} runs done, {summary['failed']} of the "
              f"{summary['runs']} in {args.output} broke an invariant (results in {args.output}/results.jsonl, "
              f"failures in {args.output}/failures); the same command goes on from seed {summary['next_seed']}",
              file=sys.stderr)
        raise SystemExit(130)
    _envelope_report(args, summary)


def _envelope_report(args, summary: dict) -> None:
    print(dumps(summary) if args.json else
          f"{summary['runs']} runs (seeds {', '.join(f'{a}…{b}' for a, b in summary['seed_ranges'])}), "
          f"{summary['steps']} steps, {summary['cpu_s']} CPU s: {summary['failed']} broke an invariant"
          + (f" (cases in {args.output}/failures)" if summary["failed"] else "")
          + ("" if len(summary["physics"]) <= 1 else
             f"; mixed cores: {', '.join(f'{d}: {sum(b - a + 1 for a, b in r)} runs' for d, r in summary['physics'].items())}"))


def _envelope_one(args) -> None:
    """`prsm-sim envelope --seed N | --case FILE [--node]`: one case, run here (and on the node)."""
    from prsm_ros.sweep.envelope import run_one
    from prsm_sim.envelope import case_from_seed
    if args.seed is not None:
        case = case_from_seed(args.seed)
    else:
        from prsm_ros.limits import load_yaml, read_text_file
        doc = load_yaml(read_text_file(args.case, what="case file", error=CliError), source=f"--case {args.case}",
                        error=CliError)
        case = doc.get("case", doc) if isinstance(doc, dict) else None
        if not isinstance(case, dict):
            raise CliError(f"--case {args.case}: expected a mapping (an envelope case, or a failure file)")
    r = run_one(case)
    node = _envelope_on_node(case, args) if args.node else None
    if args.json:
        print(dumps({"case": case, **r, **({"node": node} if node is not None else {})}))
    else:
        print(f"seed {r['seed']}: {case['model']} {case['interface']} {case['controller']} load "
              f"{case['load']['kind']} dt {case['dt_s']:.4g} s, {r['steps']} steps: "
              + ("ok" if r["ok"] else "BROKE " + "; ".join(r["violations"])))
        if node is not None:
            print(f"prsm-node in lockstep: {node['compared']} of {node['steps']} steps compared: "
                  + ("the same states" if node["ok"] else f"DIFFERS at {node['mismatch']}"))
    if not r["ok"] or (node is not None and not node["ok"]):
        raise SystemExit(1)


def build_parser() -> argparse.ArgumentParser:
    from prsm_sim import __version__
    ap = argparse.ArgumentParser(prog="prsm-sim", description="Offline planetary roller screw simulation.")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--preset", choices=list(PRESETS), help="named parameter set (default jones2016)")
    common.add_argument("--params", metavar="FILE.yaml", help="parameter file (may name a base `preset:`)")
    common.add_argument("--set", action="append", metavar="GROUP.NAME=VALUE", help="override one parameter (repeatable)")
    common.add_argument("--json", action="store_true", help="machine-readable output")
    sub.add_parser("presets", parents=[common], help="list the presets").set_defaults(func=cmd_presets)
    sim_datasheet.register(sub, common, cmd_params, _params)  # params (also --datasheet), datasheet
    sub.add_parser("contact", parents=[common], help="exact thread contact geometry").set_defaults(func=cmd_contact)
    ss = sub.add_parser("steady-state", parents=[common], help="steady state of a model")
    ss.add_argument("--model", choices=list(MODELS), default="jones2016")
    g = ss.add_mutually_exclusive_group()
    g.add_argument("--speed", type=float, help="screw speed, rad/s (default: the preset's)")
    g.add_argument("--torque", type=float, help="screw torque, N·m (jones2016 only)")
    ss.add_argument("--load", type=float, help="nut load, N (default: the preset's)")
    ss.add_argument("--dt", type=float, default=1e-3, help="step for simulated steady states, s")
    ss.add_argument("--duration", type=float, default=1.0, help="simulated time for models without a closed form, s")
    ss.set_defaults(func=cmd_steady_state)
    run = sub.add_parser("run", parents=[common], help="simulate a scenario")
    run.add_argument("--model", choices=list(MODELS), default="jones2016")
    run.add_argument("--scenario", choices=SCENARIOS, default="step")
    run.add_argument("--duration", type=float, default=1.0, help="simulated time, s")
    run.add_argument("--dt", type=float, default=1e-3, help="fixed step, s")
    run.add_argument("--load", type=float, help="nut load, N (positive resists positive motion)")
    run.add_argument("--torque", type=float, help="open-loop torque amplitude, N·m")
    run.add_argument("--speed", type=float, help="speed reference amplitude, rad/s")
    run.add_argument("--frequency", type=float, default=1.0, help="sine frequency, Hz")
    run.add_argument("--csv", metavar="FILE", help="write every step's outputs and internal loads")
    run.add_argument("--mcap", metavar="FILE", help="write the run as a ROS 2 MCAP bag (needs the mcap extra)")
    run.add_argument("--actuator", metavar="FILE.yaml",
                     help="run the actuator around the screw (motor, drive, sensors, stops, brake, faults: the node's "
                          "`actuator` parameter as a YAML file), stepped through prsm_sim.Session as the node steps it")
    run.add_argument("--no-progress", action="store_true", help="no progress bar on long runs")
    run.set_defaults(func=cmd_run)
    st = sub.add_parser("stiffness", parents=[common], help="axial load → deflection, stiffness, thread load shares")
    st.add_argument("--load", type=float, action="append", metavar="N", help="a load point, N (repeatable)")
    st.add_argument("--max-load", type=float, help="top of the load sweep, N (default a quarter of C0a)")
    st.add_argument("--points", type=int, default=9, help="load points in the sweep from 0")
    st.add_argument("--nut-position", type=float, default=0.0, help="nut position (sets the shaft length), m")
    st.set_defaults(func=cmd_stiffness)
    mo = sub.add_parser("modes", parents=[common], help="linearised axial natural frequencies and damping")
    mo.add_argument("--model", default="elastic", help="model level (elastic)")
    mo.add_argument("--load", type=float, help="operating axial load, N (default: the preset's)")
    mo.add_argument("--nut-position", type=float, default=0.0, help="nut position (sets the shaft length), m")
    mo.set_defaults(func=cmd_modes)
    env = sub.add_parser("envelope", parents=[common], help="closed loops at the plant's edges, checked against "
                                                            "its invariants (on Ray)")
    env.add_argument("--runs", type=int, help="cases to run, default 1000 (consecutive seeds; those already in "
                                              "-o's results.jsonl are skipped: a rerun resumes)")
    env.add_argument("--first-seed", type=int, help="seed of the first case (default 0)")
    env.add_argument("-o", "--output", default="envelope-out", help="directory for failures/ and summary.json")
    env.add_argument("--address", help="a Ray head, HOST:PORT (default: an embedded Ray on this machine)")
    env.add_argument("--workers", type=int, help="CPUs of the embedded Ray (default: all)")
    env.add_argument("--merge", nargs="+", metavar="DIR", help="merge the results of these envelope output "
                                                                "directories (seed ranges run apart) into -o")
    env.add_argument("--seed", type=int, help="run the one case of this seed here and report it")
    env.add_argument("--case", metavar="FILE.yaml", help="run a case (or a failure file) here and report it")
    env.add_argument("--node", action="store_true", help="with --seed/--case: also replay it into prsm-node in "
                                                          "lockstep and compare the states step by step")
    env.add_argument("--no-progress", action="store_true", help="no progress bar")
    env.set_defaults(func=cmd_envelope)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "steady-state" and args.torque is not None \
            and "torque_nm" not in model_class(args.model).steady_state_inputs:
        takers = " or ".join(n for n, c in MODELS.items() if "torque_nm" in c.steady_state_inputs)
        print(f"prsm-sim: error: --torque applies to --model {takers} only (the others take --speed)", file=sys.stderr)
        return 2
    try:
        # every command's models and parameters load scipy's root finders (the drag law, Hertz contact, load sharing):
        # here, where a Ctrl-C waits for them (`import_native`), not as an ImportError read as a missing extra below
        import_native("scipy.optimize")
        args.func(args)
    except (PrsmError, ValueError) as e:  # every deliberate error (ModelError included) is one line, exit 2
        print(f"prsm-sim: error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"prsm-sim: error: {e.name or e} is not installed; install the extras: pip install 'prsm[bag]' "
              "(MCAP writing and bag tools, no ROS) or 'prsm[all]'", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0
    except KeyboardInterrupt:  # a Ctrl-C outside a command's own handler (parsing, a probe, writing)
        interrupt_handled()
        print(f"prsm-sim: interrupted during {args.command}: outputs not written or incomplete", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
