"""Records as plain data and back: numbers, strings, lists and dicts that `json.dumps` writes as they are.

`to_plain(obj)` walks dataclasses, named tuples, tuples, lists, dicts, numbers (Python and
NumPy), arrays and None; `from_plain(data, types)` rebuilds them exactly: a float comes back with
the same bits (JSON writes the shortest repr that reads back to it), a NumPy scalar or array with
its dtype, a tuple as a tuple. It knows no field lists: a dataclass is written as its type's name
and its init fields, so a record that gains a field round-trips without a change here.

Tags (a dict with one key starting with "$"): {"$dc": type name, "fields": {...}} (dataclass),
{"$nt": type name, "items": [...]} (named tuple), {"$tuple": [...]}, {"$dict": {...}} (string keys),
{"$float": "nan" | "inf" | "-inf"} (strict JSON has no such numbers), {"$np": dtype, "value": v},
{"$array": dtype, "shape": [...], "data": [...]}.

A type is rebuilt only if it is in the `types` given to `from_plain` (`reachable_types` collects
them from a record of the same kind): a name read from the data is never imported or looked up
anywhere else.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Iterable
from typing import Any, cast

import numpy as np

from prsm_sim.errors import InputError


def _type_name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _is_named_tuple(obj: object) -> bool:
    return isinstance(obj, tuple) and hasattr(type(obj), "_fields")


def to_plain(obj: Any, _path: str = "state") -> Any:
    """`obj` as plain data (see the module doc); InputError naming the place of a value it cannot write."""
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (np.generic, np.ndarray)):
        return _numpy_to_plain(obj, _path)
    if isinstance(obj, int):
        return int(obj)
    if isinstance(obj, float):
        return float(obj) if math.isfinite(obj) else {"$float": repr(float(obj))}
    plain = _record_to_plain(obj, _path)
    if plain is not None:
        return plain
    reduced = _reduced_dataclass(obj)
    if reduced is not None:  # e.g. a record that pickles as a plain dataclass (PackedOutputs → Outputs)
        return to_plain(reduced, _path)
    raise InputError(f"{_path}: a {type(obj).__name__} cannot be written as plain data")


def _numpy_to_plain(obj: np.generic | np.ndarray, path: str) -> dict:
    if isinstance(obj, np.ndarray):
        return {"$array": obj.dtype.str, "shape": list(obj.shape),
                "data": [to_plain(v, path) for v in obj.ravel().tolist()]}
    return {"$np": obj.dtype.str, "value": to_plain(obj.item(), path)}


def _record_to_plain(obj: Any, path: str) -> Any:
    """A dataclass, named tuple, list, tuple or dict with string keys as plain data; None for anything else."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {"$dc": _type_name(type(obj)),
                "fields": {f.name: to_plain(getattr(obj, f.name), f"{path}.{f.name}")
                           for f in dataclasses.fields(obj) if f.init}}
    if _is_named_tuple(obj):
        return {"$nt": _type_name(type(obj)), "items": [to_plain(v, f"{path}.{n}") for n, v in zip(obj._fields, obj)]}
    if type(obj) is list:
        return [to_plain(v, f"{path}[{i}]") for i, v in enumerate(obj)]
    if type(obj) is tuple:
        return {"$tuple": [to_plain(v, f"{path}[{i}]") for i, v in enumerate(obj)]}
    if type(obj) is dict and all(isinstance(k, str) for k in obj):
        return {"$dict": {k: to_plain(v, f"{path}.{k}") for k, v in obj.items()}}
    return None


def _reduced_dataclass(obj: object):
    """The dataclass instance `obj` pickles as (its `__reduce__` names a dataclass type), or None."""
    try:
        reduced = obj.__reduce__()
        if not isinstance(reduced, tuple):  # a global's name: not a record
            return None
        rebuild, args = reduced[:2]
    except Exception:
        return None
    if isinstance(rebuild, type) and dataclasses.is_dataclass(rebuild) and isinstance(args, tuple):
        return rebuild(*args)
    return None


def reachable_types(*records: Any) -> dict[str, type]:
    """The dataclass and named-tuple types `records` (values, or types) hold, or can hold by their
    types' field annotations (followed through containers, unions and nested records), by name."""
    found: dict[str, type] = {}

    def add_type(tp) -> None:
        if typing.get_origin(tp) is not None:  # tuple[X, ...], X | None, dict[str, X]: their arguments
            for arg in typing.get_args(tp):
                add_type(arg)
            return
        if not isinstance(tp, type):  # Any, a type variable, an unresolved name
            return
        record = dataclasses.is_dataclass(tp) or (issubclass(tp, tuple) and hasattr(tp, "_fields"))
        if not record or _type_name(tp) in found:
            return
        found[_type_name(tp)] = tp
        try:
            hints = typing.get_type_hints(tp)
        except Exception:  # an annotation that does not resolve at run time: the values still count
            hints = {}
        for h in hints.values():
            add_type(h)

    def add_value(v) -> None:
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            add_type(type(v))
            for f in dataclasses.fields(v):
                add_value(getattr(v, f.name))
        elif _is_named_tuple(v):
            add_type(type(v))
            for x in v:
                add_value(x)
        elif isinstance(v, (list, tuple)):
            for x in v:
                add_value(x)
        elif isinstance(v, dict):
            for x in v.values():
                add_value(x)
        else:
            reduced = _reduced_dataclass(v) if not isinstance(v, (int, float, str, bytes, np.generic, np.ndarray)) \
                and v is not None else None
            if reduced is not None:
                add_value(reduced)

    for r in records:
        add_type(r) if isinstance(r, type) else add_value(r)
    return found


def from_plain(data: Any, types: dict[str, type] | Iterable[type], _path: str = "state") -> Any:
    """The value `to_plain` wrote; InputError (one line, naming the place) for data it did not write
    or a record type not in `types`."""
    if not isinstance(types, dict):
        types = {_type_name(t): t for t in types}
    if data is None or isinstance(data, (bool, str, int, float)):
        return data
    if isinstance(data, list):
        return [from_plain(v, types, f"{_path}[{i}]") for i, v in enumerate(data)]
    if not (isinstance(data, dict) and len(data) >= 1):
        raise InputError(f"{_path} = {data!r}: not plain data written by prsm_sim")
    tag = next(iter(data))
    reader = _TAGGED.get(tag)
    if reader is None:
        raise InputError(f"{_path}: unknown tag {tag!r}; not plain data written by prsm_sim")
    try:
        return reader(data, types, _path)
    except InputError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise InputError(f"{_path}: malformed {tag} entry ({type(e).__name__}: {e})") from None


def _float_from_plain(data: dict, types: dict[str, type], path: str) -> float:
    if data["$float"] not in ("nan", "inf", "-inf"):
        raise InputError(f"{path}: unknown tag '$float' value {data['$float']!r}; not plain data written by prsm_sim")
    return float(data["$float"])


def _array_from_plain(data: dict, types: dict[str, type], path: str) -> np.ndarray:
    flat = [from_plain(v, types, path) for v in data["data"]]
    return np.array(flat, dtype=np.dtype(data["$array"])).reshape(data["shape"])


def _record_from_plain(data: dict, types: dict[str, type], path: str) -> Any:
    tag = next(iter(data))
    cls = types.get(data[tag])
    if cls is None:
        raise InputError(f"{path}: record type {data[tag]!r} is not one this state holds "
                         f"(known: {', '.join(sorted(types))})")
    if tag == "$dc":
        return cls(**{k: from_plain(v, types, f"{path}.{k}") for k, v in data["fields"].items()})
    names = cast(Any, cls)._fields  # a named tuple (`reachable_types` admits no other kind here)
    return cls(*(from_plain(v, types, f"{path}.{n}") for n, v in zip(names, data["items"])))


# how each tag `to_plain` writes is read back
_TAGGED = {
    "$float": _float_from_plain,
    "$tuple": lambda d, types, path: tuple(from_plain(v, types, f"{path}[{i}]") for i, v in enumerate(d["$tuple"])),
    "$dict": lambda d, types, path: {str(k): from_plain(v, types, f"{path}.{k}") for k, v in d["$dict"].items()},
    "$np": lambda d, types, path: np.dtype(d["$np"]).type(from_plain(d["value"], types, path)),
    "$array": _array_from_plain,
    "$dc": _record_from_plain,
    "$nt": _record_from_plain,
}
