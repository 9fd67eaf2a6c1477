"""Input checks shared by the whole package: is a value a real number, a finite one, does a record
hold what its annotations say."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any

import numpy as np

from prsm_sim.errors import InputError


def is_number(v: object) -> bool:
    """A real number (Python or NumPy int or float), never a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def is_finite_number(v: object) -> bool:
    """A real number (`is_number`) that is finite (an int beyond the float range is not)."""
    if not is_number(v):
        return False
    try:
        return math.isfinite(v)  # type: ignore[arg-type]
    except OverflowError:
        return False


def _refuse(path: str, value: object, expected: str) -> InputError:
    shown = repr(value)
    shown = shown if len(shown) <= 60 else shown[:57] + "..."
    return InputError(f"{path} = {shown}: expected {expected}")


def _check_union(value: object, hint: Any, path: str) -> None:
    for arg in typing.get_args(hint):
        try:
            check_typed(value, arg, path)
            return
        except InputError:
            pass
    raise _refuse(path, value, " or ".join(getattr(a, "__name__", str(a)) for a in typing.get_args(hint)))


def _check_container(value: object, hint: Any, path: str) -> None:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if type(value) is not origin:
        raise _refuse(path, value, f"a {origin.__name__}")
    if origin is dict:
        for k, v in value.items():  # type: ignore[attr-defined]
            check_typed(v, args[1] if args else Any, f"{path}.{k}")
        return
    items = list(value)  # type: ignore[call-overload]
    if origin is tuple and args and not (len(args) == 2 and args[1] is Ellipsis):
        if len(items) != len(args):
            raise _refuse(path, value, f"a tuple of {len(args)} items")
        for i, (v, a) in enumerate(zip(items, args)):
            check_typed(v, a, f"{path}[{i}]")
        return
    for i, v in enumerate(items):
        check_typed(v, args[0] if args else Any, f"{path}[{i}]")


_SCALARS: dict[type, tuple[Any, str]] = {
    float: (is_number, "a real number"),
    int: (lambda v: isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)), "a whole number"),
    bool: (lambda v: isinstance(v, (bool, np.bool_)), "true or false"),
    str: (lambda v: isinstance(v, str), "a string"),
    type(None): (lambda v: v is None, "None"),
}


def check_typed(value: object, hint: Any, path: str) -> None:
    """InputError naming `path` unless `value` matches the type annotation `hint`, followed into
    unions, tuples, lists, dicts and the fields of dataclasses and named tuples (by their own
    annotations). A float may be NaN here: which values are finite is the caller's to say."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        return _check_union(value, hint, path)
    if origin in (tuple, list, dict):
        return _check_container(value, hint, path)
    if hint in _SCALARS:
        ok, expected = _SCALARS[hint]
        if not ok(value):
            raise _refuse(path, value, expected)
        return
    if not isinstance(hint, type):  # Any, a type variable: nothing to check
        return
    if not isinstance(value, hint):
        raise _refuse(path, value, f"a {hint.__name__}")
    if dataclasses.is_dataclass(value):
        hints = typing.get_type_hints(type(value))
        for f in dataclasses.fields(value):
            check_typed(getattr(value, f.name), hints.get(f.name, Any), f"{path}.{f.name}")
    elif isinstance(value, tuple) and hasattr(value, "_fields"):
        hints = typing.get_type_hints(type(value))
        for name in value._fields:
            check_typed(getattr(value, name), hints.get(name, Any), f"{path}.{name}")
    return None
