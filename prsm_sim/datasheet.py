"""What a catalogue lists, computed by a model; and a parameter set built from a catalogue's datasheet.

`model_datasheet` runs the model to its steady states and reports the figures a roller-screw
catalogue lists (docs/model.md "The model's datasheet"). `Datasheet` holds a catalogue row;
`params_from_datasheet` turns one into a parameter set by the rules of docs/model.md "From a
datasheet" (standard design, the most rollers that fit, engaged threads from the nut length); the
calibration that fits friction and rating factors to the row lives in `prsm_sim.calibration`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from prsm_sim.params import ParamError, Params, is_finite_number, parse_float
from prsm_sim.scenarios import ScenarioSpec, run_scenario, summarise
from prsm_sim.simulator import Simulator

DEFAULT_SPEED_RAD_S = 100.0  # the efficiencies' screw speed
NO_LOAD_SPEED_RAD_S = 1.0  # the no-load torque's screw speed
DEFAULT_LOAD_FRACTION = 0.1  # of the dynamic rating, for the efficiencies and the stiffness
RUN_S = 0.6  # simulated time of each steady state: the speed loop's 0.1 s ramp, then settling
NO_LOAD_RUN_S = 1.0  # the no-load probe's first run; doubled until its tail is steady, up to the ceiling
NO_LOAD_MAX_RUN_S = 8.0
STEADY_SPEED_TOLERANCE = 0.01  # the tail's screw speed within this share of the reference: a steady state
TAIL_FRACTION = 0.2
# Share of the nut's length that is threaded and engaged: the rest holds the ring gears, the
# carrier rings and the wipers at its two ends [assumed; catalogues do not list it].
ENGAGED_FRACTION = 0.6


@dataclass(frozen=True)
class ModelSheet:
    """A model's own datasheet (`model_datasheet`); SI units."""

    efficiency_forward: float
    efficiency_backward: float
    no_load_torque_nm: float
    static_load_rating_n: float
    dynamic_load_rating_n: float
    axial_stiffness_n_per_um: float
    conditions: dict

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def steady_run(params: Params, model: str, dt_s: float, load_n: float, speed_rad_s: float, duration_s: float) -> dict:
    # a steady state away from the thread ends: at a coarse lead the run travels farther than the nut can
    if params.geometry.thread_ends:
        params = params.with_overrides({"geometry.thread_ends": False})
    sim = Simulator(params, model, dt_s)
    traj = run_scenario(sim, ScenarioSpec("datasheet", load_n, speed_rad_s=speed_rad_s), duration_s)
    s = summarise(traj, TAIL_FRACTION)
    n = len(traj)
    tail = slice(n - max(1, int(n * TAIL_FRACTION)), n)
    s["tail_torque_nm"] = float(np.mean(traj.columns["screw_torque_nm"][tail]))
    s["tail_speed_band"] = float(np.max(np.abs(traj.columns["screw_speed_rad_s"][tail] - speed_rad_s)))
    return s


def _no_load_steady(params: Params, model: str, dt_s: float) -> tuple[dict, float]:
    """The no-load probe at `NO_LOAD_SPEED_RAD_S`, run long enough that its tail is a steady state: (summary,
    run length s). At this speed the loop's integral action builds torque at only k_i ω per second (about
    0.6 N·m/s on `s30`), so a large no-load torque (a preloaded nut) is not reached within a fixed short run
    and its tail would still be breaking away; the run is doubled until the tail's screw speed stays within
    `STEADY_SPEED_TOLERANCE` of the reference, up to `NO_LOAD_MAX_RUN_S` (the last run's tail otherwise)."""
    run_s = NO_LOAD_RUN_S
    while True:
        s = steady_run(params, model, dt_s, 0.0, NO_LOAD_SPEED_RAD_S, run_s)
        if s["tail_speed_band"] <= STEADY_SPEED_TOLERANCE * NO_LOAD_SPEED_RAD_S or run_s >= NO_LOAD_MAX_RUN_S:
            return s, run_s
        run_s = min(2.0 * run_s, NO_LOAD_MAX_RUN_S)


def datasheet_load_n(params: Params) -> float:
    """The default load of the efficiencies: 10 % of C_a (of C_0a where C_a is not rated), N."""
    r = params.ratings
    return DEFAULT_LOAD_FRACTION * float(r.dynamic_load_rating_n or r.static_load_rating_n or 0.0)


def model_datasheet(params: Params, model: str, *, load_n: float | None = None,
                    speed_rad_s: float = DEFAULT_SPEED_RAD_S, dt_s: float = 1e-3) -> ModelSheet:
    """The catalogue figures of `params` on `model` (docs/model.md "The model's datasheet").

    Efficiencies: steady state of the speed loop at `speed_rad_s` with the load `load_n` resisting
    the motion (forward, screw drives nut) and aiding it (backward, the load drives the screw),
    each the tail mean of a `RUN_S` run on a screw without thread ends (the nut would run off a
    coarse-lead screw): η = P_out / P_in of the mechanism. No-load torque: the tail mean of the screw
    torque at zero load and 1 rad/s, the run lengthened until that tail is steady (`_no_load_steady`).
    Axial stiffness: the nut's (thread contacts and teeth, no shaft or housing) at `load_n`. Ratings:
    the parameter set's.
    """
    from prsm_sim.physics.load_sharing import AxialChain  # scipy-heavy; kept off `import prsm_sim`
    f = datasheet_load_n(params) if load_n is None else float(load_n)
    if not (math.isfinite(f) and f > 0):
        raise ParamError(f"load_n = {load_n!r}: must be a finite number > 0 (N)")
    if not (math.isfinite(speed_rad_s) and speed_rad_s > 0):
        raise ParamError(f"speed_rad_s = {speed_rad_s!r}: must be a finite number > 0 (rad/s)")
    fwd = steady_run(params, model, dt_s, f, speed_rad_s, RUN_S)
    bwd = steady_run(params, model, dt_s, -f, speed_rad_s, RUN_S)
    idle, idle_s = _no_load_steady(params, model, dt_s)
    stiffness = AxialChain(params).at(f).nut_stiffness_n_per_m
    conditions = {"model": model, "load_n": f, "speed_rad_s": speed_rad_s, "no_load_speed_rad_s": NO_LOAD_SPEED_RAD_S,
                  "dt_s": dt_s, "run_s": RUN_S, "no_load_run_s": idle_s, "tail_fraction": TAIL_FRACTION,
                  "stiffness": "nut: thread contacts and teeth at the load (no shaft, no housing)"}
    return ModelSheet(efficiency_forward=fwd["tail_efficiency"], efficiency_backward=bwd["tail_efficiency"],
                      no_load_torque_nm=idle["tail_torque_nm"],
                      static_load_rating_n=float(params.ratings.static_load_rating_n or 0.0),
                      dynamic_load_rating_n=float(params.ratings.dynamic_load_rating_n or 0.0),
                      axial_stiffness_n_per_um=float(stiffness) * 1e-6, conditions=conditions)


# -- a catalogue row ---------------------------------------------------------------------------

_REQUIRED = ("nominal_diameter_m", "lead_m", "starts")


@dataclass(frozen=True)
class Datasheet:
    """One catalogue row: what a roller-screw vendor lists for a nut size (SI units).

    `nominal_diameter_m`, `lead_m`, `starts` are required; every other figure may be None (not
    listed). Efficiencies in (0, 1]; `no_load_torque_nm` the listed starting (no-load) torque.
    """

    nominal_diameter_m: float
    lead_m: float
    starts: int
    n_rollers: int | None = None
    nut_length_m: float | None = None
    nut_outer_diameter_m: float | None = None
    dynamic_load_rating_n: float | None = None
    static_load_rating_n: float | None = None
    efficiency_forward: float | None = None
    efficiency_backward: float | None = None
    no_load_torque_nm: float | None = None
    preload_n: float | None = None

    def __post_init__(self) -> None:
        s = self.starts
        _check(isinstance(s, int) and not isinstance(s, bool) and s >= 3, "starts", s, "a whole number >= 3")
        n = self.n_rollers
        _check(n is None or (isinstance(n, int) and not isinstance(n, bool) and n >= 3), "n_rollers", n,
               "a whole number >= 3")
        for name in ("nominal_diameter_m", "lead_m", "nut_length_m", "nut_outer_diameter_m", "dynamic_load_rating_n",
                     "static_load_rating_n", "no_load_torque_nm"):
            v = getattr(self, name)
            _check(v is None or (is_finite_number(v) and v > 0), name, v, "a finite number > 0")
        for name in ("efficiency_forward", "efficiency_backward"):
            v = getattr(self, name)
            _check(v is None or (is_finite_number(v) and 0 < v <= 1), name, v, "a number in (0, 1]")
        v = self.preload_n
        _check(v is None or (is_finite_number(v) and v >= 0), "preload_n", v, "a finite number >= 0")

    @classmethod
    def from_dict(cls, data: Any) -> Datasheet:
        """From a mapping (a YAML sheet), refusing unknown keys and missing required ones by name."""
        if not isinstance(data, dict):
            raise ParamError(f"datasheet: expected a mapping of {', '.join(f.name for f in fields(cls))}, "
                             f"got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(map(str, set(data) - known))
        if unknown:
            raise ParamError(f"datasheet: unknown key {unknown[0]!r}; allowed: {', '.join(sorted(known))}")
        for name in _REQUIRED:
            if data.get(name) is None:
                raise ParamError(f"datasheet: {name} is required")
        values = {}
        for k, v in data.items():
            if isinstance(v, str) and k not in ("starts", "n_rollers"):
                v = parse_float(v, f"datasheet.{k}")  # YAML 1.1 reads 5e-3 (no dot) as a string
            if k in ("starts", "n_rollers") and isinstance(v, float) and v.is_integer():
                v = int(v)
            if isinstance(v, int) and not isinstance(v, bool) and k not in ("starts", "n_rollers"):
                v = float(v)
            values[k] = v
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


def _check(ok: bool, name: str, value: Any, allowed: str) -> None:
    if not ok:
        raise ParamError(f"datasheet.{name} = {value!r}: must be {allowed}")


# -- a parameter set from a catalogue row --------------------------------------------------------

def most_rollers(screw_radius_m: float, roller_radius_m: float, crest_radius_m: float) -> int:
    """The most rollers whose thread crests clear each other on the pin circle a = r_S + r_R.

    Neighbouring centres 2a sin(π/N) apart must be at least two crest radii apart:
    N ≤ π / asin(r_crest / a).
    """
    a = screw_radius_m + roller_radius_m
    return max(3, math.floor(math.pi / math.asin(min(1.0, crest_radius_m / a)) + 1e-9))


def params_from_datasheet(sheet: Datasheet, base: Params) -> tuple[Params, list[str]]:
    """A parameter set for a catalogue row: its geometry from the row plus the rules below, the rest from `base`.

    Rules (docs/model.md "From a datasheet"): r_S = d₀/2 (the nominal diameter as the screw's
    pitch diameter); the standard design r_R = r_S/(n − 2), r_N = n r_R; P = L/n; the most rollers
    whose crests (r_R + h_t/2) fit on the pin circle; N_T = ⌊0.6 A / P⌋ engaged teeth of a nut of
    length A; the screw root diameter 2 r_S − h_t. Without a nut length the engaged length is
    `base`'s, scaled with d₀. Friction, material, thread-form ratios and rating factors come from
    `base`; every derived mass, inertia and rating is derived anew. Returns the parameter set and
    the list of what was assumed, one line each.
    """
    n, lead = sheet.starts, sheet.lead_m
    g0 = base.geometry
    r_s = sheet.nominal_diameter_m / 2
    r_r = r_s / (n - 2)
    pitch = lead / n
    h_t = g0.tooth_height_per_pitch * pitch
    said = [f"screw pitch radius r_S = d0/2 = {r_s * 1e3:.4g} mm; standard design r_R = r_S/(n - 2) = "
            f"{r_r * 1e3:.4g} mm, r_N = n r_R = {n * r_r * 1e3:.4g} mm; pitch P = L/n = {pitch * 1e3:.4g} mm"]
    if sheet.n_rollers is None:
        n_r = most_rollers(r_s, r_r, r_r + h_t / 2)
        said.append(f"rollers: the most whose crests (r_R + h_t/2) fit on the pin circle: {n_r}")
    else:
        n_r = sheet.n_rollers
    if sheet.nut_length_m is not None:
        engaged = ENGAGED_FRACTION * sheet.nut_length_m
        said.append(f"engaged length {ENGAGED_FRACTION:g} x nut length = {engaged * 1e3:.4g} mm")
    else:
        engaged = g0.n_teeth * g0.pitch_m * sheet.nominal_diameter_m / (2 * g0.screw_radius_m)
        said.append(f"no nut length: engaged length {engaged * 1e3:.4g} mm, the base's scaled with d0")
    n_t = max(1, math.floor(engaged / pitch + 1e-9))
    said.append(f"engaged teeth N_T = {n_t} per roller and side")
    screw_length = max(float(g0.screw_length_m or 0.0), 4 * n_t * pitch)
    elastic: dict[str, Any] = {"bearing_position_m": None, "root_diameter_m": 2 * r_s - h_t,
                               "tooth_effective_width_m": None, "nut_outer_diameter_m": sheet.nut_outer_diameter_m}
    if sheet.preload_n:
        elastic.update(preload_n=sheet.preload_n, preload_kind="oversize_rollers", axial_clearance_m=0.0)
        said.append(f"preload {sheet.preload_n:g} N by oversize rollers (elastic model)")
    data = {"name": f"sheet_{sheet.nominal_diameter_m * 1e3:g}x{lead * 1e3:g}",
            "geometry": {"screw_radius_m": r_s, "roller_radius_m": r_r, "starts": n, "pitch_m": pitch,
                         "n_rollers": n_r, "n_teeth": n_t, "nut_radius_m": None, "gear_ratio": None,
                         "screw_length_m": screw_length, "pin_radius_m": None, "nut_length_m": None},
            "mass": {"screw_inertia_kgm2": None, "roller_mass_kg": None, "roller_inertia_kgm2": None,
                     "carrier_inertia_kgm2": None},
            "friction": {"drag_radius_m": None},
            "elastic": elastic,
            "ratings": {"static_load_rating_n": None, "dynamic_load_rating_n": None}}
    return Params.from_dict(data, base=base), said
