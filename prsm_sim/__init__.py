"""prsm_sim: the pure dynamics core of the planetary roller screw simulator (numpy/scipy only)."""

from prsm_sim.errors import InputError, PrsmError
from prsm_sim.outputs import OUTPUT_FIELDS, InternalBlock, InternalLayout, Outputs, State, Trajectory
from prsm_sim.params import Friction, Geometry, IdealLoss, Loads, MassProperties, ParamError, Params
from prsm_sim.presets import PRESETS, preset
from prsm_sim.simulator import MODELS, Simulator, build_model

__all__ = [
    "PrsmError", "InputError",
    "OUTPUT_FIELDS", "InternalBlock", "InternalLayout", "Outputs", "State", "Trajectory",
    "Friction", "Geometry", "IdealLoss", "Loads", "MassProperties", "ParamError", "Params",
    "PRESETS", "preset", "MODELS", "Simulator", "build_model",
]
