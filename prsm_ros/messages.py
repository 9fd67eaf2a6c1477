"""The node's interface bound to rclpy: message classes, QoSProfiles and the Outputs → message mapper.

The interface itself (topics, QoS, labels document, the mapping) is plain data in
`prsm_ros.interface`, which imports no ROS package; this module gives the node the same
definitions as rclpy objects, so a bag written by `prsm-sim run` and one recorded from `prsm-node`
carry the same topics, types and layouts. Only code that talks to ROS imports this module.
"""

from __future__ import annotations

import array
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3, Wrench, WrenchStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Bool, Float64, Float64MultiArray, Header, MultiArrayDimension, MultiArrayLayout, String

from prsm_sim import InternalLayout

from prsm_ros.cdr_write import StepEncoder
from prsm_ros.interface import (
    LABELS_FORMAT, NODE_NAME, NUT_FRAME, NUT_JOINT, SCALAR_SEGMENT, SCREW_JOINT, STEP_TOPICS, TOPIC_DEFS,
    MessageBuilder, QosSpec, event_document, labels_document, parse_labels, time_ns, unpack_internal)

# The interface's names are re-exported: the node and the tests import them from here.
__all__ = ["CLASSES", "LABELS_FORMAT", "NODE_NAME", "NUT_FRAME", "NUT_JOINT", "SCALAR_SEGMENT", "SCREW_JOINT",
           "STEP_TOPICS", "TOPICS", "TOPIC_DEFS", "MessageMapper", "TopicSpec", "event_message", "labels_document", "parse_labels",
           "qos_profile", "stamp", "time_ns", "unpack_internal", "with_depth"]

# The rclpy class of every type the interface uses (the message kit of `MessageBuilder`).
CLASSES: dict[str, type] = {f"{c.__module__.split('.')[0]}/msg/{c.__name__}": c for c in (
    Time, Header, JointState, Vector3, Wrench, WrenchStamped, MultiArrayDimension, MultiArrayLayout,
    Float64MultiArray, String, Float64, Clock, DiagnosticArray, TimeReference, Bool)}


def qos_profile(spec: QosSpec) -> QoSProfile:
    """The rclpy QoSProfile of a plain `QosSpec` (same rmw integers)."""
    return QoSProfile(history=HistoryPolicy(spec.history), depth=spec.depth,
                      reliability=ReliabilityPolicy(spec.reliability), durability=DurabilityPolicy(spec.durability))


@dataclass(frozen=True)
class TopicSpec:
    """A topic of the node's interface: `name` as declared (relative to the node), class, QoS, direction."""

    key: str
    name: str
    msg_class: type
    qos: QoSProfile
    direction: str  # "in" | "out"

    def resolved(self, node_name: str = NODE_NAME, namespace: str = "/") -> str:
        """The full topic name for a node of this name in this namespace (no remapping)."""
        return TOPIC_DEFS[self.key].resolved(node_name, namespace)


TOPICS: dict[str, TopicSpec] = {
    k: TopicSpec(k, t.name, CLASSES[t.type_name], qos_profile(t.qos), t.direction) for k, t in TOPIC_DEFS.items()}


def event_message(time_s: float, source: str, severity: str, code: str, message: str,
                  details: dict[str, Any] | None = None) -> String:
    """One event for `~/events` (`interface.event_document`): a std_msgs/String holding one JSON object."""
    return String(data=event_document(time_s, source, severity, code, message, details))


def with_depth(qos: QoSProfile, depth: int) -> QoSProfile:
    """The same policies with a deeper keep-last history.

    For the other end of a topic: a controller's command writer or a test's reader. A reliable
    writer of depth 1 can fail to publish ("cannot publish data") when its previous sample is not
    yet acknowledged, which happens on a loaded machine; the node's depth-1 command reader still
    keeps only the newest command.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(qos.depth, depth), reliability=qos.reliability,
                      durability=qos.durability)


def stamp(time_s: float) -> Time:
    """builtin_interfaces/Time for a simulation time in seconds."""
    sec, nanosec = divmod(time_ns(time_s), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def _float_array(a: np.ndarray) -> array.array:
    # rclpy stores float64[] as array.array("d"); from bytes it is one copy, not an element loop
    return array.array("d", a.tobytes())


class MessageMapper(MessageBuilder):
    """Outputs → rclpy messages for one model's layout (the interface's mapping with rclpy's classes)."""

    def __init__(self, layout: InternalLayout, model_name: str, *, joint_names: tuple[str, str] = (SCREW_JOINT, NUT_JOINT),
                 nut_frame: str = NUT_FRAME) -> None:
        super().__init__(layout, model_name, CLASSES, _float_array, joint_names=joint_names, nut_frame=nut_frame)

    @staticmethod
    def clock(time_s: float) -> Clock:
        return Clock(clock=stamp(time_s))

    def encoder(self) -> StepEncoder:
        """The same per-step messages as CDR bytes, without message objects (`prsm_ros.cdr_write`)."""
        return StepEncoder(self.layout, tuple(self._names), self._nut_frame,
                           [(d.label, d.size) for d in self._multiarray_layout.dim])
