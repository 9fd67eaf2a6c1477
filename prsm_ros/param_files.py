"""Parameter files: YAML in and out, with errors that name the file and what was wrong.

A file holds the nested groups of `prsm_sim.Params.to_dict()`; an optional top-level
`preset: NAME` supplies every value the file leaves out, so a file can be a short diff.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from prsm_sim import ParamError, Params, preset
from prsm_sim.actuator import ActuatorParams, actuator_params_from_dict


def params_to_yaml(params: Params) -> str:
    """Every parameter, resolved, as YAML (loads back to an equal Params)."""
    return yaml.safe_dump(params.to_dict(), sort_keys=False)


def _yaml_mapping(text: str, source: str, what: str) -> dict:
    """The YAML text's top-level mapping, loaded within `limits.load_yaml`'s bounds; ParamError names
    `source`, the line and what was wrong, never the text."""
    from prsm_ros.limits import load_yaml
    data = load_yaml(text, source=source, error=ParamError)
    if not isinstance(data, dict):
        raise ParamError(f"{source}: expected a mapping of {what}, got {type(data).__name__}")
    return dict(data)


# A key or value that reads as a name (a parameter, a preset, a model) may be echoed in an error;
# any other text came from the file and is not printed back (a file given by mistake: a key, a log).
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.\-]{0,63}")
HIDDEN = "<text from the file>"


def _texts(doc) -> set[str]:
    """Every string key and value of a loaded document that is not a name (`_NAME`)."""
    found: set[str] = set()
    seen: set[int] = set()
    todo = [doc]
    while todo:
        item = todo.pop()
        if isinstance(item, str):
            if not _NAME.fullmatch(item):
                found.add(item)
        elif isinstance(item, (dict, list)) and id(item) not in seen:  # aliases share objects: visit once
            seen.add(id(item))
            todo.extend([*item.keys(), *item.values()] if isinstance(item, dict) else item)
    return found


def without_file_text(message: str, doc) -> str:
    """`message` with every text of `doc` that is not a name replaced by HIDDEN (its repr too)."""
    for text in sorted(_texts(doc), key=len, reverse=True):
        for form in (repr(text), text):
            if form:
                message = message.replace(form, HIDDEN)
    return message


def _read_text(path: str | Path, what: str) -> str:
    """A regular UTF-8 file within `limits.TEXT_FILE_MAX_BYTES` (ParamError naming the file otherwise)."""
    from prsm_ros.limits import read_text_file
    return read_text_file(path, what=what, error=ParamError)


def params_from_yaml(text: str, source: str = "<string>") -> Params:
    """Parse and validate; ParamError names `source` and the offending field or line."""
    data = _yaml_mapping(text, source, "parameter groups")
    base_name = data.pop("preset", None)
    try:
        base = preset(base_name) if base_name is not None else None
        return Params.from_dict(data, base=base)
    except ParamError as e:
        raise ParamError(f"{source}: {without_file_text(str(e), [data, base_name])}") from None


def load_params_file(path: str | Path) -> Params:
    return params_from_yaml(_read_text(path, "parameter file"), str(Path(path)))


def load_actuator_file(path: str | Path) -> ActuatorParams:
    """The actuator around the screw from a YAML file: the groups of the node's `actuator`
    parameter (motor, drive, sensors, stops, brake, faults); ParamError names the file and the field."""
    source = str(Path(path))
    data = _yaml_mapping(_read_text(path, "actuator file"), source, "actuator groups")
    try:
        return actuator_params_from_dict(data)
    except ParamError as e:
        raise ParamError(f"{source}: {without_file_text(str(e), data)}") from None


def resolve_params(preset_name: str | None, params_file: str | None, overrides: dict[str, Any] | None = None) -> Params:
    """The parameter set a command asked for: --params FILE, else --preset NAME (default jones2016)."""
    if preset_name and params_file:
        raise ParamError("give --preset or --params, not both")
    params = load_params_file(params_file) if params_file else preset(preset_name or "jones2016")
    return params.with_overrides(overrides) if overrides else params
