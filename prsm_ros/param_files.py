"""Parameter files: YAML in and out, with errors that name the file and what was wrong.

A file holds the nested groups of `prsm_sim.Params.to_dict()`; an optional top-level
`preset: NAME` supplies every value the file leaves out, so a file can be a short diff.
"""

from __future__ import annotations

import math
from dataclasses import fields
import re
from pathlib import Path
from typing import Any

import yaml

from prsm_sim import ParamError, Params, preset
from prsm_sim.actuator import (ActuatorParams, BrakeParams, DriveParams, Fault, MotorParams, SensorParams, StopParams,
                               actuator_params_from_dict, fault_from_dict, parse_faults)
from prsm_sim.params import parse_float


def params_to_yaml(params: Params) -> str:
    """Every parameter, resolved, as YAML (loads back to an equal Params)."""
    return yaml.safe_dump(params.to_dict(), sort_keys=False)


def yaml_mapping(text: str, source: str, what: str) -> dict:
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


def read_param_text(path: str | Path, what: str) -> str:
    """A regular UTF-8 file within `limits.TEXT_FILE_MAX_BYTES` (ParamError naming the file otherwise)."""
    from prsm_ros.limits import read_text_file
    return read_text_file(path, what=what, error=ParamError)


def params_from_yaml(text: str, source: str = "<string>") -> Params:
    """Parse and validate; ParamError names `source` and the offending field or line."""
    data = yaml_mapping(text, source, "parameter groups")
    base_name = data.pop("preset", None)
    try:
        base = preset(base_name) if base_name is not None else None
        return Params.from_dict(data, base=base)
    except ParamError as e:
        raise ParamError(f"{source}: {without_file_text(str(e), [data, base_name])}") from None


def load_params_file(path: str | Path) -> Params:
    return params_from_yaml(read_param_text(path, "parameter file"), str(Path(path)))


def load_actuator_file(path: str | Path) -> ActuatorParams:
    """The actuator around the screw from a YAML file: the groups of the node's `actuator`
    parameter (motor, drive, sensors, stops, brake, faults); ParamError names the file and the field."""
    source = str(Path(path))
    data = yaml_mapping(read_param_text(path, "actuator file"), source, "actuator groups")
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


# -- the actuator from node-style parameters (the node's parameters, the FMU's build options) --------------------
ACTUATOR_PREFIX = "actuator."
FAULTS_PREFIX = "faults."
FAULT_FIELDS = tuple(f.name for f in fields(Fault))  # faults.<name>.<field>
# the groups of the actuator, each a frozen dataclass of prsm_sim.actuator (the drive runs in the session's `command_interface`)
ACTUATOR_GROUPS: dict[str, type] = {"motor": MotorParams, "drive": DriveParams, "sensors": SensorParams,
                                    "stops": StopParams, "brake": BrakeParams}
# What a fault's value may be, like a command's bound: a larger one is a mistake or an attack,
# never a test (a jam 1e300 N·m, a friction factor of a million), and is refused.
FAULT_VALUE_LIMITS = {"friction_surge": (100.0, ""), "lubrication_loss": (100.0, ""), "jam": (1e6, "N·m"),
                      "sensor_bias": (1e6, "in the sensor's unit"), "sensor_noise": (1e6, "in the sensor's unit"),
                      "backlash": (1.0, "m/s")}
FAULT_START_LIMIT_S = 1e9


def bound_fault(f: Fault) -> Fault:
    """The fault, or ParamError when its value or start lies beyond what any test needs."""
    limit, unit = FAULT_VALUE_LIMITS.get(f.kind, (None, ""))
    if limit is not None and abs(f.value) > limit:
        raise ParamError(f"fault.value = {f.value!r}: {f.kind} allows |value| <= {limit:g}" + (f" {unit}" if unit else ""))
    if f.start_s > FAULT_START_LIMIT_S:
        raise ParamError(f"fault.start_s = {f.start_s!r}: must be <= {FAULT_START_LIMIT_S:g} s")
    return f


def is_fault_field(name: str) -> bool:
    """`faults.<name>.<field>` with a field of prsm_sim.actuator.Fault."""
    parts = name.split(".")
    return len(parts) == 3 and parts[0] + "." == FAULTS_PREFIX and parts[1] != "" and parts[2] in FAULT_FIELDS


def _fault_field_value(name: str, key: str, v: Any) -> Any:
    if key in ("sensor", "roller") and (v == "" or (isinstance(v, float) and math.isnan(v))):
        return None  # the string list's "not given": no sensor, all rollers
    if key not in ("kind", "sensor") and isinstance(v, str):
        return parse_float(v, f"parameter {name}")  # YAML 1.1 reads "1e-5" and rcl "inf" as strings
    return v


def nested_faults(values: dict[str, Any]) -> dict[str, Fault]:
    """The faults given as `faults.<name>.<field>` in `values`: name → Fault, in name order.
    ParamError naming the fault."""
    groups: dict[str, dict[str, Any]] = {}
    for k, v in values.items():
        if is_fault_field(k):
            _, name, key = k.split(".")
            groups.setdefault(name, {})[key] = _fault_field_value(k, key, v)
    out = {}
    for name in sorted(groups):
        try:
            out[name] = fault_from_dict(groups[name])
        except ParamError as e:
            raise ParamError(f"parameter {FAULTS_PREFIX}{name}: {e}") from None
    return out


def _actuator_mapping(text: str, given: frozenset[str]) -> dict:
    """The `actuator` parameter's YAML mapping (a copy, groups as dicts where the nested names need them)."""
    try:
        data = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as e:
        raise ParamError(f"parameter actuator = {text!r}: not a YAML mapping ({str(e).splitlines()[0]})") from None
    data = data if data is not None else {}
    if given and not isinstance(data, dict):
        raise ParamError(f"parameter actuator = {text!r}: expected a mapping of groups "
                         f"({', '.join(ACTUATOR_GROUPS)}, faults)")
    return {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()} if isinstance(data, dict) else data


def _apply_nested(data: dict, values: dict[str, Any], given: frozenset[str]) -> None:
    """The actuator.<group>.<field> names `given` over the mapping (`fitted` adds or, for the motor, removes a group)."""
    for name in sorted(given):
        group, key = name[len(ACTUATOR_PREFIX):].split(".", 1)
        v = values[name]
        if key == "fitted" and group == "motor" and not v:
            data["motor"] = None
            continue
        if not isinstance(data.get(group), dict):
            data[group] = {}
        if key != "fitted":
            data[group][key] = None if isinstance(v, float) and math.isnan(v) else v
    if data.get("motor") is None and any(n.startswith(f"{ACTUATOR_PREFIX}motor.") and not n.endswith(".fitted")
                                         for n in given) and values.get(f"{ACTUATOR_PREFIX}motor.fitted", True):
        data["motor"] = data.get("motor") or {}


def _actuator_from(data: Any, values: dict[str, Any], given: frozenset[str]) -> tuple[ActuatorParams, tuple]:
    """ActuatorParams of the mapping and the faults of the `faults` string; ParamError naming the parameter."""
    try:
        a = actuator_params_from_dict(data)
        return a, a.faults + parse_faults(values["faults"])
    except ParamError as e:
        text_e = str(e)
        if text_e.startswith("fault"):
            raise ParamError(f"parameter faults: {e}") from None
        group = text_e.split(".", 1)[0].removeprefix("unknown parameter ")
        nested = any(n.startswith(f"{ACTUATOR_PREFIX}{group}.") for n in given)
        raise ParamError(f"parameter actuator.{e}" if nested and group in ACTUATOR_GROUPS
                         else f"parameter actuator: {e}") from None


def actuator_config(values: dict[str, Any], params: Params, given: frozenset[str] = frozenset()) -> ActuatorParams:
    """ActuatorParams from the `actuator` (YAML mapping), the actuator.* names `given` and `faults` values (the
    node's parameters, the FMU's build options); a given nested name overrides the same field of the mapping.
    ParamError naming the parameter. Its drive runs in the session's `command_interface` (`Session`)."""
    from dataclasses import replace

    from prsm_sim.actuator.faults import check_fault
    data = _actuator_mapping(values["actuator"], given)
    if given:
        _apply_nested(data, values, given)
    a, faults = _actuator_from(data, values, given)
    named = nested_faults(values)
    for label, f in [("faults", f) for f in faults] + [(FAULTS_PREFIX + n, f) for n, f in named.items()]:
        try:
            check_fault(f, params, values["model"], a.motor is not None)
            bound_fault(f)
        except ParamError as e:
            raise ParamError(f"parameter {label}: {e}") from None
    faults += tuple(named.values())
    # `command_interface` is the session's (`Session` runs the drive in it, whatever drive.mode says)
    return replace(a, faults=faults)
