"""Joint commands as ros2_control's topic-based hardware interface writes them (no ROS needed).

Oracle: JointStateTopicSystem::write() (ros-controls/topic_based_hardware_interfaces,
joint_state_topic_hardware_interface): `name` = every joint of the <ros2_control> tag in order;
per joint, per declared command interface, its value is appended to that interface's array.
"""

from __future__ import annotations

import math

import pytest

from prsm_ros.node.joint_commands import decode_joint_command


def plugin_message(joints: list[tuple[str, list[str]]], commands: dict[tuple[str, str], float]):
    """Build (name, arrays) exactly as JointStateTopicSystem::write() packs them."""
    names, arrays = [], {"position": [], "velocity": [], "effort": []}
    for joint, interfaces in joints:
        names.append(joint)
        for itf in interfaces:
            arrays[itf].append(commands[(joint, itf)])
    return names, arrays


URDF = [("screw_joint", ["velocity", "effort"]), ("nut_joint", ["position"])]
VALUES = {("screw_joint", "velocity"): 12.5, ("screw_joint", "effort"): 0.75, ("nut_joint", "position"): 0.042}


@pytest.mark.parametrize("active,expected", [("velocity", 12.5), ("effort", 0.75), ("position", 0.042)])
def test_plugin_shaped_message_is_accepted_in_every_mode(active, expected):
    names, arrays = plugin_message(URDF, VALUES)
    assert decode_joint_command(names, arrays, active) == (expected, None)


def test_state_only_joint_listed_and_packed_velocity():
    """The issue's case: names [screw_joint, nut_joint] (nut state-only), velocity [ω]."""
    names, arrays = plugin_message([("screw_joint", ["velocity"]), ("nut_joint", [])], VALUES)
    assert arrays == {"position": [], "velocity": [12.5], "effort": []}
    assert decode_joint_command(names, arrays, "velocity") == (12.5, None)


def test_unpacked_layout_indexed_by_name():
    assert decode_joint_command(["nut_joint", "screw_joint"], {"effort": [math.nan, 1.5]}, "effort") == (1.5, None)


@pytest.mark.parametrize("names,arrays,active,says", [
    (["screw_joint", "nut_joint"], {"velocity": [3.0]}, "effort", "active command interface is 'effort'"),
    (["screw_joint"], {"position": [0.1]}, "position", "no 'nut_joint'"),
    (["screw_joint", "nut_joint", "x"], {"effort": [1.0, 2.0]}, "effort", "3 names but 2 effort values"),
    (["screw_joint"], {"effort": [math.inf]}, "effort", "not a finite number"),
    (["screw_joint", "screw_joint"], {"effort": [1.0]}, "effort", "repeat"),
    (["screw_joint"], {}, "velocity", "no velocity value"),
])
def test_refused_with_a_reason(names, arrays, active, says):
    value, reason = decode_joint_command(names, arrays, active)
    assert value is None and says in reason and "\n" not in reason
