"""The xacro macro `prsm_actuator` (package data), its ros2_control blocks and the example controllers file.

Oracles: `xacro` from PyPI expands the shipped file with no ROS installation (no `$(find …)`);
yourdfpy, an independent URDF parser, reads the expansion; the node's own description
(`prsm-node --urdf`) for the same configuration; the thread ends of the s30 preset,
±(screw length − nut length)/2 = ±(0.3 − 0.03)/2 = ±0.135 m; the command interfaces the node
decodes (`prsm_ros.node.joint_commands.INTERFACE_JOINT`).
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from importlib.resources import files

import pytest
import yaml
import yourdfpy

from prsm_sim import preset
from prsm_sim.actuator import ActuatorParams, StopParams

from prsm_ros.node.joint_commands import INTERFACE_JOINT
from prsm_ros.node.urdf import actuator_urdf, actuator_xacro

xacro = pytest.importorskip("xacro")

MACRO_FILE = files("prsm_ros.description") / "prsm_actuator.urdf.xacro"
STATE = ["position", "velocity", "effort"]


def expand(tmp_path, body: str, name: str = "robot") -> str:
    src = tmp_path / f"{name}.urdf.xacro"
    src.write_text(f'<?xml version="1.0"?>\n<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="{name}">\n'
                   f'  <xacro:include filename="{MACRO_FILE}"/>\n{body}\n</robot>\n')
    return xacro.process_file(str(src)).toprettyxml(indent="  ")


def systems(text: str) -> dict[str, dict[str, tuple[dict[str, tuple[float, float]], list[str]]]]:
    """ros2_control name → joint → ({command interface: (min, max)}, [state interfaces])."""
    out = {}
    for rc in ET.fromstring(text).iter("ros2_control"):
        joints = {}
        for j in rc.iter("joint"):
            cmds = {c.get("name"): tuple(float(p.text) for p in c.iter("param")) for c in j.iter("command_interface")}
            joints[j.get("name")] = (cmds, [s.get("name") for s in j.iter("state_interface")])
        out[rc.get("name")] = joints
    return out


def test_shipped_macro_is_the_generated_one():
    assert MACRO_FILE.read_text() == actuator_xacro()  # regenerate: python -m prsm_ros.node.urdf > FILE


def test_two_actuators_expand_parse_and_declare_every_interface(tmp_path):
    text = expand(tmp_path, '  <link name="base_link"/>\n'
                  '  <xacro:prsm_actuator prefix="left_" parent="base_link" xyz="0 0.1 0"/>\n'
                  '  <xacro:prsm_actuator prefix="right_" parent="base_link" xyz="0 -0.1 0"\n'
                  '      joint_commands_topic="/right/prsm_actuator/joint_commands"/>')
    u = yourdfpy.URDF.load(io.BytesIO(text.encode()), load_meshes=False)
    assert set(u.joint_names) == {"left_screw_joint", "left_nut_joint", "right_screw_joint", "right_nut_joint"}
    for side, y in (("left_", 0.1), ("right_", -0.1)):
        screw, nut = u.joint_map[f"{side}screw_joint"], u.joint_map[f"{side}nut_joint"]
        assert screw.type == "continuous" and list(screw.axis) == [0, 0, 1] and screw.parent == "base_link"
        assert nut.type == "prismatic" and list(nut.axis) == [0, 0, -1] and nut.parent == "base_link"
        assert screw.origin[1, 3] == pytest.approx(y)
        assert (nut.limit.lower, nut.limit.upper) == (pytest.approx(-0.135), pytest.approx(0.135))  # thread ends
    sys_ = systems(text)
    assert set(sys_) == {"left_prsm_actuator", "right_prsm_actuator"}
    for side in ("left_", "right_"):
        joints = sys_[f"{side}prsm_actuator"]
        for interface, joint in INTERFACE_JOINT.items():  # every command the node accepts, on its joint
            assert interface in joints[f"{side}{joint}"][0]
        assert joints[f"{side}screw_joint"][0]["effort"] == (-50.0, 50.0)  # the node's default max_effort
        assert joints[f"{side}nut_joint"][0]["position"] == (pytest.approx(-0.135), pytest.approx(0.135))
        assert all(states == STATE for _, states in joints.values())
    topics = [p.text for p in ET.fromstring(text).iter("param") if p.get("name") == "joint_commands_topic"]
    assert topics == ["/prsm_actuator/joint_commands", "/right/prsm_actuator/joint_commands"]


def _canonical(text: str) -> list:
    """Every element as (tag, attributes with numbers as floats, text), in document order."""
    def value(v: str):
        try:
            return float(v)
        except ValueError:
            return v
    return [(e.tag, {k: value(v) for k, v in e.attrib.items()}, value((e.text or "").strip()))
            for e in ET.fromstring(text).iter()]


def test_prsm_node_urdf_is_the_macro_expanded(tmp_path):
    text = expand(tmp_path, '  <link name="base_link"/>\n  <xacro:prsm_actuator prefix="" parent="base_link"/>',
                  name="prsm_actuator")
    env = {**os.environ, "RERUN": "off"}
    r = subprocess.run([sys.executable, "-m", "prsm_ros.cli.node", "--urdf"], capture_output=True, text=True,
                       env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert _canonical(r.stdout) == _canonical(text)


def test_stops_beyond_the_thread_ends_leave_the_thread_ends():
    act = ActuatorParams(stops=StopParams(min_position_m=-0.3, max_position_m=0.1))
    u = yourdfpy.URDF.load(io.BytesIO(actuator_urdf(preset("s30"), act).encode()), load_meshes=False)
    nut = u.joint_map["nut_joint"]
    assert (nut.limit.lower, nut.limit.upper) == (pytest.approx(-0.135), 0.1)


def test_controllers_file_names_declared_interfaces(tmp_path):
    cfg = yaml.safe_load((files("prsm_ros.description") / "controllers.yaml").read_text())
    declared = systems(expand(tmp_path, '  <link name="base_link"/>\n'
                              '  <xacro:prsm_actuator prefix="" parent="base_link"/>'))["prsm_actuator"]
    manager = cfg["controller_manager"]["ros__parameters"]
    commanded = [name for name, c in manager.items() if isinstance(c, dict)
                 and c["type"] == "forward_command_controller/ForwardCommandController"]
    assert sorted(cfg[name]["ros__parameters"]["interface_name"] for name in commanded) == sorted(INTERFACE_JOINT)
    for name in commanded:
        p = cfg[name]["ros__parameters"]
        for joint in p["joints"]:
            assert p["interface_name"] in declared[joint][0]
