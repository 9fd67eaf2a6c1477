"""prsm_sim: the pure dynamics core of the planetary roller screw simulator (numpy/scipy only)."""

from .outputs import OUTPUT_FIELDS, InternalBlock, InternalLayout, Outputs, State, Trajectory
from .params import Friction, Geometry, IdealLoss, Loads, MassProperties, ParamError, Params
from .presets import PRESETS, preset
from .simulator import MODELS, Simulator, build_model

__all__ = [
    "OUTPUT_FIELDS", "InternalBlock", "InternalLayout", "Outputs", "State", "Trajectory",
    "Friction", "Geometry", "IdealLoss", "Loads", "MassProperties", "ParamError", "Params",
    "PRESETS", "preset", "MODELS", "Simulator", "build_model",
]
