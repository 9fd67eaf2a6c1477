"""The parameters a fit may free: their bounds, units and scales, and the default set of a model.

Names are the parameter files' dotted keys (`Params.with_overrides`), plus `DELAY_KEY`, the
command-path delay in whole steps, which is not a parameter of the screw but of the bench's signal
path and is reported beside the parameters. The default set is asked of the model's capabilities
(`Model.has_friction_laws`, `has_axial_chain`), never of its name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from prsm_sim.errors import InputError
from prsm_sim.models.registry import model_class
from prsm_sim.params import Params

DELAY_KEY = "command.delay_steps"  # the command-path delay, whole steps (fit.json only, not a Params field)
MAX_DELAY_STEPS = 5


@dataclass(frozen=True)
class FreeParameter:
    """A parameter the fit moves: dotted name, unit, bounds, and whether it moves on a log scale.

    A log-scale parameter is searched as log(value), so a mass or a stiffness spanning decades is as
    easy to move as a friction coefficient; its interval is then symmetric in log(value).
    """

    name: str
    unit: str
    lower: float
    upper: float
    log: bool = False

    def __post_init__(self) -> None:
        if not (self.lower < self.upper) or (self.log and self.lower <= 0.0):
            raise InputError(f"--free {self.name}: bounds [{self.lower:g}, {self.upper:g}] are empty"
                             + (" or not positive (log scale)" if self.log else ""))

    def to_unit(self, value: float) -> float:
        """The value as a point of [0, 1] between the bounds (log or linear)."""
        if self.log:
            value = math.log(max(value, self.lower))
            lo, hi = math.log(self.lower), math.log(self.upper)
        else:
            lo, hi = self.lower, self.upper
        return min(1.0, max(0.0, (value - lo) / (hi - lo)))

    def from_unit(self, u: float) -> float:
        if self.log:
            lo, hi = math.log(self.lower), math.log(self.upper)
            return math.exp(lo + u * (hi - lo))
        return self.lower + u * (self.upper - self.lower)

    def span(self) -> float:
        """d(log value)/du for a log scale, d(value)/du otherwise."""
        return math.log(self.upper / self.lower) if self.log else self.upper - self.lower


# name → (unit, lower, upper, log); a mass or stiffness bound is relative to the base value (factor)
_KNOWN: dict[str, tuple[str, float, float, bool]] = {
    "mass.moved_mass_kg": ("kg", 0.05, 20.0, True),
    "friction.mu_screw_roller": ("1", 0.0, 0.45, False),
    "friction.mu_pin": ("1", 0.0, 0.5, False),
    "friction.mu_nut_roller_rolling": ("1", 0.0, 0.05, False),
    "friction.viscous_n_s_m": ("N·s/m", 0.0, 5000.0, False),
    "ideal.efficiency_forward": ("1", 0.05, 1.0, False),
    "ideal.efficiency_backward": ("1", -0.5, 1.0, False),
    "ideal.viscous_nm_s_rad": ("N·m·s/rad", 0.0, 0.05, False),
    "elastic.housing_stiffness_n_per_m": ("N/m", 1e6, 1e11, True),
    "elastic.axial_clearance_m": ("m", 0.0, 1e-4, False),
    "drag.seal_friction_n_per_m": ("N/m", 0.0, 2000.0, False),
    "drag.internal_preload_n": ("N", 0.0, 20000.0, False),
    "drag.film_area_m2": ("m²", 0.0, 1e-4, False),
}
_RELATIVE = {"mass.moved_mass_kg"}  # bounds are factors of the base value


def base_value(params: Params, name: str) -> float:
    group, field = name.split(".")
    return float(getattr(getattr(params, group), field))


def free_parameter(params: Params, name: str) -> FreeParameter:
    """The bounds of `name` for a fit from `params` (InputError naming it when it is not a number one can fit)."""
    if name == DELAY_KEY:
        return FreeParameter(DELAY_KEY, "steps", 0.0, float(MAX_DELAY_STEPS))
    if name not in Params.override_keys():
        raise InputError(f"--free {name!r}: not a parameter; parameter files' dotted names are e.g. "
                         "mass.moved_mass_kg, friction.mu_screw_roller (prsm-sim params lists them)")
    value = getattr(getattr(params, name.split(".")[0]), name.split(".")[1])
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"--free {name} = {value!r}: only real-valued parameters can be fitted")
    if name in _KNOWN:
        unit, lo, hi, log = _KNOWN[name]
        if name in _RELATIVE:
            lo, hi = lo * value, hi * value
        return FreeParameter(name, unit, lo, hi, log)
    if not math.isfinite(value) or value <= 0.0:
        raise InputError(f"--free {name} = {value!r}: no bounds known for it and its base value is not a positive "
                         "number to scale them from")
    return FreeParameter(name, _unit_of(name), value / 10.0, value * 10.0, True)


def _unit_of(name: str) -> str:
    suffixes = (("_kgm2", "kg·m²"), ("_kg", "kg"), ("_m", "m"), ("_n_per_m", "N/m"), ("_n", "N"), ("_pa", "Pa"),
                ("_m2_s", "m²/s"), ("_kg_m3", "kg/m³"))
    return next((u for s, u in suffixes if name.endswith(s)), "1")


def default_free(params: Params, model: str) -> list[str]:
    """What a fit frees by default for `model` (module docstring): the moved mass, the no-load drag and the
    load-dependent friction of the model, the command-path delay, and on an axial chain its stiffness
    and backlash."""
    cls = model_class(model)
    names = ["mass.moved_mass_kg"]
    if cls.has_friction_laws:
        names.append("friction.mu_screw_roller")
    else:
        names += ["ideal.efficiency_forward", "ideal.efficiency_backward"]
    names += no_load_drag_keys(params, model)
    if cls.has_axial_chain:
        names += ["elastic.housing_stiffness_n_per_m", "elastic.axial_clearance_m"]
    return names + [DELAY_KEY]


def no_load_drag_keys(params: Params, model: str) -> list[str]:
    """The coefficient that sets the model's load-independent (no-load) torque: the seal friction of the
    drag group where the parameter set has one, else the viscous screw torque of a model without
    friction laws (none for the others)."""
    if any(f.name == "drag" for f in fields(Params)):
        return ["drag.seal_friction_n_per_m"]
    return [] if model_class(model).has_friction_laws else ["ideal.viscous_nm_s_rad"]


def prepared_base(params: Params, names: list[str]) -> Params:
    """The base with what freeing `names` needs switched on: a freed drag coefficient turns the drag on
    (with it off the coefficient would act on nothing)."""
    if any(n.startswith("drag.") for n in names) and not getattr(getattr(params, "drag", None), "enabled", True):
        return params.with_overrides({"drag.enabled": True})
    return params
