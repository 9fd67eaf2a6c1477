"""The node's parameters declared on an rclpy node: descriptors, rclpy's refusals in our words, typos refused.

What the parameters are, their defaults, units, ranges and checks is `parameters` (no ROS); this
module only tells rclpy about them and reads back what the command line and files gave.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node

from prsm_ros.node.parameters import (PHYSICS_PREFIX, ConfigError, NodeConfig, NodeParam, check_preset, check_value,
                                      node_parameters, physics_parameters, physics_type, physics_unit)


def declare_parameters(node: Node) -> NodeConfig:
    """Declare every node parameter and the preset's physics.* parameters; the validated configuration."""
    values: dict[str, Any] = {}
    for p in node_parameters():
        values[p.name] = _declare(node, p.name, p.default, descriptor(p), p)
        if p.name == "preset":
            base = check_preset(values["preset"])
    for key, default in physics_parameters(base).items():
        unit = physics_unit(key)
        desc = ParameterDescriptor(
            description=f"physical parameter {key[len(PHYSICS_PREFIX):]}"
                        + (f" [{unit}]" if unit else "") + f"; default from preset {base.name}",
            additional_constraints=f"{physics_type(base, key).__name__}; validated by prsm_sim.Params",
            dynamic_typing=True)
        values[key] = _declare(node, key, default, desc)
    return NodeConfig.from_values(values)


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


def check_unknown_overrides(node: Node, config: NodeConfig) -> None:
    """A physics.* key in the parameter file that was not declared is a typo: refused; other unknown keys are logged."""
    for k in sorted(k for k in _overrides(node) if not node.has_parameter(k)):
        if k.startswith(PHYSICS_PREFIX):
            group = k[len(PHYSICS_PREFIX):].split(".")[0]
            allowed = [n for n in physics_parameters(config.params) if n.startswith(f"{PHYSICS_PREFIX}{group}.")]
            raise ConfigError(f"unknown parameter {k}; allowed: "
                              + (", ".join(allowed) if allowed else
                                 "physics.<group>.<name> with group geometry, mass, friction, ideal or loads"))
        node.get_logger().warning(f"parameter {k} is not a parameter of this node; ignored")


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
             "usage: prsm-node [--help] [--params-template [PRESET]] [--ros-args ...]",
             "", "parameters (-p name:=value, or a ros__parameters YAML via --params-file):"]
    for p in node_parameters():
        unit = f" [{p.unit}]" if p.unit and p.unit != "1" else ""
        lines.append(f"  {p.name} = {p.default!r}{unit}: {p.description}; {p.allowed}"
                     + (" (read-only)" if p.read_only else ""))
    lines.append("  physics.<group>.<name>: any prsm_sim parameter, default from the preset "
                 "(see prsm-node --params-template)")
    return "\n".join(lines)
