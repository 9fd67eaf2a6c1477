"""The model registry: every model level by name, and `build_model` (SciPy's `solve_ivp` METHODS habit).

It sits above the models, so no model imports it; `Simulator`, the actuator (which builds its screw
model) and the tools look models up here.
"""

from __future__ import annotations

from typing import Protocol, cast

from prsm_sim.errors import ParamError
from prsm_sim.models.elastic import ElasticModel
from prsm_sim.models.fu2018 import Fu2018
from prsm_sim.models.ideal import Ideal
from prsm_sim.models.jones2016 import Jones2016
from prsm_sim.models.kernels import check_kernel
from prsm_sim.params import Params
from prsm_sim.stepping.model import Model


class _KernelModelClass(Protocol):
    """A model class with `Model.compiled_kernel` set: its constructor also takes the kernel (`models.kernels`)."""

    def __call__(self, params: Params, dt_s: float, kernel: str = ...) -> Model: ...


MODELS: dict[str, type[Model]] = {"ideal": Ideal, "jones2016": Jones2016, "fu2018": Fu2018, "elastic": ElasticModel}


def model_class(model: str) -> type[Model]:
    """The class of the named model, to ask its capabilities (`Model.has_axial_chain`, …) before building it.

    Raises
    ------
    ParamError
        Unknown model name (the message names the field `model` and lists the known ones).
    """
    try:
        return MODELS[model]
    except (KeyError, TypeError):
        raise ParamError(f"model = {model!r}: known models are {', '.join(MODELS)}") from None


def build_model(params: Params, model: str, dt_s: float, kernel: str = "compiled") -> Model:
    """Build the named model for a parameter set and a fixed step.

    Parameters
    ----------
    params : Params
        A validated parameter set, e.g. ``preset("s30")``.
    model : str
        One of `MODELS`: ``"ideal"`` (rigid lead with efficiencies), ``"jones2016"`` (2-DOF
        viscous, docs/model.md §4.1), ``"fu2018"`` (spatial force system, docs/model.md §4.2) or
        ``"elastic"`` (fu2018 with an axially compliant screw–nut chain, docs/model.md §4.3).
    dt_s : float
        Fixed step, s, in (0, 0.1].
    kernel : {"compiled", "reference"}, default "compiled"
        For the models with a compiled step (``"fu2018"``, ``"elastic"``): numba code, or the
        pure-Python reference it is tested against (same results to 1e-12). The others have one path.

    Returns
    -------
    Model
        The pure model: ``step(state, torque_nm, load_n) -> (State, Outputs)`` (`stepping.model.Model`).

    Raises
    ------
    ParamError
        Unknown model name (the message lists the known ones), a step out of range or an unknown kernel.
    """
    cls = model_class(model)
    check_kernel(kernel)
    cls.check_params(params)
    if cls.compiled_kernel:
        return cast(_KernelModelClass, cls)(params, dt_s, kernel=kernel)
    return cls(params, dt_s)
