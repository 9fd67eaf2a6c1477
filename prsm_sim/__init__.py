"""prsm_sim: the pure dynamics core of the planetary roller screw simulator (numpy/scipy only).

.. include:: ../docs/guide.md
"""

from prsm_sim.errors import DriveLoopWarning, InputError, ModelError, ParamError, PrsmError
from prsm_sim.models.registry import MODELS, build_model
from prsm_sim.params import Friction, Geometry, IdealLoss, Loads, MassProperties, Params
from prsm_sim.presets import PRESETS, preset
from prsm_sim.simulator import Simulator
from prsm_sim.stepping.records import OUTPUT_FIELDS, InternalBlock, InternalLayout, Outputs, State
from prsm_sim.stepping.trajectory import Trajectory
from prsm_sim.session import Session, SessionConfig


def _version() -> str:
    """The installed distribution's version; from pyproject.toml beside the package when not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("prsm")
    except PackageNotFoundError:
        import re
        from pathlib import Path

        pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
        try:
            text = pyproject.read_text(encoding="utf-8")
        except OSError:
            return "0+unknown"
        # the [project] table's version line (tomllib is 3.11+, the project supports 3.10)
        m = re.search(r'(?ms)^\[project\]\s*$.*?^version\s*=\s*"([^"]+)"', text)
        return m.group(1) if m else "0+unknown"


__version__: str = _version()
"""Version of the `prsm` distribution (PEP 440 string)."""

__all__ = [
    "__version__",
    "PrsmError", "ParamError", "InputError", "ModelError", "DriveLoopWarning",
    "OUTPUT_FIELDS", "InternalBlock", "InternalLayout", "Outputs", "State", "Trajectory",
    "Friction", "Geometry", "IdealLoss", "Loads", "MassProperties", "Params",
    "PRESETS", "preset", "MODELS", "Simulator", "build_model", "Session", "SessionConfig",
]
