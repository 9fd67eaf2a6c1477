"""The actuator's description: the xacro macro `prsm_actuator` (package data) and the URDF of a node as
configured (`robot_description`, `prsm-node --urdf`), both from one body so they cannot drift apart.

No ROS import: the text is built from the parameters (prsm_sim.Params, ActuatorParams) and the
node's names. `prsm_ros/description/prsm_actuator.urdf.xacro` is `actuator_xacro()` written out
(`python -m prsm_ros.node.urdf > prsm_ros/description/prsm_actuator.urdf.xacro`; a test checks
the shipped file is current); the node's URDF is the same body with the node's values in place of
the macro's parameters, under a root link, which is what xacro expands
`<xacro:prsm_actuator prefix="" parent="base_link"/>` to for the s30 preset's defaults.

Kinematic tree (z along the screw axis, as in the sign convention of docs/node.md):

    parent ──${prefix}screw_joint (continuous, axis +z)──▶ ${prefix}screw_link
           └─${prefix}nut_joint (prismatic, axis −z)─────▶ ${prefix}nut_link

The parent is the housing (`base_link` for the node's own URDF); `xyz`/`rpy` place the screw axis
on it. The joints are the node's two `joint_states` joints and carry the same coordinates: screw
angle positive right-handed about +z; nut position x_nut = (L/2π) θ_S, positive where a positive
screw rotation drives the nut, which for right-hand threads is the body's −z (docs/node.md's sign
convention; the Rerun view draws the nut at z = −x_nut). Hence the prismatic axis (0, 0, −1): a
positive `nut_joint` position puts `nut_link` at z = −x_nut, and the URDF, the joint states and
the 3D view agree.

The nut joint's limits are the thread ends, ±(screw length − nut length)/2 (±half the screw
length when the geometry has none), narrowed by the end stops where fitted: a stop beyond a thread
end changes nothing, the threads end first. Masses and inertias: the screw a solid steel cylinder
of the preset's radius and length at the preset's density, with the preset's own screw inertia
about z (plus, with a motor, the rotor reflected through its gear, J_rotor N², since the URDF has
no gear); the nut link carries what moves axially with the nut (`moved_mass_kg` and the rollers).
Joint limits: the screw's effort the node's `max_effort` (or the motor's peak torque times its
gear when lower), its speed the drive's or motor's speed limit (1e9 rad/s when none); the nut's
effort the axial force that torque makes, τ/p.

One `<ros2_control>` block per actuator declares the topic-based system
(`joint_state_topic_hardware_interface/JointStateTopicSystem`) on the node's topics with every
command interface the node accepts, each bounded by its limits: effort and velocity on the screw
joint, position on the nut joint (`prsm_ros.node.joint_commands`: the node's position command
is the nut's); position, velocity and effort state interfaces on both. The node runs one of them
at a time (`command_interface`, `~/set_command_interface`); a controller switch needs no new URDF.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

from prsm_sim.actuator import ActuatorParams
from prsm_sim.actuator.drive_train import lead_per_rad_m, motor_inertia_at_screw_kgm2
from prsm_sim.params import Params

PLUGIN = "joint_state_topic_hardware_interface/JointStateTopicSystem"
MACRO = "prsm_actuator"
XACRO_PATH = Path(__file__).resolve().parents[1] / "description" / "prsm_actuator.urdf.xacro"
XACRO_PRESET = "s30"  # the macro's defaults: this preset, the bare model, the node's default max_effort
UNLIMITED = 1e9  # a speed limit where the configuration has none (URDF needs a number)
# The macro's parameters besides prefix and parent, in order, with their unit and meaning.
MACRO_PARAMS = {
    "xyz": ("m", "screw axis origin on the parent"), "rpy": ("rad", "its orientation"),
    "screw_radius": ("m", "screw radius"), "screw_length": ("m", "screw length"),
    "screw_mass": ("kg", "screw mass"), "screw_ixx": ("kg m^2", "screw inertia about x and y"),
    "screw_izz": ("kg m^2", "screw inertia about z, with the rotor through its gear"),
    "nut_radius": ("m", "nut radius"), "nut_length": ("m", "nut length"),
    "nut_mass": ("kg", "what moves axially with the nut"), "nut_ixx": ("kg m^2", "its inertia about x and y"),
    "nut_izz": ("kg m^2", "about z"), "screw_effort": ("N m", "screw torque limit"),
    "screw_velocity": ("rad/s", "screw speed limit"), "nut_lower": ("m", "nut position, lower thread end or stop"),
    "nut_upper": ("m", "upper"), "nut_effort": ("N", "axial force of screw_effort"),
    "nut_velocity": ("m/s", "nut speed of screw_velocity"),
    "joint_commands_topic": ("", "the node's ~/joint_commands"), "joint_states_topic": ("", "the node's joint_states"),
}


@dataclass(frozen=True)
class Names:
    """The frames and joints of the description (the node's joint names and its wrench frame)."""

    screw_joint: str = "screw_joint"
    nut_joint: str = "nut_joint"
    base_link: str = "base_link"
    screw_link: str = "screw_link"
    nut_link: str = "nut_link"


def nut_limits_m(params: Params, actuator: ActuatorParams | None) -> tuple[float, float]:
    """(lower, upper) nut position: the thread ends, narrowed by the stops where fitted."""
    geo = params.geometry
    travel = geo.travel_m  # None: the geometry has no thread ends
    half = 0.5 * (travel if travel is not None else geo.screw_length_m)
    lo, hi = -half, half
    stops = actuator.stops if actuator is not None else None
    if stops is not None and stops.fitted:  # a stop beyond a thread end: the threads end first
        lo = min(max(lo, stops.min_position_m), half) if stops.min_position_m is not None else lo
        hi = max(min(hi, stops.max_position_m), -half) if stops.max_position_m is not None else hi
    return lo, hi


def screw_limits(actuator: ActuatorParams | None, max_effort_nm: float) -> tuple[float, float]:
    """(effort N·m, speed rad/s) at the screw."""
    effort = max_effort_nm
    speed = math.inf
    if actuator is not None:
        speed = actuator.drive.speed_limit_rad_s
        m = actuator.motor
        if m is not None:
            effort = min(effort, m.peak_torque_nm * m.gear_ratio)
            speed = min(speed, m.speed_limit_rad_s / m.gear_ratio)
    return effort, speed


def _f(x: float) -> str:
    return repr(float(x))


def description_values(params: Params, actuator: ActuatorParams | None = None, *, max_effort_nm: float = 50.0,
                       joint_commands_topic: str = "/prsm_actuator/joint_commands",
                       joint_states_topic: str = "/joint_states") -> dict[str, str]:
    """The value of every macro parameter (`MACRO_PARAMS`) for this configuration, as URDF text."""
    geo, mass = params.geometry, params.mass
    p = lead_per_rad_m(params)
    r_s, l_s = geo.screw_radius_m, geo.screw_length_m
    screw_mass = mass.density_kg_m3 * math.pi * r_s ** 2 * l_s
    nut_mass = mass.moved_mass_kg + geo.n_rollers * mass.roller_mass_kg
    r_n = geo.nut_radius_m
    l_n = getattr(geo, "nut_length_m", None) or geo.n_teeth * geo.pitch_m
    lo, hi = nut_limits_m(params, actuator)
    effort_nm, speed_rad_s = screw_limits(actuator, max_effort_nm)
    speed_rad_s = speed_rad_s if math.isfinite(speed_rad_s) else UNLIMITED
    nut_speed = speed_rad_s * p if speed_rad_s < UNLIMITED else UNLIMITED
    numbers = {"screw_radius": r_s, "screw_length": l_s, "screw_mass": screw_mass,
               "screw_ixx": screw_mass * (3 * r_s ** 2 + l_s ** 2) / 12,
               "screw_izz": mass.screw_inertia_kgm2 + motor_inertia_at_screw_kgm2(actuator),
               "nut_radius": r_n, "nut_length": l_n, "nut_mass": nut_mass,
               "nut_ixx": nut_mass * (3 * r_n ** 2 + l_n ** 2) / 12, "nut_izz": nut_mass * r_n ** 2,
               "screw_effort": effort_nm, "screw_velocity": speed_rad_s, "nut_lower": lo, "nut_upper": hi,
               "nut_effort": effort_nm / p, "nut_velocity": nut_speed}
    out = {"xyz": "0 0 0", "rpy": "0 0 0", **{k: _f(v) for k, v in numbers.items()},
           "joint_commands_topic": joint_commands_topic, "joint_states_topic": joint_states_topic}
    return out


def _inertial(v: dict[str, str], part: str, indent: str) -> list[str]:
    ixx, izz = v[f"{part}_ixx"], v[f"{part}_izz"]
    return [f"{indent}<inertial>", f'{indent}  <origin xyz="0 0 0" rpy="0 0 0"/>',
            f'{indent}  <mass value="{v[part + "_mass"]}"/>',
            f'{indent}  <inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{ixx}" iyz="0" izz="{izz}"/>', f"{indent}</inertial>"]


def _cylinder(v: dict[str, str], part: str, indent: str) -> list[str]:
    return [f"{indent}<visual>",
            f'{indent}  <geometry><cylinder radius="{v[part + "_radius"]}" length="{v[part + "_length"]}"/></geometry>',
            f"{indent}</visual>"]


def _body(v: dict[str, str], neg, names: dict[str, str], indent: str) -> list[str]:
    """Links, joints and the ros2_control block: `v` the macro parameters' text, `neg(key)` the text of
    minus that parameter, `names` the links', joints' and system's names."""
    q, i = quoteattr, indent
    lines = [f"{i}<link name={q(names['screw_link'])}>", *_inertial(v, "screw", i + "  "),
             *_cylinder(v, "screw", i + "  "), f"{i}</link>",
             f"{i}<link name={q(names['nut_link'])}>", *_inertial(v, "nut", i + "  "),
             *_cylinder(v, "nut", i + "  "), f"{i}</link>"]
    for joint, kind, child, axis, limit in (
            ("screw_joint", "continuous", "screw_link", "0 0 1",
             f'effort="{v["screw_effort"]}" velocity="{v["screw_velocity"]}"'),
            ("nut_joint", "prismatic", "nut_link", "0 0 -1",
             f'lower="{v["nut_lower"]}" upper="{v["nut_upper"]}" effort="{v["nut_effort"]}" '
             f'velocity="{v["nut_velocity"]}"')):
        lines += [f"{i}<joint name={q(names[joint])} type=\"{kind}\">",
                  f"{i}  <parent link={q(names['base_link'])}/>", f"{i}  <child link={q(names[child])}/>",
                  f'{i}  <origin xyz="{v["xyz"]}" rpy="{v["rpy"]}"/>', f'{i}  <axis xyz="{axis}"/>',
                  f"{i}  <limit {limit}/>", f"{i}</joint>"]

    def command(name: str, low: str, high: str) -> list[str]:
        return [f'{i}    <command_interface name="{name}">', f'{i}      <param name="min">{low}</param>',
                f'{i}      <param name="max">{high}</param>', f"{i}    </command_interface>"]
    state = [f'{i}    <state_interface name="{s}"/>' for s in ("position", "velocity", "effort")]
    return lines + [
        f"{i}<ros2_control name={q(names['system'])} type=\"system\">", f"{i}  <hardware>",
        f"{i}    <plugin>{PLUGIN}</plugin>",
        f'{i}    <param name="joint_commands_topic">{v["joint_commands_topic"]}</param>',
        f'{i}    <param name="joint_states_topic">{v["joint_states_topic"]}</param>', f"{i}  </hardware>",
        f"{i}  <joint name={q(names['screw_joint'])}>",
        *command("effort", neg("screw_effort"), v["screw_effort"]),
        *command("velocity", neg("screw_velocity"), v["screw_velocity"]), *state, f"{i}  </joint>",
        f"{i}  <joint name={q(names['nut_joint'])}>",
        *command("position", v["nut_lower"], v["nut_upper"]), *state, f"{i}  </joint>",
        f"{i}</ros2_control>"]


def actuator_urdf(params: Params, actuator: ActuatorParams | None = None, *, robot_name: str = "prsm_actuator",
                  names: Names = Names(), max_effort_nm: float = 50.0,
                  joint_commands_topic: str = "/prsm_actuator/joint_commands",
                  joint_states_topic: str = "/joint_states") -> str:
    """The URDF text (see the module doc): the root link `names.base_link` and the macro's body on it."""
    v = description_values(params, actuator, max_effort_nm=max_effort_nm, joint_commands_topic=joint_commands_topic,
                           joint_states_topic=joint_states_topic)
    named = {**vars(names), "system": robot_name}
    lines = ['<?xml version="1.0"?>',
             f"<!-- {robot_name}: planetary roller screw actuator as simulated by prsm-node ({params.name}); "
             "nut_joint axis -z: x_nut is positive where a positive screw rotation drives the nut -->",
             f"<robot name={quoteattr(robot_name)}>", f"  <link name={quoteattr(names.base_link)}/>",
             *_body(v, lambda k: _f(-float(v[k])), named, "  "), "</robot>"]
    return "\n".join(lines) + "\n"


def actuator_xacro() -> str:
    """The xacro macro `prsm_actuator` (prefix, parent; every other parameter defaulted from `XACRO_PRESET`)."""
    from prsm_sim import preset
    defaults = description_values(preset(XACRO_PRESET))
    params = " ".join(["prefix", "parent"] + [f"{k}:='{d}'" if " " in d else f"{k}:={d}" for k, d in defaults.items()])
    v = {k: "${" + k + "}" for k in MACRO_PARAMS}
    names = {k: "${prefix}" + k for k in ("screw_joint", "nut_joint", "screw_link", "nut_link")}
    names.update(base_link="${parent}", system="${prefix}" + MACRO)
    doc = [f"       {k}: {what}" + (f" ({unit})" if unit else "") for k, (unit, what) in MACRO_PARAMS.items()]
    lines = ['<?xml version="1.0"?>',
             "<!-- prsm_actuator: a planetary roller screw actuator as prsm-node simulates it, for a robot's URDF.",
             '     <xacro:include filename="prsm_actuator.urdf.xacro"/>',
             '     <xacro:prsm_actuator prefix="left_" parent="base_link"/>',
             "     adds ${prefix}screw_joint (continuous, +z) and ${prefix}nut_joint (prismatic, -z: x_nut > 0 is -z",
             "     for right-hand threads), their links, and a <ros2_control> system on the node's topics with every",
             "     command interface the node accepts. Parameters (defaults: the "
             f"{XACRO_PRESET} preset, the bare model, max_effort 50 N m):",
             *doc,
             "     Generated by `python -m prsm_ros.node.urdf`; the node's robot_description (and its URDF",
             "     option) is the same body for the node's own configuration. -->",
             '<robot xmlns:xacro="http://www.ros.org/wiki/xacro">',
             f'  <xacro:macro name="{MACRO}" params="{params}">',
             *_body(v, lambda k: "${-" + k + "}", names, "    "), "  </xacro:macro>", "</robot>"]
    return "\n".join(lines) + "\n"


def urdf_for_node(cfg, node_name: str, namespace: str = "/") -> str:
    """The URDF of a node's configuration (`prsm_ros.node.parameters.NodeConfig`) with its topic names."""
    from prsm_ros.interface import TOPIC_DEFS, resolve_name

    def topic(key: str) -> str:
        return resolve_name(cfg.topics.get(key, TOPIC_DEFS[key].name), node_name, namespace)
    v = cfg.values
    names = Names(screw_joint=v["joints.screw"], nut_joint=v["joints.nut"], base_link=v["frames.base"],
                  screw_link=v["frames.screw"], nut_link=v["frames.nut"])
    return actuator_urdf(cfg.params, cfg.actuator if cfg.with_actuator else None, robot_name=node_name, names=names,
                         max_effort_nm=cfg.max_effort, joint_commands_topic=topic("joint_commands"),
                         joint_states_topic=topic("joint_states"))


if __name__ == "__main__":
    sys.stdout.write(actuator_xacro())
