"""A study: one YAML file → a normalised description, its hash, and the list of run specs.

    preset: s30                 # or params: FILE.yaml (which may name its own `preset:`)
    model: fu2018
    scenario: heavy             # or a list (a grid axis); `position` = the demo's closed loop
    duration_s: 0.3
    vary:
      friction.mu_screw_roller: {values: [0.02, 0.05, 0.08, 0.11]}
      friction.mu_pin: {uniform: [0.0, 0.05]}
    samples: 3                  # random draws per grid point
    seed: 7
    metrics: [efficiency, speed_ratio]

Optional keys: `dt_s` (1e-3), `set` (fixed overrides, same keys as `vary`), `runs_per_task`
(`auto` or a count; execution only, not part of the hash), `trajectories` (`{decimate: N}`:
keep every N-th step of each run; output only, not hashed), `life.dynamic_load_rating_n`
(for the L10 metrics), `tune` (the gain search of `prsm-sweep tune`, see `tune.py`), `actuator`
(the actuator around the screw, a mapping as the node's `actuator` parameter: motor, drive,
sensors, stops, brake, faults; each run is then stepped through `prsm_sim.Session` as the node
steps it; every scenario but `position`, drive.mode effort).

Keys that can be set or varied: every parameter `group.name` (`prsm-sim params`), the
scenario's `scenario.load_n|speed_rad_s|torque_nm|frequency_hz`, the closed loop's
`controller.bandwidth_hz|damping|integral_ratio|max_torque_nm|load_n` and
`reference.amplitude_m|frequency_hz`.

Grids (`values`, `linspace: [start, stop, count]`) multiply; random draws (`normal: [mean, sd]`,
`uniform: [low, high]`, `lognormal: [median, sigma_ln]`) are drawn `samples` times per grid
point from a generator seeded with (seed, grid point, sample), so a run's inputs depend on
nothing but the study: the same study gives the same draws, in any order, on any machine.

The study's identity is the SHA-256 of its normalised content (keys sorted, defaults filled,
comments and layout gone, a params file by its parsed content).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from prsm_sim import MODELS, OUTPUT_FIELDS, Params, preset
from prsm_sim.actuator import actuator_params_from_dict
from prsm_sim.control import DEFAULT_AMPLITUDE_M, DEFAULT_FREQUENCY_HZ, PositionController
from prsm_sim.errors import PrsmError
from prsm_sim.scenarios import SCENARIOS

from prsm_ros.limits import MAX_STUDY_RUNS, load_yaml, read_text_file, run_steps

POSITION = "position"  # the demo's nut-position loop (prsm_sim.control), run offline
ALL_SCENARIOS = (*SCENARIOS, POSITION)
GRID_KINDS = ("values", "linspace")
RANDOM_KINDS = ("normal", "uniform", "lognormal")
SCENARIO_KEYS = ("load_n", "speed_rad_s", "torque_nm", "frequency_hz")
CONTROLLER_KEYS = ("bandwidth_hz", "damping", "integral_ratio", "max_torque_nm", "load_n")
REFERENCE_KEYS = ("amplitude_m", "frequency_hz")
TOP_KEYS = ("preset", "params", "model", "scenario", "duration_s", "dt_s", "set", "vary", "samples", "seed",
            "metrics", "runs_per_task", "trajectories", "life", "tune", "actuator")
SELECTORS = ("final", "mean", "max", "min", "rms")
COLUMN_NAMES = tuple(n for n, _ in OUTPUT_FIELDS)
# run-level figures (no @selector): the summary of `prsm-sim run --json` and the study's own
SUMMARY_METRICS = ("peak_nut_force_n", "peak_screw_speed_rad_s", "peak_tooth_normal_force_n",
                   "peak_roller_screw_normal_force_n", "peak_roller_nut_normal_force_n",
                   "tracking_error_rms_m", "tracking_error_max_m", "energy_residual_j", "energy_residual_rel",
                   "l10_revolutions", "l10_hours")
DEFAULT_METRICS = ("efficiency", "speed_ratio")


class StudyError(PrsmError, ValueError):
    """A study file or study directory was refused; the message names the key, the value and what is allowed."""


def settable_keys() -> list[str]:
    """Every key `set:` and `vary:` accept."""
    return (Params.override_keys() + [f"scenario.{k}" for k in SCENARIO_KEYS]
            + [f"controller.{k}" for k in CONTROLLER_KEYS] + [f"reference.{k}" for k in REFERENCE_KEYS])


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _check_key(where: str, key: Any) -> str:
    if not isinstance(key, str) or key not in settable_keys():
        group = str(key).split(".")[0]
        near = [k for k in settable_keys() if k.startswith(group + ".")]
        allowed = f"allowed in {group}: {', '.join(k.split('.', 1)[1] for k in near)}" if near else \
            "expected group.name, e.g. friction.mu_screw_roller (see `prsm-sim params`)"
        raise StudyError(f"{where}: unknown parameter {key!r}; {allowed}")
    return key


def _distribution(key: str, spec: Any) -> dict:
    """{kind: args} → normalised {"kind": kind, "args": [...]}; refused with what is allowed."""
    where = f"vary.{key}"
    kinds = GRID_KINDS + RANDOM_KINDS
    if not isinstance(spec, dict) or len(spec) != 1:
        raise StudyError(f"{where} = {spec!r}: expected one distribution, e.g. {{values: [..]}}; "
                         f"allowed: {', '.join(kinds)}")
    kind, args = next(iter(spec.items()))
    if kind not in kinds:
        raise StudyError(f"{where}: unknown distribution {kind!r}; allowed: {', '.join(kinds)}")
    if kind == "values":
        return {"kind": kind, "args": _values(where, args)}
    want = 3 if kind == "linspace" else 2
    if not isinstance(args, list) or len(args) != want or not all(_finite(a) for a in args):
        form = {"linspace": "[start, stop, count]", "normal": "[mean, sd]", "uniform": "[low, high]",
                "lognormal": "[median, sigma_ln]"}[kind]
        raise StudyError(f"{where}.{kind} = {args!r}: expected {want} finite numbers {form}")
    a, b = float(args[0]), float(args[1])
    if kind == "linspace":
        n = args[2]
        if float(n) != int(n) or int(n) < 1:
            raise StudyError(f"{where}.linspace count = {n!r}: must be a whole number >= 1")
        return {"kind": kind, "args": [a, b, int(n)]}
    _check_random(where, kind, args, a, b)
    return {"kind": kind, "args": [a, b]}


def _values(where: str, args: Any) -> list:
    """A `values` grid: a non-empty list of finite numbers (as floats) or strings."""
    if not isinstance(args, list) or not args:
        raise StudyError(f"{where}.values = {args!r}: expected a non-empty list")
    for v in args:
        if not (_finite(v) or isinstance(v, str)):
            raise StudyError(f"{where}.values: {v!r} is not a finite number or a string")
    return [float(v) if _finite(v) else v for v in args]


def _check_random(where: str, kind: str, args: list, a: float, b: float) -> None:
    """The two parameters of a random draw within the distribution's domain."""
    if kind == "normal" and b < 0:
        raise StudyError(f"{where}.normal sd = {b!r}: must be >= 0")
    if kind == "uniform" and b < a:
        raise StudyError(f"{where}.uniform = {args!r}: low must not exceed high")
    if kind == "lognormal" and (a <= 0 or b < 0):
        raise StudyError(f"{where}.lognormal = {args!r}: median must be > 0 and sigma_ln >= 0")


def _metric(name: Any) -> str:
    if not isinstance(name, str):
        raise StudyError(f"metrics: {name!r} is not a metric name")
    base, sep, sel = name.partition("@")
    if base in SUMMARY_METRICS and not sep:
        return name
    if base in COLUMN_NAMES and (not sep or sel in SELECTORS):
        return name
    if base in COLUMN_NAMES:
        raise StudyError(f"metrics: {name!r}: unknown selector @{sel}; allowed: {', '.join('@' + s for s in SELECTORS)}")
    raise StudyError(f"metrics: unknown metric {name!r}; allowed: an output ({', '.join(COLUMN_NAMES)}) optionally "
                     f"with {'/'.join('@' + s for s in SELECTORS)}, or {', '.join(SUMMARY_METRICS)}")


def _number(key: str, v: Any, *, positive: bool = False, whole: bool = False, lo: float | None = None) -> Any:
    ok = _finite(v) and (not positive or v > 0) and (lo is None or v >= lo) and (not whole or float(v) == int(v))
    if not ok:
        allowed = "a whole number" if whole else "a finite number"
        allowed += " > 0" if positive else f" >= {lo:g}" if lo is not None else ""
        raise StudyError(f"{key} = {v!r}: must be {allowed}")
    return int(v) if whole else float(v)


def normalise(data: Any, source: str = "<study>", base_dir: Path | None = None) -> dict:
    """Check a parsed study and return its normalised form (every default filled, keys sorted)."""
    if not isinstance(data, dict):
        raise StudyError(f"{source}: expected a mapping of study keys, got {type(data).__name__}")
    unknown = sorted(str(k) for k in data if k not in TOP_KEYS)
    if unknown:
        raise StudyError(f"{source}: unknown study key {unknown[0]!r}; allowed: {', '.join(TOP_KEYS)}")
    if data.get("preset") is not None and data.get("params") is not None:
        raise StudyError(f"{source}: give preset or params, not both")
    out: dict[str, Any] = {"preset": None, "params": None}
    if data.get("params") is not None:
        path = Path(str(data["params"]))
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        text = read_text_file(path, what="parameter file", error=StudyError)
        pdata = load_yaml(text, source=f"params = {str(data['params'])!r}", error=StudyError)
        out["params"] = pdata
    else:
        out["preset"] = str(data.get("preset", "jones2016"))
    out["model"] = _model(data.get("model", "jones2016"))
    out.update(_timing(data))
    out.update(_inputs(data, out["scenarios"]))
    out["samples"] = _number("samples", data.get("samples", 1), whole=True, lo=1)
    _check_run_count(out)
    out["seed"] = _number("seed", data.get("seed", 0), whole=True, lo=0)
    out.update(_measures(data, out["scenarios"]))
    if data.get("actuator") is not None:  # only then in the identity: a study without one keeps its hash
        out["actuator"] = _actuator(data["actuator"], out)
    base_params(out)  # the base parameter set must build
    return out


def _model(model: Any) -> str:
    if model not in MODELS:
        raise StudyError(f"model = {model!r}: unknown model; allowed: {', '.join(MODELS)}")
    return model


def _timing(data: dict) -> dict:
    """The study's `scenarios` (a list), `duration_s` and `dt_s`, checked."""
    scen = data.get("scenario", "step")
    scen_list = scen if isinstance(scen, list) else [scen]
    for s in scen_list:
        if s not in ALL_SCENARIOS:
            raise StudyError(f"scenario = {s!r}: unknown scenario; allowed: {', '.join(ALL_SCENARIOS)}")
    if not scen_list:
        raise StudyError("scenario = []: name at least one scenario")
    out = {"scenarios": list(scen_list), "duration_s": _number("duration_s", data.get("duration_s", 1.0), positive=True),
           "dt_s": _number("dt_s", data.get("dt_s", 1e-3), positive=True)}
    if out["duration_s"] < out["dt_s"]:
        raise StudyError(f"duration_s = {out['duration_s']}: shorter than one step ({out['dt_s']} s)")
    run_steps(out["duration_s"], out["dt_s"], error=StudyError)
    return out


def _inputs(data: dict, scenarios: list[str]) -> dict:
    """The study's `set` (fixed values) and `vary` (distributions), keys checked, each key in one of them."""
    fixed = data.get("set") or {}
    if not isinstance(fixed, dict):
        raise StudyError(f"set = {fixed!r}: expected a mapping of group.name: value")
    out = {"set": {_check_key("set", k): v for k, v in sorted(fixed.items(), key=lambda kv: str(kv[0]))}}
    vary = data.get("vary") or {}
    if not isinstance(vary, dict):
        raise StudyError(f"vary = {vary!r}: expected a mapping of group.name: {{distribution: args}}")
    out["vary"] = {_check_key("vary", k): _distribution(k, v) for k, v in sorted(vary.items(), key=lambda kv: str(kv[0]))}
    both = sorted(set(out["set"]) & set(out["vary"]))
    if both:
        raise StudyError(f"{both[0]}: both set and varied; give it in one of them")
    if POSITION in scenarios:
        extra = sorted(k for k in [*out["set"], *out["vary"]] if k.startswith("scenario.") and k != "scenario.load_n")
        if extra:
            raise StudyError(f"{extra[0]}: the {POSITION} scenario takes scenario.load_n only (its motion is the "
                             f"reference.* settings)")
    return out


def _check_run_count(norm: dict) -> None:
    """Refuse a study of more than MAX_STUDY_RUNS runs, counted before anything is built."""
    runs = norm["samples"] * len(norm["scenarios"]) * math.prod(
        len(d["args"]) if d["kind"] == "values" else int(d["args"][2])
        for d in norm["vary"].values() if d["kind"] in GRID_KINDS)
    if runs > MAX_STUDY_RUNS:
        raise StudyError(f"samples = {norm['samples']} over {runs // norm['samples']} grid point(s) = {runs} runs: "
                         f"more than the {MAX_STUDY_RUNS} runs a study may have")


def _measures(data: dict, scenarios: list[str]) -> dict:
    """The study's `metrics` and `life` (the rating the l10 metrics need), checked against each other."""
    metrics = data.get("metrics", list(DEFAULT_METRICS))
    if not isinstance(metrics, list) or not metrics:
        raise StudyError(f"metrics = {metrics!r}: expected a non-empty list of metric names")
    out: dict[str, Any] = {"metrics": [_metric(m) for m in metrics]}
    if len(set(out["metrics"])) != len(out["metrics"]):
        raise StudyError(f"metrics = {metrics!r}: a metric is named twice")
    life = data.get("life") or {}
    if not isinstance(life, dict) or set(life) - {"dynamic_load_rating_n"}:
        raise StudyError(f"life = {life!r}: expected {{dynamic_load_rating_n: N}}")
    out["life"] = {"dynamic_load_rating_n": _number("life.dynamic_load_rating_n", life["dynamic_load_rating_n"],
                                                    positive=True)} if life else {}
    if any(m.startswith("l10_") for m in out["metrics"]) and not out["life"]:
        raise StudyError("metrics: the l10 metrics need life.dynamic_load_rating_n (the screw's C_a, N)")
    tracking = [m for m in out["metrics"] if m.startswith("tracking_error")]
    if tracking and scenarios != [POSITION]:
        raise StudyError(f"metrics: {tracking[0]} needs scenario: {POSITION} (the closed position loop)")
    return out


def _actuator(data: Any, norm: dict) -> dict:
    """The `actuator` mapping, checked as `actuator_params_from_dict` builds it (kept as given: plain data)."""
    try:
        a = actuator_params_from_dict(data)
        json.dumps(data, allow_nan=False)
    except (PrsmError, TypeError, ValueError) as e:
        raise StudyError(f"actuator: {e}") from None
    if a.drive.mode != "effort":
        raise StudyError(f"actuator.drive.mode = {a.drive.mode!r}: the scenarios command the screw torque (effort)")
    if POSITION in norm["scenarios"]:
        raise StudyError(f"actuator: the {POSITION} scenario drives the bare model only")
    energy = [m for m in norm["metrics"] if m.startswith("energy_residual")]
    if energy:
        raise StudyError(f"metrics: {energy[0]} is the bare screw's balance; with an actuator its drive and motor "
                         "hold energy too")
    return data


def execution_options(data: dict) -> dict:
    """The keys that steer execution and output but not results (not hashed)."""
    rpt = data.get("runs_per_task", "auto")
    if rpt != "auto":
        rpt = _number("runs_per_task", rpt, whole=True, lo=1)
    traj = data.get("trajectories") or {}
    if not isinstance(traj, dict) or set(traj) - {"decimate"}:
        raise StudyError(f"trajectories = {traj!r}: expected {{decimate: N}} (keep every N-th step)")
    decimate = _number("trajectories.decimate", traj["decimate"], whole=True, lo=1) if traj else None
    return {"runs_per_task": rpt, "decimate": decimate}


def load(path: str | Path) -> tuple[dict, dict, dict]:
    """Read a study file → (raw mapping, normalised study, execution options)."""
    p = Path(path)
    data = load_yaml(read_text_file(p, what="study file", error=StudyError), source=str(p), error=StudyError)
    try:
        norm = normalise(data, str(p), p.parent)
        return data, norm, execution_options(data)
    except StudyError as e:
        raise StudyError(f"{p}: {e}") from None


def study_hash(norm: dict) -> str:
    """SHA-256 (hex, first 16 digits) of the canonical JSON of the normalised study."""
    text = json.dumps(norm, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def base_params(norm: dict) -> Params:
    """The study's base parameter set (preset, or params file with its own optional `preset:`)."""
    from prsm_ros.param_files import params_from_yaml  # one reader of params files
    try:
        if norm["params"] is not None:
            return params_from_yaml(yaml.safe_dump(norm["params"]), "params")
        return preset(norm["preset"])
    except PrsmError as e:
        raise StudyError(str(e)) from None


def _grid_axis(d: dict) -> list:
    if d["kind"] == "values":
        return list(d["args"])
    a, b, n = d["args"]
    return [float(v) for v in np.linspace(a, b, n)]


def _draw(rng: np.random.Generator, d: dict) -> float:
    a, b = d["args"]
    if d["kind"] == "normal":
        return float(rng.normal(a, b))
    if d["kind"] == "uniform":
        return float(rng.uniform(a, b))
    return float(a * math.exp(rng.normal(0.0, b)))  # lognormal: median · e^(σ z)


def run_specs(norm: dict) -> list[dict]:
    """Every run of the study: grid points (scenario × grid axes) × `samples` seeded draws.

    A spec is {"run_id", "grid_point", "sample", "scenario", "inputs": {key: value}}; run_id
    is grid_point · samples + sample, stable for a given study.
    """
    grid_keys = [k for k, d in norm["vary"].items() if d["kind"] in GRID_KINDS]
    rand_keys = [k for k, d in norm["vary"].items() if d["kind"] in RANDOM_KINDS]
    axes = [norm["scenarios"]] + [_grid_axis(norm["vary"][k]) for k in grid_keys]
    specs = []
    for gi, point in enumerate(itertools.product(*axes)):
        for si in range(norm["samples"]):
            rng = np.random.default_rng([norm["seed"], gi, si])
            inputs = dict(zip(grid_keys, point[1:]))
            inputs.update({k: _draw(rng, norm["vary"][k]) for k in rand_keys})
            specs.append({"run_id": gi * norm["samples"] + si, "grid_point": gi, "sample": si,
                          "scenario": point[0], "inputs": inputs})
    return specs


def controller_defaults() -> dict:
    """The demo's controller settings, the values `controller.*` and `reference.*` keys replace."""
    names = {f.name: f.default for f in fields(PositionController)}
    return {**{f"controller.{k}": names[k] for k in ("bandwidth_hz", "damping", "integral_ratio", "max_torque_nm")},
            "reference.amplitude_m": DEFAULT_AMPLITUDE_M, "reference.frequency_hz": DEFAULT_FREQUENCY_HZ}
