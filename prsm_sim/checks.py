"""Input checks shared by the whole package: is a value a real number, a finite one."""

from __future__ import annotations

import math

import numpy as np


def is_number(v: object) -> bool:
    """A real number (Python or NumPy int or float), never a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def is_finite_number(v: object) -> bool:
    """A real number (`is_number`) that is finite."""
    return is_number(v) and math.isfinite(v)
