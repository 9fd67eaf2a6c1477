"""prsm-fit: identify an actuator from bench recordings, with confidence intervals and a held-out check.

    prsm-fit BAG_OR_TABLE… [--preset P | --params FILE] [--model M] [--actuator FILE] [--free NAME…]
             [--validate BAG_OR_TABLE…] [--address RAY | --serial] -o DIR
    prsm-fit excite -o FILE.csv [--kind multisine|chirp|prbs] [--signal torque|speed] …

DIR receives params.yaml (the base with the identified values), fit.json and one plot per
recording; it is written whole or not at all (a temporary folder renamed at the end). docs/fit.md
describes the loop excite → record → fit → validate → use.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

from prsm_sim.errors import PrsmError
from prsm_sim.identify import DELAY_KEY, default_free, fit, free_parameter, validate
from prsm_sim.identify.free import MAX_DELAY_STEPS, prepared_base
from prsm_sim.identify.shooting import HORIZON_S
from prsm_sim.models.registry import MODELS, model_class
from prsm_sim.presets import PRESETS

from prsm_ros.fit.readers import BagTopics, read_source
from prsm_ros.interrupts import import_native, interrupt_handled
from prsm_ros.json_out import dumps

PROG = "prsm-fit"


def ray_map(address: str | None, workers: int | None):
    """A `map_fn` for `prsm_sim.identify.fit` that runs the starts as Ray tasks (joined or started here)."""
    def run(fn, problem, points):
        from prsm_ros.ray_runner import connect, disconnect
        ray, owned, tmp = connect(address, workers)
        try:
            task = ray.remote(fn)
            shared = ray.put(problem)
            futures = [task.remote(shared, p) for p in points]
            for f in futures:
                yield ray.get(f)
        finally:
            disconnect(ray, owned, tmp)
    return run


def build_parser() -> argparse.ArgumentParser:
    from prsm_sim import __version__
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0],
                                 epilog="prsm-fit excite --help: the identification signal")
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    ap.add_argument("recordings", nargs="+", metavar="BAG_OR_TABLE", help="MCAP bag or CSV/Parquet table; "
                    "FILE@LOAD_N gives a constant nut load in N")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--preset", choices=list(PRESETS), help="base parameter set (default s30)")
    g.add_argument("--params", metavar="FILE.yaml", help="base parameter file (e.g. prsm-sim params --datasheet)")
    ap.add_argument("--model", choices=list(MODELS), default="fu2018", help="the model to fit (default fu2018)")
    ap.add_argument("--actuator", metavar="FILE.yaml", help="the actuator around the screw (as prsm-node's)")
    ap.add_argument("--free", nargs="+", metavar="NAME", help=f"parameters to fit by dotted name, {DELAY_KEY} for "
                    "the command delay (default: the model's mass, drag, friction, delay[, stiffness, backlash])")
    ap.add_argument("--validate", nargs="+", default=[], metavar="BAG_OR_TABLE", help="held-out recordings")
    ap.add_argument("-o", "--output", required=True, metavar="DIR", help="a new (or empty) folder for the results")
    ap.add_argument("--starts", type=int, default=4, help="least-squares starts (default 4)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the start points")
    ap.add_argument("--horizon", type=float, default=HORIZON_S, help=f"horizon length, s (default {HORIZON_S})")
    run = ap.add_mutually_exclusive_group()
    run.add_argument("--address", metavar="HOST:PORT", help="join this Ray cluster (default: a Ray on loopback)")
    run.add_argument("--serial", action="store_true", help="run the starts one after the other, without Ray")
    ap.add_argument("--workers", type=int, help="CPUs of the embedded Ray (default: all)")
    t = BagTopics()
    ap.add_argument("--joint-states-topic", default=t.joint_states, help=f"JointState topic (default {t.joint_states})")
    ap.add_argument("--command-topic", default=t.command,
                    help=f"torque command, Float64 or JointState (default {t.command})")
    ap.add_argument("--load-topic", help="nut load, std_msgs/Float64 in N (else FILE@LOAD_N)")
    ap.add_argument("--screw-joint", default=t.screw_joint, help=f"default {t.screw_joint}")
    ap.add_argument("--nut-joint", default=t.nut_joint, help=f"default {t.nut_joint}")
    return ap


def _output_dir(text: str) -> Path:
    out = Path(text)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise PrsmError(f"-o {out}: exists and is not an empty folder; name a new one")
    if not out.absolute().parent.is_dir():
        raise PrsmError(f"-o {out}: its parent folder does not exist")
    return out


def _inputs(args):
    from prsm_ros.param_files import load_actuator_file, resolve_params
    if args.starts < 1 or (args.workers is not None and args.workers < 1) or not 0 < args.horizon <= 10:
        raise PrsmError(f"--starts {args.starts} / --workers {args.workers} / --horizon {args.horizon}: "
                        "starts and workers must be >= 1, the horizon in (0, 10] s")
    model_class(args.model)
    base = resolve_params(args.preset or (None if args.params else "s30"), args.params)
    actuator = load_actuator_file(args.actuator) if args.actuator else None
    topics = BagTopics(joint_states=args.joint_states_topic, command=args.command_topic, load=args.load_topic,
                       screw_joint=args.screw_joint, nut_joint=args.nut_joint)
    recs = [read_source(s, topics) for s in args.recordings]
    held = [read_source(s, topics) for s in args.validate]
    names = args.free or default_free(base, args.model)
    base = prepared_base(base, names)
    return base, actuator, recs, held, [free_parameter(base, n) for n in names]


def run(args, tmp: Path) -> dict:
    """The fit, its validation and its files in `tmp`; returns fit.json's content."""
    # scipy's solvers, filters and statistics load here, where a Ctrl-C waits for them (`import_native`)
    import_native("scipy.optimize", "scipy.signal", "scipy.stats")
    from tqdm import tqdm

    from prsm_ros.fit.plots import plot_recording
    from prsm_ros.param_files import params_to_yaml
    base, actuator, recs, held, free = _inputs(args)
    delay_scan = MAX_DELAY_STEPS + 1 if any(p.name == DELAY_KEY for p in free) else 0
    total = args.starts + delay_scan + 3 + len(recs) + len(held)  # starts, delays, polish, intervals, plots
    bar = tqdm(total=total, desc="fitting", unit="task", file=sys.stderr, disable=None)

    def progress(stage: str, done: int, of: int) -> None:
        bar.set_description(f"{stage} {done}/{of}")
        bar.update(1)

    map_fn = None if args.serial else ray_map(args.address, args.workers)
    kw = {"map_fn": map_fn} if map_fn else {}
    result = fit(recs, base, args.model, free, actuator=actuator, starts=args.starts, seed=args.seed,
                 progress=progress, horizon_s=args.horizon, **kw)
    doc = {"model": args.model, "base": args.params or args.preset or "s30", "dt_s": recs[0].dt_s,
           "horizon_steps": {r.name: result.problem.horizons(r).steps for r in recs},
           "signal_scale": result.problem.scale, "recordings": [r.name for r in recs]}
    doc |= result.to_dict()
    doc["validation"] = {}
    for r in held:
        doc["validation"][r.name] = validate(result, r)
        plot_recording(result.problem, result.params, result.base, r, result.delay_steps,
                       tmp / f"validate_{Path(r.name).stem}.png", "held out")
        progress("plots", 1, 1)
    for r in recs:
        plot_recording(result.problem, result.params, result.base, r, result.delay_steps,
                       tmp / f"fit_{Path(r.name).stem}.png", "fitted")
        progress("plots", 1, 1)
    bar.close()
    (tmp / "params.yaml").write_text(params_to_yaml(result.params), encoding="utf-8")
    (tmp / "fit.json").write_text(dumps(doc), encoding="utf-8")
    return doc


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["excite"]:
        from prsm_ros.fit.excite import main as excite_main
        return excite_main(argv[1:])
    args = build_parser().parse_args(argv)
    tmp = None
    try:
        out = _output_dir(args.output)
        tmp = Path(tempfile.mkdtemp(prefix=".prsm-fit-", dir=out.absolute().parent))
        doc = run(args, tmp)
        if out.exists():
            out.rmdir()
        os.replace(tmp, out)
        tmp = None
    except (PrsmError, OSError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        interrupt_handled()
        print(f"\n{PROG}: interrupted; nothing written", file=sys.stderr)
        return 130
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    _summary(doc, out)
    return 0


def _summary(doc: dict, out: Path) -> None:
    for name, p in doc["parameters"].items():
        lo, hi = p["ci95"]
        flag = "" if p["identifiable"] else f"  NOT IDENTIFIABLE ({p.get('why_not', 'see fit.json')}); kept at base"
        print(f"{name:36s} {p['value']:<12.6g} [{lo:.6g}, {hi:.6g}] {p['unit']}{flag}")
    for name, v in doc["validation"].items():
        print(f"validation {name}: rms nut position {v['rms_nut_position_m']:.3g} m "
              f"(base {v['base']['rms_nut_position_m']:.3g} m)")
    print(f"wrote {out}/params.yaml, fit.json and plots")


if __name__ == "__main__":
    sys.exit(main())
