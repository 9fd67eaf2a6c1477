"""Controller gains tuned against the plant spread with Ray Tune (`prsm-sweep tune STUDY.yaml -o DIR`).

The study is a `prsm-sweep run` study with `scenario: position` (the demo's position loop run
offline); its `vary:` draws are the plant spread (Monte Carlo) and its `tune:` section names the
gains and their search ranges:

    tune:
      gains:
        controller.bandwidth_hz: {uniform: [2, 40]}
        controller.damping: {uniform: [0.5, 2.0]}
        controller.integral_ratio: {loguniform: [3, 30]}
      metric: tracking_error_max_m   # one of the study's metrics (default: the first)
      objective: max                 # worst case over the draws, or pNN (a percentile, e.g. p95)
      trials: 16
      seed: 0                        # of the search (the draws use the study's seed)
      holdout_seed: 1001             # draws the tuned and the default gains are compared on

A trial evaluates one gain set on every draw of the study (sequentially: one trial is one
CPU's work) and reports the objective; Ray Tune searches. Afterwards the best gains and the
demo's defaults are scored on a held-out set of draws (same distributions, another seed),
so the gain is judged on plants it was not tuned on.

Gains: controller.bandwidth_hz (Hz), controller.damping (ζ), controller.integral_ratio (κ),
controller.max_torque_nm (N·m); each {uniform: [low, high]}, {loguniform: [low, high]} or
{values: [..]}, positive. A gain tuned must not also be in the study's set: or vary:.

DIR receives: gains.yaml (the best gains: `prsm-demo --gains DIR/gains.yaml`, or the demo
controller's --gains), tuned.json (gains, objective, held-out comparison, every trial) and
ray_tune/ (Ray Tune's own experiment folder: trial logs and checkpoints). An existing DIR with
these files is refused unless --force.
"""

from __future__ import annotations

import contextlib
import math
import sys
from pathlib import Path

import numpy as np

from prsm_ros.sweep import execute
from prsm_ros.sweep.study import CONTROLLER_KEYS, POSITION, StudyError, controller_defaults, run_specs

GAIN_KEYS = tuple(f"controller.{k}" for k in CONTROLLER_KEYS if k != "load_n")
DOMAINS = ("uniform", "loguniform", "values")


def settings(data: dict, norm: dict) -> dict:
    """Check the study's `tune:` section → normalised settings."""
    t = data.get("tune")
    if not isinstance(t, dict):
        raise StudyError("tune: missing; give tune.gains with a search range per gain (see `prsm-sweep tune --help`)")
    unknown = sorted(set(t) - {"gains", "metric", "objective", "trials", "seed", "holdout_seed"})
    if unknown:
        raise StudyError(f"tune.{unknown[0]}: unknown key; allowed: gains, metric, objective, trials, seed, holdout_seed")
    if norm["scenarios"] != [POSITION]:
        raise StudyError(f"scenario = {norm['scenarios']}: tuning needs scenario: {POSITION} (the closed position loop)")
    gains = t.get("gains")
    if not isinstance(gains, dict) or not gains:
        raise StudyError(f"tune.gains = {gains!r}: expected a mapping of controller.NAME: {{uniform|loguniform|values: ..}}")
    space = {k: _gain_domain(k, d, norm) for k, d in gains.items()}
    metric = t.get("metric", norm["metrics"][0])
    if metric not in norm["metrics"]:
        raise StudyError(f"tune.metric = {metric!r}: not one of the study's metrics ({', '.join(norm['metrics'])})")
    objective = str(t.get("objective", "max"))
    if objective != "max" and not (objective.startswith("p") and objective[1:].replace(".", "", 1).isdigit()
                                   and 0 < float(objective[1:]) <= 100):
        raise StudyError(f"tune.objective = {objective!r}: max or pNN (a percentile in (0, 100], e.g. p95)")
    out = {"space": space, "metric": metric, "objective": objective}
    for key, default, lo in (("trials", 16, 1), ("seed", 0, 0), ("holdout_seed", norm["seed"] + 1000, 0)):
        v = t.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise StudyError(f"tune.{key} = {v!r}: must be a whole number >= {lo}")
        out[key] = v
    if out["holdout_seed"] == norm["seed"]:
        raise StudyError(f"tune.holdout_seed = {out['holdout_seed']}: must differ from the study's seed")
    return out


def _gain_domain(k: str, d, norm: dict) -> dict:
    """One gain's search domain, `{kind: args}` → {"kind", "args"}; refused with what is allowed."""
    if k not in GAIN_KEYS:
        raise StudyError(f"tune.gains: unknown gain {k!r}; allowed: {', '.join(GAIN_KEYS)}")
    if k in norm["vary"] or k in norm["set"]:
        raise StudyError(f"tune.gains.{k}: also set or varied in the study; give it in one place")
    if not isinstance(d, dict) or len(d) != 1 or next(iter(d)) not in DOMAINS:
        raise StudyError(f"tune.gains.{k} = {d!r}: expected one of {', '.join(DOMAINS)}")
    kind, args = next(iter(d.items()))
    ok = isinstance(args, list) and args and all(isinstance(a, (int, float)) and not isinstance(a, bool)
                                                  and math.isfinite(a) and a > 0 for a in args)
    if not ok or (kind != "values" and (len(args) != 2 or args[0] >= args[1])):
        raise StudyError(f"tune.gains.{k}.{kind} = {args!r}: expected positive finite numbers "
                         f"{'[..]' if kind == 'values' else '[low, high] with low < high'}")
    return {"kind": kind, "args": [float(a) for a in args]}


def score(values: list[float], objective: str) -> float:
    """Worst case (max) or a percentile of the per-draw metric; a failed or NaN draw scores inf."""
    v = np.asarray(values, dtype=float)
    if not v.size or not np.all(np.isfinite(v)):
        return math.inf
    return float(v.max() if objective == "max" else np.percentile(v, float(objective[1:])))


def evaluate(norm: dict, gains: dict, metric: str, seed: int | None = None) -> list[float]:
    """The metric of every draw of the study with these gains (and, if given, another draw seed)."""
    study = {**norm, "set": {**norm["set"], **gains}}
    if seed is not None:
        study["seed"] = seed
    return [execute.run_one(study, spec)[0][metric] for spec in run_specs(study)]


def _trainable(config: dict, norm: dict, metric: str, objective: str) -> None:
    from ray import tune
    values = evaluate(norm, config, metric)
    tune.report({"objective": score(values, objective), "worst": float(np.max(values)) if values else math.inf})


def run_tune(norm: dict, ts: dict, storage: Path, *, address: str | None = None, workers: int | None = None) -> dict:
    """Search (Ray Tune's experiment folder under `storage`), then compare the best and the demo's
    default gains on held-out draws."""
    from prsm_ros.ray_runner import connect, disconnect
    ray, owned, tmp = connect(address, workers)
    try:
        from ray import tune
        from ray.tune.search.basic_variant import BasicVariantGenerator
        dom = {"uniform": lambda a: tune.uniform(*a), "loguniform": lambda a: tune.loguniform(*a),
               "values": lambda a: tune.choice(a)}
        space = {k: dom[d["kind"]](d["args"]) for k, d in ts["space"].items()}
        trainable = tune.with_resources(tune.with_parameters(_trainable, norm=norm, metric=ts["metric"],
                                                             objective=ts["objective"]), {"cpu": 1})
        tuner = tune.Tuner(trainable, param_space=space,
                           tune_config=tune.TuneConfig(metric="objective", mode="min", num_samples=ts["trials"],
                                                       search_alg=BasicVariantGenerator(random_state=ts["seed"]),
                                                       reuse_actors=True),  # one process per CPU, not per trial
                           run_config=tune.RunConfig(storage_path=str(Path(storage).resolve()), name="prsm-tune",
                                                     verbose=0))
        with contextlib.redirect_stdout(sys.stderr):  # Tune's banners; stdout is for our result
            grid = tuner.fit()
        best = grid.get_best_result()
        trials = grid.get_dataframe()
        best_gains = {k: float(best.config[k]) for k in ts["space"]}
        defaults = {k: v for k, v in controller_defaults().items() if k in ts["space"]}
        held = ray.get([ray.remote(num_cpus=1)(evaluate).remote(norm, g, ts["metric"], ts["holdout_seed"])
                        for g in (best_gains, defaults)])
    finally:
        disconnect(ray, owned, tmp)
    cols = [c for c in trials.columns if c.startswith("config/")] + ["objective"]
    return {"metric": ts["metric"], "objective": ts["objective"], "trials": ts["trials"], "draws": norm["samples"],
            "best_gains": best_gains, "best_objective_tuning_draws": float(best.metrics["objective"]),
            "default_gains": defaults,
            "holdout_seed": ts["holdout_seed"],
            "holdout": {"tuned": score(held[0], ts["objective"]), "default": score(held[1], ts["objective"]),
                        "tuned_worst": float(np.max(held[0])), "default_worst": float(np.max(held[1]))},
            "trial_table": trials[cols].rename(columns=lambda c: c.removeprefix("config/")).to_dict("records")}


RESULT_JSON, GAINS_YAML, TUNE_DIR = "tuned.json", "gains.yaml", "ray_tune"


def save(result: dict, out_dir: Path) -> None:
    """DIR/tuned.json (everything) and DIR/gains.yaml (the best gains, for `prsm-demo --gains`)."""
    from prsm_ros.sweep.gains import gains_document
    from prsm_ros.json_out import dumps
    (out_dir / RESULT_JSON).write_text(dumps(result) + "\n", encoding="utf-8")
    h = result["holdout"]
    gains = {k.removeprefix("controller."): v for k, v in result["best_gains"].items()}
    comment = (f"demo position controller gains tuned by prsm-sweep tune (study {result.get('study', '?')}):\n"
               f"{result['objective']} of {result['metric']} on held-out draws (seed {result['holdout_seed']}): "
               f"{h['tuned']:.6g} tuned, {h['default']:.6g} with the demo's defaults\n"
               f"use: prsm-demo --gains {out_dir / GAINS_YAML}")
    (out_dir / GAINS_YAML).write_text(gains_document(gains, comment), encoding="utf-8")
