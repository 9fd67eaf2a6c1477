"""`prsm-sweep`: design sweeps, Monte Carlo studies and gain tuning on Ray.

    prsm-sweep run STUDY.yaml -o DIR [--address HOST:PORT] [--workers N]
    prsm-sweep report DIR [--json] [--no-plots]
    prsm-sweep tune STUDY.yaml [-o DIR] [--address HOST:PORT] [--workers N]   (DIR/gains.yaml → prsm-demo --gains)

Without --address an embedded Ray starts on this machine and stops at the end; with it the
study runs on that Ray cluster. Errors print one line and exit 2; an interrupted run exits 130
and resumes where it stopped when run again.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from prsm_sim import __version__
from prsm_sim.errors import PrsmError

from prsm_ros.json_out import dumps
from prsm_ros.limits import read_text_file
from prsm_ros.interrupts import interrupt_handled

PROG = "prsm-sweep"


def _workers(v: str) -> int:
    n = int(v)
    if n < 1:
        raise argparse.ArgumentTypeError(f"--workers {v}: must be a whole number >= 1")
    return n


def cmd_run(args) -> int:
    from prsm_ros.sweep import execute, runner, study
    raw, norm, ex = study.load(args.study)
    out = Path(args.output)
    text = read_text_file(args.study, what="study file", error=study.StudyError)  # the file load() accepted
    try:
        s = runner.run_study(norm, out, address=args.address, workers=args.workers,
                             runs_per_task=args.runs_per_task or ex["runs_per_task"], decimate=ex["decimate"],
                             retry_failed=args.retry_failed, progress=not args.no_progress, source_text=text)
    except KeyboardInterrupt:
        interrupt_handled()
        done = len(runner.recorded_rows(out)) if (out / runner.STUDY_JSON).exists() else 0
        print(f"{PROG}: interrupted: {done} runs recorded in {out}; run the same command again to resume",
              file=sys.stderr)
        return 130
    if args.json:
        print(dumps(s))
    else:
        rate = f" ({s['ran'] / s['wall_time_s']:.1f} runs/s incl. Ray start)" if s["ran"] else ""
        print(f"study {s['study']}: {s['runs']} runs, {s['ran']} run now{rate}, "
              f"{s['skipped']} already recorded, {s['failed']} failed → {out / runner.RUNS}")
        for line in execute.undefined_text(s["undefined"]):
            print(f"  {line}")
    return 0


def cmd_report(args) -> int:
    from prsm_ros.sweep import report
    r = report.build(Path(args.dir), make_plots=not args.no_plots)
    print(dumps(r) if args.json else report.text(r))
    return 0


def cmd_tune(args) -> int:
    import yaml

    from prsm_ros.sweep import study, tune
    raw, norm, _ = study.load(args.study)
    try:
        ts = tune.settings(raw, norm)
    except study.StudyError as e:
        raise study.StudyError(f"{args.study}: {e}") from None
    out = Path(args.output or f"{Path(args.study).stem}_tune")
    if out.exists() and not out.is_dir():
        raise study.StudyError(f"-o {out}: not a directory")
    held = [out / n for n in (tune.RESULT_JSON, tune.GAINS_YAML, tune.TUNE_DIR) if (out / n).exists()]
    if held and not args.force:
        raise study.StudyError(f"-o {out}: holds a tuning result ({held[0].name}); give another directory "
                               "or --force to replace it")
    if (out / tune.TUNE_DIR).exists():
        import shutil
        shutil.rmtree(out / tune.TUNE_DIR)
    out.mkdir(parents=True, exist_ok=True)
    r = tune.run_tune(norm, ts, out / tune.TUNE_DIR, address=args.address, workers=args.workers)
    r["study"] = study.study_hash(norm)
    tune.save(r, out)
    if args.json:
        print(dumps(r))
    else:
        h = r["holdout"]
        print(f"best gains ({r['objective']} of {r['metric']} over {r['draws']} draws, {r['trials']} trials): "
              + ", ".join(f"{k} = {v:.4g}" for k, v in r["best_gains"].items()))
        print(f"held-out draws (seed {r['holdout_seed']}): tuned {h['tuned']:.4g}, demo defaults {h['default']:.4g}"
              f" ({yaml.safe_dump(r['default_gains'], default_flow_style=True).strip()})")
        print(f"→ {out / tune.GAINS_YAML} (prsm-demo --gains {out / tune.GAINS_YAML}), {out / tune.RESULT_JSON}, "
              f"Ray Tune's trials in {out / tune.TUNE_DIR}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    ray_opts = argparse.ArgumentParser(add_help=False)
    ray_opts.add_argument("--address", metavar="HOST:PORT", help="run on this Ray cluster (default: an embedded Ray)")
    ray_opts.add_argument("--workers", type=_workers, metavar="N",
                          help="CPUs of the embedded Ray / tasks in flight per round (default: all CPUs)")
    ray_opts.add_argument("--json", action="store_true", help="machine-readable summary")
    run = sub.add_parser("run", parents=[ray_opts], help="run a study (resumes a partial one)")
    run.add_argument("study", metavar="STUDY.yaml")
    run.add_argument("-o", "--output", required=True, metavar="DIR", help="study directory (runs.parquet, plots)")
    run.add_argument("--runs-per-task", type=_workers, metavar="K", help="runs per Ray task (default: the study's, auto)")
    run.add_argument("--retry-failed", action="store_true", help="run recorded failures again")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.set_defaults(func=cmd_run)
    rep = sub.add_parser("report", help="statistics, sensitivities and plots of a study directory")
    rep.add_argument("dir", metavar="DIR")
    rep.add_argument("--json", action="store_true", help="machine-readable report")
    rep.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    rep.set_defaults(func=cmd_report)
    from prsm_ros.sweep import tune as tune_doc
    tn = sub.add_parser("tune", parents=[ray_opts], help="tune controller gains against the study's plant spread",
                        description=tune_doc.__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    tn.add_argument("study", metavar="STUDY.yaml")
    tn.add_argument("-o", "--output", metavar="DIR",
                    help="where to save gains.yaml, tuned.json and Ray Tune's trials (default ./STUDY_tune)")
    tn.add_argument("--force", action="store_true", help="replace an existing result in DIR")
    tn.set_defaults(func=cmd_tune)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (PrsmError, ValueError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"{PROG}: error: {e.name or e} is not installed; install the sweep extra: pip install 'prsm[sweep]'",
              file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
