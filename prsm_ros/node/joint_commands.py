"""Decode a sensor_msgs/JointState command as ros2_control's topic-based hardware interface writes it (no ROS).

`joint_state_topic_hardware_interface/JointStateTopicSystem` (ros-controls/
topic_based_hardware_interfaces, formerly PickNik's topic_based_ros2_control) publishes, on
every `write()`, one JointState whose `name` lists every joint of the `<ros2_control>` tag in
order, and whose `position`, `velocity` and `effort` arrays hold one value per joint that
declares that command interface, packed in `name` order. They may therefore be shorter than
`name`, or empty. With this actuator's joints (`screw_joint`: velocity and/or effort;
`nut_joint`: position) the arrays hold at most one value each.

Also accepted: the unpacked layout (an array as long as `name`, indexed by name).
"""

from __future__ import annotations

from collections.abc import Sequence

from prsm_sim import Session
from prsm_sim.command_gate import INTERFACE_UNIT

from prsm_ros.interface import NUT_JOINT, SCREW_JOINT

# which joint takes which command interface (ROS conventions: the nut is prismatic, the screw revolute)
INTERFACE_JOINT = {"position": NUT_JOINT, "velocity": SCREW_JOINT, "effort": SCREW_JOINT}


def decode_joint_command(names: Sequence[str], arrays: dict[str, Sequence[float]], active: str,
                         joints: dict[str, str] | None = None) -> tuple[float | None, str | None]:
    """The command for the `active` interface from a JointState's arrays: (value, None) or (None, reason).

    `arrays` maps "position", "velocity", "effort" to the message's arrays. The active
    interface's array must hold the value of its joint, packed (one value per joint that has
    the interface; here one) or unpacked (as long as `name`). Arrays of the other interfaces
    are ignored when the active one is present (the plugin writes every declared command
    interface, active or not); a message that carries only another interface's value is
    refused with a reason naming the active one.
    """
    joints = joints or INTERFACE_JOINT
    names = list(names)
    if len(set(names)) != len(names):
        return None, f"joint command names {names} repeat a joint"
    joint = joints[active]
    arr = list(arrays.get(active, ()))
    if not arr:
        others = [k for k, v in arrays.items() if k != active and len(v)]
        if others:
            return None, (f"joint command carries {', '.join(others)} but the active command interface is {active!r} "
                          f"({joint}, {INTERFACE_UNIT[active]}); switch with ~/set_command_interface or "
                          f"the command_interface parameter")
        return None, f"joint command has no {active} value (active command interface {active!r}, joint {joint})"
    if joint not in names:
        return None, f"joint command has no {joint!r} (names: {names}); the {active} command goes to {joint}"
    n = len(names)
    if len(arr) == n:
        value = arr[names.index(joint)]
    elif len(arr) == 1:
        value = arr[0]  # packed: the one joint with this command interface
    else:
        return None, (f"joint command has {n} names but {len(arr)} {active} values; expected 1 (packed, only "
                      f"{joint} has a {active} command interface), {n} (one per name) or 0")
    return value, None  # the gate checks it is a finite number


def offer_joint_command(session: Session, names: Sequence[str], arrays: dict[str, Sequence[float]],
                        joints: dict[str, str] | None = None) -> str | None:
    """A JointState command to `session` for its active interface: the reason it was refused, or None.

    A message that does not hold a value for the active interface is counted by the gate as
    received and malformed; the value it holds goes to the gate, which checks it is a finite number.
    """
    value, reason = decode_joint_command(names, arrays, session.interface, joints)
    if reason is not None:
        return session.refuse_malformed(reason)
    return session.offer(session.interface, value)
