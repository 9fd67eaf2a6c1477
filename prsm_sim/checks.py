"""Input checks shared by the whole package: is a value a real number, a finite one; a parameter
field refused in one line (`group.name = value: what is allowed`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from prsm_sim.errors import ParamError


def is_number(v: object) -> bool:
    """A real number (Python or NumPy int or float), never a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def is_finite_number(v: object) -> bool:
    """A real number (`is_number`) that is finite."""
    return is_number(v) and math.isfinite(v)


def check_field(group: str, name: str, value: Any, ok: bool, allowed: str) -> None:
    """ParamError ``group.name = value: allowed`` unless `ok`."""
    if not ok:
        raise ParamError(f"{group}.{name} = {value!r}: {allowed}")


def require_positive(group: str, obj: Any, *names: str) -> None:
    """Each field `names` of `obj` a finite number > 0 (ParamError naming the first that is not)."""
    for n in names:
        v = getattr(obj, n)
        check_field(group, n, v, is_finite_number(v) and v > 0, "must be a finite number > 0")


def require_non_negative(group: str, obj: Any, *names: str) -> None:
    """Each field `names` of `obj` a finite number >= 0 (ParamError naming the first that is not)."""
    for n in names:
        v = getattr(obj, n)
        check_field(group, n, v, is_finite_number(v) and v >= 0, "must be a finite number >= 0")
