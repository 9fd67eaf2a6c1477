"""JSON for the command-line tools: numpy values become plain numbers, NaN and ±inf become null.

JSON has no NaN; a consumer must read "undefined" (e.g. an efficiency when no power flows),
not a number and not an invalid document.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def dumps(x: Any) -> str:
    """Indented, strict JSON (allow_nan=False: a NaN that slipped through is a bug, not output)."""
    return json.dumps(jsonable(x), indent=2, ensure_ascii=False, allow_nan=False)
