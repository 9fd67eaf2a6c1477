"""The node's parameters declared on an rclpy node: descriptors, rclpy's refusals in our words, typos refused.

What the parameters are, their defaults, units, ranges and checks is `parameters` (no ROS); this
module only tells rclpy about them and reads back what the command line and files gave.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from prsm_ros.node.parameters import (ACTUATOR_PREFIX, FAULT_FIELDS, FAULTS_PREFIX, PHYSICS_PREFIX, RCLPY_PARAMETERS,
                                      ConfigError, NodeConfig, NodeParam, ParamSources, base_params, check_preset, check_value,
                                      fault_field_names, is_fault_field, nearest_hint, node_parameters,
                                      physics_parameters, physics_type, physics_unit, unknown_parameter)


def declare_parameters(node: Node) -> NodeConfig:
    """Declare every node parameter and the preset's physics.* parameters; the validated configuration."""
    values: dict[str, Any] = {}
    for p in node_parameters():
        values[p.name] = _declare(node, p.name, p.default, descriptor(p), p)
        if p.name == "preset":
            check_preset(values["preset"])
    base = base_params(values)  # the params_file, else the preset (ConfigError naming the parameter)
    origin = f"parameter file {values['params_file']}" if values["params_file"] else f"preset {base.name}"
    for key, default in physics_parameters(base).items():
        unit = physics_unit(key)
        desc = ParameterDescriptor(
            description=f"physical parameter {key[len(PHYSICS_PREFIX):]}"
                        + (f" [{unit}]" if unit else "") + f"; default from {origin}",
            additional_constraints=f"{physics_type(base, key).__name__}; validated by prsm_sim.Params",
            dynamic_typing=True)
        values[key] = _declare(node, key, default, desc)
    values.update(_declare_faults(node))
    # the actuator.* names given at start-up apply (they override the `actuator` mapping)
    given = {k for k in _overrides(node) if k.startswith(ACTUATOR_PREFIX) and k in values}
    return NodeConfig.from_values(values, given, base=base)


def _declare_faults(node: Node) -> dict[str, Any]:
    """Declare the `faults.<name>.<field>` names given at start-up (rclpy knows no names ahead of time).

    A fault with a name that is not one of its fields takes no part: that name is refused by
    check_unknown_overrides with the nearest valid one, before the fault's other fields are judged."""
    given = [k for k in _overrides(node) if k.startswith(FAULTS_PREFIX)]
    broken = {k.split(".")[1] for k in given if not is_fault_field(k)}
    out = {}
    for k in sorted(filter(is_fault_field, given)):
        desc = ParameterDescriptor(description=f"fault {k.split('.')[1]}: {k.split('.')[2]} (prsm_sim.actuator.Fault)",
                                   read_only=True, dynamic_typing=True)
        value = node.declare_parameter(k, _overrides(node)[k].value, desc).value
        if k.split(".")[1] not in broken:
            out[k] = value
    return out


def _overrides(node: Node) -> dict:
    """The parameter values given on the command line or in files (rclpy keeps them here; no getter)."""
    return getattr(node, "_parameter_overrides", {})


def _declare(node: Node, name: str, default: Any, desc: ParameterDescriptor, spec: NodeParam | None = None) -> Any:
    """Declare one parameter; rclpy's type or range refusal is re-worded by our own check when we can."""
    try:
        return node.declare_parameter(name, default, desc).value
    except ParameterException as e:
        overrides = _overrides(node)
        given = overrides.get(name)
        if spec is not None and given is not None:
            value = check_value(spec, given.value)  # raises ConfigError in the words of `parameters`
            if isinstance(given.value, str) and isinstance(value, float):
                # a float spelled as YAML 1.1 reads it ("1e-5" is a string there): declare the number
                del overrides[name]
                return node.declare_parameter(name, value, desc).value
        raise ConfigError(f"parameter {name}: {e}") from None


def check_unknown_overrides(node: Node, sources: ParamSources | None) -> None:
    """A name given to this node (`-p`, its own section of a params file) that it does not have is
    refused (ConfigError naming the nearest valid one); one from a wildcard section is only warned
    about (multi-node files are normal); rclpy's own parameters pass. `sources` None: every name
    given is this node's (a node built in-process with parameter_overrides)."""
    known = sorted(node.list_parameters([], 0).names)
    known += sorted({n for k in _overrides(node) for n in fault_field_names(k)} - set(known))
    for k in sorted(n for n in _overrides(node) if not node.has_parameter(n)):
        if k in RCLPY_PARAMETERS:
            continue
        where = None if sources is None else sources.own.get(k)
        if sources is None or where is not None:
            raise ConfigError(unknown_parameter(k, where or "given to this node", known))
        hint = nearest_hint(k, known)
        node.get_logger().warning(f"parameter {k} ({sources.wildcard.get(k, 'a parameter file')}) is not a parameter "
                                  "of this node; ignored" + (hint if "did you mean" in hint else ""))


def descriptor(p: NodeParam) -> ParameterDescriptor:
    """rclpy's descriptor of a node parameter: description with its unit, allowed values, range."""
    unit = f" [{p.unit}]" if p.unit and p.unit != "1" else ""
    d = ParameterDescriptor(description=p.description + unit, additional_constraints=p.allowed, read_only=p.read_only)
    if isinstance(p.default, float):
        d.dynamic_typing = True  # accept integers for doubles; `parameters` checks the type
        if p.lo is not None and p.hi is not None:
            d.floating_point_range = [FloatingPointRange(from_value=float(p.lo), to_value=float(p.hi))]
    elif isinstance(p.default, int) and not isinstance(p.default, bool) and p.lo is not None and p.hi is not None:
        d.integer_range = [IntegerRange(from_value=int(p.lo), to_value=int(p.hi), step=1)]
    return d


def usage() -> str:
    """`prsm-node --help`: the command line and every parameter with its default, unit and allowed values."""
    lines = ["prsm-node: the simulated PRSM actuator (planetary roller screw) on the ROS 2 graph.", "",
             "usage: prsm-node [--help] [--version] [--params-template [PRESET]] [--urdf] [--ros-args ...]", "",
             "  --urdf: print the URDF of the actuator as the parameters configure it, and exit",
             "", "parameters (-p name:=value, or a ros__parameters YAML via --params-file):"]
    for p in node_parameters():
        unit = f" [{p.unit}]" if p.unit and p.unit != "1" else ""
        lines.append(f"  {p.name} = {p.default!r}{unit}: {p.description}; {p.allowed}"
                     + (" (read-only)" if p.read_only else ""))
    lines.append(f"  {FAULTS_PREFIX}<name>.<field>: a fault injected from the start, one group per fault under a "
                 "name of your choice; fields " + ", ".join(FAULT_FIELDS) + " as in the faults string "
                 "(read-only; they add to it)")
    lines.append("  physics.<group>.<name>: any prsm_sim parameter, default from the preset "
                 "(see prsm-node --params-template)")
    return "\n".join(lines)
