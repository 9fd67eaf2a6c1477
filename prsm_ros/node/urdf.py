"""A URDF of the simulated actuator as configured, for `robot_description` and `prsm-node --urdf`.

No ROS import: the text is built from the parameters (prsm_sim.Params, ActuatorParams) and the
node's names; the node publishes it on `robot_description` and `prsm-node --urdf` prints it.

Kinematic tree (z along the screw axis, as in the sign convention of docs/node.md):

    base_link ──screw_joint (continuous, axis +z)──▶ screw_link
              └─nut_joint (prismatic, axis −z)─────▶ nut_link

The joints are the node's two `joint_states` joints and carry the same coordinates: screw angle
positive right-handed about +z; nut position x_nut = (L/2π) θ_S, positive where a positive screw
rotation drives the nut, which for right-hand threads is the body's −z (docs/node.md's sign
convention; the Rerun view draws the nut at z = −x_nut). Hence the prismatic axis (0, 0, −1): a
positive `nut_joint` position puts `nut_link` at z = −x_nut, and the URDF, the joint states and
the 3D view agree.

The nut joint's limits are the end stops where fitted (`actuator.stops`), else the thread ends
(±(screw length − nut length)/2 when the geometry has them, else ±half the screw length).
Masses and inertias: the screw a solid steel cylinder of the preset's radius and length at the
preset's density, with the preset's own screw inertia about z (plus, with a motor, the rotor
reflected through its gear, J_rotor N², since the URDF has no gear); the nut link carries what
moves axially with the nut (`moved_mass_kg` and the rollers). Joint limits: the screw's effort
the node's `max_effort` (or the motor's peak torque times its gear when lower), its speed the
drive's or motor's speed limit; the nut's effort the axial force that torque makes, τ/p.

The `<ros2_control>` block declares the topic-based system
(`joint_state_topic_hardware_interface/JointStateTopicSystem`) with the node's topic names and the
active command interface, as docs/actuator.md's ros2_control section describes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from prsm_sim.actuator import ActuatorParams
from prsm_sim.actuator.drive_train import lead_per_rad_m, motor_inertia_at_screw_kgm2
from prsm_sim.params import Params

PLUGIN = "joint_state_topic_hardware_interface/JointStateTopicSystem"


@dataclass(frozen=True)
class Names:
    """The frames and joints of the description (the node's joint names and its wrench frame)."""

    screw_joint: str = "screw_joint"
    nut_joint: str = "nut_joint"
    base_link: str = "base_link"
    screw_link: str = "screw_link"
    nut_link: str = "nut_link"


def nut_limits_m(params: Params, actuator: ActuatorParams | None) -> tuple[float, float]:
    """(lower, upper) nut position: the stops where fitted, else the thread ends."""
    geo = params.geometry
    travel = getattr(geo, "travel_m", geo.screw_length_m)  # None: the geometry has no thread ends
    half = 0.5 * (travel if travel is not None else geo.screw_length_m)
    lo, hi = -half, half
    stops = actuator.stops if actuator is not None else None
    if stops is not None and stops.fitted:
        lo = stops.min_position_m if stops.min_position_m is not None else lo
        hi = stops.max_position_m if stops.max_position_m is not None else hi
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


def _inertial(mass: float, ixx: float, izz: float, indent: str) -> list[str]:
    return [f"{indent}<inertial>", f'{indent}  <origin xyz="0 0 0" rpy="0 0 0"/>',
            f'{indent}  <mass value="{_f(mass)}"/>',
            f'{indent}  <inertia ixx="{_f(ixx)}" ixy="0" ixz="0" iyy="{_f(ixx)}" iyz="0" izz="{_f(izz)}"/>',
            f"{indent}</inertial>"]


def _cylinder(radius: float, length: float, indent: str) -> list[str]:
    return [f"{indent}<visual>", f'{indent}  <geometry><cylinder radius="{_f(radius)}" length="{_f(length)}"/></geometry>',
            f"{indent}</visual>"]


def actuator_urdf(params: Params, actuator: ActuatorParams | None = None, *, robot_name: str = "prsm_actuator",
                  names: Names = Names(), interface: str = "effort", max_effort_nm: float = 50.0,
                  joint_commands_topic: str = "/prsm_actuator/joint_commands",
                  joint_states_topic: str = "/joint_states") -> str:
    """The URDF text (see the module doc)."""
    geo, mass = params.geometry, params.mass
    p = lead_per_rad_m(params)
    r_s, l_s = geo.screw_radius_m, geo.screw_length_m
    screw_mass = mass.density_kg_m3 * math.pi * r_s ** 2 * l_s
    screw_izz = mass.screw_inertia_kgm2 + motor_inertia_at_screw_kgm2(actuator)
    screw_ixx = screw_mass * (3 * r_s ** 2 + l_s ** 2) / 12
    nut_mass = mass.moved_mass_kg + geo.n_rollers * mass.roller_mass_kg
    r_n = geo.nut_radius_m
    l_n = getattr(geo, "nut_length_m", None) or geo.n_teeth * geo.pitch_m
    lo, hi = nut_limits_m(params, actuator)
    effort_nm, speed_rad_s = screw_limits(actuator, max_effort_nm)
    speed_txt = _f(speed_rad_s) if math.isfinite(speed_rad_s) else "1e9"
    nut_speed_txt = _f(speed_rad_s * p) if math.isfinite(speed_rad_s) else "1e9"
    q = quoteattr
    lines = ['<?xml version="1.0"?>',
             f"<!-- {robot_name}: planetary roller screw actuator as simulated by prsm-node ({params.name}); "
             "nut_joint axis -z: x_nut is positive where a positive screw rotation drives the nut -->",
             f"<robot name={q(robot_name)}>",
             f"  <link name={q(names.base_link)}/>",
             f"  <link name={q(names.screw_link)}>", *_inertial(screw_mass, screw_ixx, screw_izz, "    "),
             *_cylinder(r_s, l_s, "    "), "  </link>",
             f"  <link name={q(names.nut_link)}>",
             *_inertial(nut_mass, nut_mass * (3 * r_n ** 2 + l_n ** 2) / 12, nut_mass * r_n ** 2, "    "),
             *_cylinder(r_n, l_n, "    "), "  </link>",
             f'  <joint name={q(names.screw_joint)} type="continuous">',
             f"    <parent link={q(names.base_link)}/>", f"    <child link={q(names.screw_link)}/>",
             '    <origin xyz="0 0 0" rpy="0 0 0"/>', '    <axis xyz="0 0 1"/>',
             f'    <limit effort="{_f(effort_nm)}" velocity="{speed_txt}"/>', "  </joint>",
             f'  <joint name={q(names.nut_joint)} type="prismatic">',
             f"    <parent link={q(names.base_link)}/>", f"    <child link={q(names.nut_link)}/>",
             '    <origin xyz="0 0 0" rpy="0 0 0"/>', '    <axis xyz="0 0 -1"/>',
             f'    <limit lower="{_f(lo)}" upper="{_f(hi)}" effort="{_f(effort_nm / p)}" velocity="{nut_speed_txt}"/>',
             "  </joint>"]
    lines += _ros2_control(robot_name, names, interface, effort_nm, speed_rad_s, lo, hi, joint_commands_topic,
                           joint_states_topic)
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def _ros2_control(robot_name: str, names: Names, interface: str, effort_nm: float, speed_rad_s: float,
                  lo: float, hi: float, commands: str, states: str) -> list[str]:
    q = quoteattr

    def command(name: str, low: float, high: float) -> list[str]:
        out = [f'      <command_interface name="{name}">']
        if math.isfinite(low) and math.isfinite(high):
            out += [f'        <param name="min">{_f(low)}</param>', f'        <param name="max">{_f(high)}</param>']
        return out + ["      </command_interface>"]
    state = ['      <state_interface name="position"/>', '      <state_interface name="velocity"/>',
             '      <state_interface name="effort"/>']
    screw_cmd = (command("effort", -effort_nm, effort_nm) if interface == "effort" else
                 command("velocity", -speed_rad_s, speed_rad_s) if interface == "velocity" else [])
    nut_cmd = command("position", lo, hi) if interface == "position" else []
    return [f"  <ros2_control name={q(robot_name)} type=\"system\">", "    <hardware>",
            f"      <plugin>{PLUGIN}</plugin>",
            f'      <param name="joint_commands_topic">{commands}</param>',
            f'      <param name="joint_states_topic">{states}</param>', "    </hardware>",
            f"    <joint name={q(names.screw_joint)}>", *screw_cmd, *state, "    </joint>",
            f"    <joint name={q(names.nut_joint)}>", *nut_cmd, *state, "    </joint>",
            "  </ros2_control>"]


def urdf_for_node(cfg, node_name: str, namespace: str = "/") -> str:
    """The URDF of a node's configuration (`prsm_ros.node.parameters.NodeConfig`) with its topic names."""
    from prsm_ros.interface import TOPIC_DEFS, resolve_name

    def topic(key: str) -> str:
        return resolve_name(cfg.topics.get(key, TOPIC_DEFS[key].name), node_name, namespace)
    v = cfg.values
    names = Names(screw_joint=v["joints.screw"], nut_joint=v["joints.nut"], base_link=v["frames.base"],
                  screw_link=v["frames.screw"], nut_link=v["frames.nut"])
    return actuator_urdf(cfg.params, cfg.actuator if cfg.with_actuator else None, robot_name=node_name, names=names,
                         interface=cfg.command_interface, max_effort_nm=cfg.max_effort,
                         joint_commands_topic=topic("joint_commands"), joint_states_topic=topic("joint_states"))
