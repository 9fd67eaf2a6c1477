"""A parameter set calibrated to a catalogue row: geometry by rule, then friction and rating factors fitted.

docs/model.md "From a datasheet". `params_from_datasheet` gives the geometry; this module then
fits, each by a one-dimensional root search on the model's own datasheet (`model_datasheet`), so
the fitted size reproduces its row:

- the rating factors f_0 and f_c (`ratings.static_factor`, `ratings.dynamic_factor`) to C_0a and C_a
  (the ratings are proportional to them: one step);
- the screw–roller friction coefficient (`friction.mu_screw_roller`) to the mean of the listed
  efficiencies η and η′, and the share of the base's lead-independent losses (pin and nut–roller
  rolling friction, scaled together) to their difference η − η′ (`fit_friction`);
- the no-load drag (`NO_LOAD_KEYS`, the drag law's coefficients, scaled together) to the listed
  no-load torque; the drag also lowers η, so the friction is fitted once more after it.

Everything else (material, thread-form ratios, the other friction laws, the drag law's other
coefficients) comes from the base parameter set: a second size of a product line is its own row
with the first size's calibrated file as the base.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any
from collections.abc import Callable

from prsm_sim.datasheet import Datasheet, ModelSheet, datasheet_load_n, model_datasheet, params_from_datasheet
from prsm_sim.datasheet import DEFAULT_SPEED_RAD_S, RUN_S, steady_run
from prsm_sim.models.registry import model_class
from prsm_sim.params import ParamError, Params

MU_MAX = 0.45  # upper end of the screw–roller friction search
EFFICIENCY_TOL = 2e-4  # root tolerance on the fitted mean efficiency
# the drag laws' coefficients scaled together to the no-load torque (docs/model.md §4.5): the seals'
# lead-independent torque and the idle flanks' lead-proportional one, in the base's proportion
NO_LOAD_KEYS: tuple[str, ...] = ("drag.seal_friction_n_per_m", "drag.internal_preload_n")
GAP_TOL = 1e-3  # root tolerance on the fitted η − η′
# load-proportional losses that do not scale with the lead: scaled together by the η − η′ fit
LEAD_INDEPENDENT_KEYS = ("friction.mu_pin", "friction.mu_nut_roller_rolling")


@dataclass(frozen=True)
class FittedValue:
    """One fitted parameter: the key, its value, the sheet figure it matches and how well."""

    key: str
    value: float
    figure: str
    target: float
    achieved: float


@dataclass(frozen=True)
class Calibration:
    """The result of `calibrate`: the parameter set, what was assumed, what was fitted, the comparison."""

    params: Params
    assumptions: list[str]
    fitted: list[FittedValue]
    sheet: Datasheet
    model: str
    model_sheet: ModelSheet
    notes: list[str] = field(default_factory=list)

    def comparison(self) -> list[dict[str, Any]]:
        """Each figure the sheet lists beside the model's, with the ratio model / sheet."""
        ms = self.model_sheet.to_dict()
        rows = []
        for name in ("efficiency_forward", "efficiency_backward", "no_load_torque_nm", "static_load_rating_n",
                     "dynamic_load_rating_n"):
            listed = getattr(self.sheet, name)
            if listed is not None:
                rows.append({"figure": name, "sheet": listed, "model": float(ms[name]),
                             "ratio": float(ms[name]) / listed})
        return rows


def _efficiencies(params: Params, model: str, dt_s: float) -> tuple[float, float]:
    f = datasheet_load_n(params)
    fwd = steady_run(params, model, dt_s, f, DEFAULT_SPEED_RAD_S, RUN_S)["tail_efficiency"]
    bwd = steady_run(params, model, dt_s, -f, DEFAULT_SPEED_RAD_S, RUN_S)["tail_efficiency"]
    return fwd, bwd


def _root(fn: Callable[[float], float], lo: float, hi: float, tol: float) -> float | None:
    """A root of a monotone fn on [lo, hi] by bisection on the secant (Illinois method); None if not bracketed."""
    f_lo, f_hi = fn(lo), fn(hi)
    if not (math.isfinite(f_lo) and math.isfinite(f_hi)) or f_lo * f_hi > 0:
        return None
    side = 0
    for _ in range(60):
        x = hi - f_hi * (hi - lo) / (f_hi - f_lo) if f_hi != f_lo else 0.5 * (lo + hi)
        fx = fn(x)
        if not math.isfinite(fx):
            x, fx = 0.5 * (lo + hi), fn(0.5 * (lo + hi))
        if abs(fx) < tol or hi - lo < 1e-12:
            return x
        if fx * f_hi > 0:
            hi, f_hi = x, fx
            if side == -1:
                f_lo /= 2
            side = -1
        else:
            lo, f_lo = x, fx
            if side == 1:
                f_hi /= 2
            side = 1
    return x


def fit_ratings(params: Params, sheet: Datasheet) -> tuple[Params, list[FittedValue]]:
    """Scale f_0 and f_c so the derived ratings equal the sheet's (ratings ∝ their factor)."""
    r = params.ratings
    out: list[FittedValue] = []
    over: dict[str, float | None] = {}
    for figure, factor in (("static_load_rating_n", "static_factor"), ("dynamic_load_rating_n", "dynamic_factor")):
        listed = getattr(sheet, figure)
        if listed is None:
            continue
        over[f"ratings.{factor}"] = getattr(r, factor) * listed / getattr(r, figure)
    if not over:
        return params, out
    over.update({"ratings.static_load_rating_n": None, "ratings.dynamic_load_rating_n": None})
    p = params.with_overrides(over)
    for key, value in over.items():
        if value is not None:
            figure = "static_load_rating_n" if key.endswith("static_factor") else "dynamic_load_rating_n"
            out.append(FittedValue(key, value, figure, getattr(sheet, figure), getattr(p.ratings, figure)))
    return p, out


def _fit_mu(params: Params, model: str, dt_s: float, target: float,
            use: tuple[bool, bool]) -> tuple[float | None, tuple[float, float]]:
    """μ_SR so the mean of the listed efficiencies (`use`: which of η, η′) is `target`; and (η, η′) there."""
    seen: dict[float, tuple[float, float]] = {}

    def mean_eff(mu: float) -> float:
        e = _efficiencies(params.with_overrides({"friction.mu_screw_roller": mu}), model, dt_s)
        seen[mu] = e
        vals = [x for x, u in zip(e, use, strict=True) if u]
        return sum(vals) / len(vals) - target

    mu = _root(mean_eff, 0.0, MU_MAX, EFFICIENCY_TOL)
    return mu, seen.get(mu, (math.nan, math.nan)) if mu is not None else (math.nan, math.nan)


def _listed_efficiencies(sheet: Datasheet) -> tuple[tuple[bool, bool], float | None, float | None]:
    """(which of η, η′ the sheet lists; their mean; η − η′ where both are listed)."""
    ef, eb = sheet.efficiency_forward, sheet.efficiency_backward
    use = (ef is not None, eb is not None)
    listed = [v for v in (ef, eb) if v is not None]
    mean = sum(listed) / len(listed) if listed else None
    return use, mean, (ef - eb if ef is not None and eb is not None else None)


def fit_friction(params: Params, sheet: Datasheet, model: str, dt_s: float) -> tuple[Params, list[FittedValue], str]:
    """Friction fitted to the listed efficiencies (module docstring).

    μ_SR sets the mean of η and η′. Where both are listed, their difference η − η′ sets s, the
    share (0 … 1) of the base's load-proportional, lead-independent losses (pin and nut–roller
    rolling friction: `LEAD_INDEPENDENT_KEYS`) that stays: they widen η − η′ at a given mean, the
    screw–roller sliding hardly does (docs/model.md §4.2).
    """
    use, target, gap = _listed_efficiencies(sheet)
    if target is None:
        return params, [], "no efficiency listed: friction kept from the base"
    base_values = {k: _get(params, k) for k in LEAD_INDEPENDENT_KEYS}
    scaled = lambda s: params.with_overrides({k: s * v for k, v in base_values.items()})
    fits: dict[float, tuple[float | None, tuple[float, float]]] = {}

    def gap_error(s: float) -> float:
        fits[s] = _fit_mu(scaled(s), model, dt_s, target, use)
        mu, e = fits[s]
        return e[0] - e[1] - gap if mu is not None and gap is not None else math.nan

    share = 1.0
    if gap is not None and any(base_values.values()):
        s = _root(gap_error, 0.0, 1.0, GAP_TOL)
        # not bracketed: the end of [0, 1] whose η − η′ comes nearer the sheet's
        share = s if s is not None else min((0.0, 1.0), key=lambda x: abs(gap_error(x)) if x not in fits
                                            else abs(fits[x][1][0] - fits[x][1][1] - gap))
    if share not in fits:
        fits[share] = _fit_mu(scaled(share), model, dt_s, target, use)
    mu, e = fits[share]
    if mu is None:
        return params, [], (f"efficiency {target:.4g} out of reach with friction.mu_screw_roller in [0, {MU_MAX}]: "
                            "the base's other losses already exceed it; friction kept from the base")
    p = scaled(share).with_overrides({"friction.mu_screw_roller": mu})
    vals = [x for x, u in zip(e, use, strict=True) if u]
    out = [FittedValue("friction.mu_screw_roller", mu, "mean listed efficiency", target, sum(vals) / len(vals))]
    if gap is not None:
        out += [FittedValue(k, _get(p, k), "efficiency_forward - efficiency_backward", gap, e[0] - e[1])
                for k in LEAD_INDEPENDENT_KEYS]
    return p, out, ""


def _get(params: Params, key: str) -> float:
    group, name = key.split(".")
    return float(getattr(getattr(params, group), name))


def fit_no_load(params: Params, sheet: Datasheet, model: str, dt_s: float,
                keys: tuple[str, ...]) -> tuple[Params, list[FittedValue], str]:
    """Scale the drag coefficients `keys` together so the model's no-load torque is the sheet's.

    The no-load torque is a sum of terms each proportional to one of them, so one common factor
    keeps the base's split (e.g. seals against the idle flanks) and fits the sum; a few
    proportional steps absorb the small coupling through the carrier's speed.
    """
    if sheet.no_load_torque_nm is None:
        return params, [], "no no-load torque listed: the drag kept from the base"
    if not keys:
        return params, [], f"model {model!r} has no drag coefficient to fit: no-load torque not calibrated"
    target = sheet.no_load_torque_nm
    if not params.drag.enabled:  # a listed no-load torque is a drag the base left off
        params = params.with_overrides({"drag.enabled": True})
    values = {k: _get(params, k) for k in keys}
    t0 = model_datasheet(params, model, dt_s=dt_s).no_load_torque_nm
    for _ in range(4):
        if not (t0 > 0 and any(values.values())):
            return params, [], (f"no-load torque {t0:.3g} N·m with {', '.join(keys)} = {list(values.values())}: "
                                "cannot scale it to the sheet's")
        values = {k: v * target / t0 for k, v in values.items()}
        params = params.with_overrides(values)
        t0 = model_datasheet(params, model, dt_s=dt_s).no_load_torque_nm
        if abs(t0 / target - 1) < 1e-3:
            break
    return params, [FittedValue(k, v, "no_load_torque_nm", target, t0) for k, v in values.items()], ""


def calibrate(sheet: Datasheet, base: Params, model: str = "fu2018", *, dt_s: float = 1e-3,
              no_load_keys: tuple[str, ...] = NO_LOAD_KEYS,
              progress: Callable[[str], None] | None = None) -> Calibration:
    """A parameter set for `sheet` on `model`, its friction and rating factors fitted (module docstring).

    `progress(message)` is told of each stage (the friction fits run the model for tens of seconds).
    """
    if model_class(model).takes_efficiencies:
        raise ParamError(f"model = {model!r}: it takes its efficiencies as parameters; calibrate a model whose "
                         "efficiencies follow from its friction (fu2018, elastic, jones2016)")
    say = progress or (lambda message: None)
    params, assumed = params_from_datasheet(sheet, base)
    params, fitted = fit_ratings(params, sheet)
    notes = []
    say("fitting the friction to the efficiencies")
    params, fv, note = fit_friction(params, sheet, model, dt_s)
    say("fitting the drag to the no-load torque")
    params, nv, note2 = fit_no_load(params, sheet, model, dt_s, no_load_keys)
    if nv:  # the drag lowers η and the friction sets the idle flanks' torque: once more each
        say("fitting the friction again with the drag in place")
        params, fv, note = fit_friction(params, sheet, model, dt_s)
        say("fitting the drag again with that friction")
        params, nv, note2 = fit_no_load(params, sheet, model, dt_s, no_load_keys)
    say("computing the model's datasheet")
    fitted += fv + nv
    notes += [n for n in (note, note2) if n]
    return Calibration(params=params, assumptions=assumed, fitted=fitted, sheet=sheet, model=model,
                       model_sheet=model_datasheet(params, model, dt_s=dt_s), notes=notes)


def predict(sheet: Datasheet, calibrated: Params, model: str = "fu2018", *, dt_s: float = 1e-3) -> ModelSheet:
    """The model's datasheet for another size of the line: the row's geometry by rule, all else from `calibrated`.

    Only the row's geometry (d₀, lead, starts, nut length and diameter, rollers) enters; its listed
    efficiencies, torque and ratings are what the prediction is compared with.
    """
    params, _ = params_from_datasheet(sheet, calibrated)
    return model_datasheet(params, model, dt_s=dt_s)
