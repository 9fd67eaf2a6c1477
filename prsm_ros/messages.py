"""The one mapping from simulator outputs to ROS 2 messages (DESIGN.md "ROS interface").

Used by the node, by the offline MCAP writer and by the Rerun bag reader, so a bag written by
`prsm-sim run` and one recorded from `prsm-node` carry the same topics, types and layouts.

Topics (names as the node declares them; `~` is the node, default `/prsm_actuator`):

| key                    | declared name               | type                          | dir |
|------------------------|-----------------------------|-------------------------------|-----|
| screw_torque           | ~/screw_torque              | std_msgs/Float64 (N·m)        | in  |
| joint_commands         | ~/joint_commands            | sensor_msgs/JointState        | in  |
| nut_position_reference | ~/nut_position_reference    | std_msgs/Float64 (m)          | in (recorded only) |
| joint_states           | joint_states                | sensor_msgs/JointState        | out |
| wrench                 | ~/nut/wrench                | geometry_msgs/WrenchStamped   | out |
| internal_loads         | ~/internal_loads            | std_msgs/Float64MultiArray    | out |
| labels                 | ~/internal_loads/labels     | std_msgs/String (JSON)        | out, latched |
| command_echo           | ~/command_echo              | sensor_msgs/TimeReference     | out |
| clock                  | /clock                      | rosgraph_msgs/Clock           | out |
| diagnostics            | /diagnostics                | diagnostic_msgs/DiagnosticArray | out |

`/clock` is published reliable, keep last 1: a reliable writer matches both the best-effort
readers of rclcpp's TimeSource and reliable readers (a best-effort writer would match only the
former).

`joint_states` is reliable keep-last 100: a reader that stalls up to 100 ms at 1 kHz loses no
state; a slower one loses the oldest. `~/command_echo` carries, with the step that first applied
a command (`header.stamp`, the same stamp as that step's joint_states), the command's own stamp
(`time_ref`: DDS source timestamp for Float64 commands, header stamp for JointState ones, system
clock) and its topic (`source`), so a controller can measure its loop latency.

`~/internal_loads` layout: `data` = every scalar output in `OUTPUT_FIELDS` order, `time_s`
included (Float64MultiArray has no header, so the row carries its own simulation time), then the
model's flat internal vector (`InternalLayout`, blocks concatenated in C order). `layout.dim` has
one entry per segment — "scalars" then each block name — with `size` = `stride` = the segment's
element count and `data_offset` = 0; the shapes, element labels and units are on the latched
`~/internal_loads/labels` topic (JSON, see `labels_document`).
"""

from __future__ import annotations

import array
import json
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_system_default)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState, TimeReference
from std_msgs.msg import Float64, Float64MultiArray, Header, MultiArrayDimension, MultiArrayLayout, String

from prsm_sim import OUTPUT_FIELDS, InternalBlock, InternalLayout, Outputs

NODE_NAME = "prsm_actuator"
SCREW_JOINT = "screw_joint"
NUT_JOINT = "nut_joint"
NUT_FRAME = "nut_link"
LABELS_FORMAT = "prsm_internal_loads/1"
SCALAR_SEGMENT = "scalars"


def _qos(depth: int, *, reliable: bool = True, latched: bool = False) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


@dataclass(frozen=True)
class TopicSpec:
    """A topic of the node's interface: `name` as declared (relative to the node), type, QoS, direction."""

    key: str
    name: str
    msg_class: type
    qos: QoSProfile
    direction: str  # "in" | "out"

    def resolved(self, node_name: str = NODE_NAME, namespace: str = "/") -> str:
        """The full topic name for a node of this name in this namespace (no remapping)."""
        ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
        if self.name.startswith("/"):
            return self.name
        if self.name.startswith("~/"):
            return f"{ns}/{node_name}/{self.name[2:]}"
        return f"{ns}/{self.name}"


TOPICS: dict[str, TopicSpec] = {t.key: t for t in (
    TopicSpec("screw_torque", "~/screw_torque", Float64, _qos(1), "in"),
    TopicSpec("joint_commands", "~/joint_commands", JointState, _qos(1), "in"),
    TopicSpec("nut_position_reference", "~/nut_position_reference", Float64, _qos(10), "in"),
    TopicSpec("joint_states", "joint_states", JointState, _qos(100), "out"),
    TopicSpec("wrench", "~/nut/wrench", WrenchStamped, _qos(10), "out"),
    TopicSpec("internal_loads", "~/internal_loads", Float64MultiArray, _qos(10), "out"),
    TopicSpec("labels", "~/internal_loads/labels", String, _qos(1, latched=True), "out"),
    TopicSpec("command_echo", "~/command_echo", TimeReference, _qos(100), "out"),
    TopicSpec("clock", "/clock", Clock, _qos(1), "out"),
    TopicSpec("diagnostics", "/diagnostics", DiagnosticArray, qos_profile_system_default, "out"),
)}

def with_depth(qos: QoSProfile, depth: int) -> QoSProfile:
    """The same policies with a deeper keep-last history.

    For the other end of a topic: a controller's command writer or a test's reader. A reliable
    writer of depth 1 can fail to publish ("cannot publish data") when its previous sample is not
    yet acknowledged, which happens on a loaded machine; the node's depth-1 command reader still
    keeps only the newest command.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=max(qos.depth, depth), reliability=qos.reliability,
                      durability=qos.durability)


# The per-step output topics, in the order `MessageMapper.messages` returns them.
STEP_TOPICS = ("joint_states", "wrench", "internal_loads", "clock")


def time_ns(time_s: float) -> int:
    """Simulation time in integer nanoseconds (rounded: step sums like 0.001 × k are not exact)."""
    return int(round(time_s * 1e9))


def stamp(time_s: float) -> Time:
    """builtin_interfaces/Time for a simulation time in seconds."""
    sec, nanosec = divmod(time_ns(time_s), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def _split_label(text: str) -> tuple[str, str]:
    """ "per_roller[2].x_n [N]" → ("per_roller[2].x_n", "N") (InternalLayout.labels() format)."""
    name, _, unit = text.rpartition(" [")
    return name, unit[:-1]


def labels_document(layout: InternalLayout, model_name: str) -> dict[str, Any]:
    """What every element of `~/internal_loads` data means (the labels topic's JSON).

    Keys: format, model, elements (list of {label, unit}, one per data element), segments
    (name, offset, size, and for blocks dims/shape/quantities), layout (InternalLayout.to_dict()).
    """
    elements = [{"label": n, "unit": u} for n, u in OUTPUT_FIELDS]
    elements += [dict(zip(("label", "unit"), _split_label(t))) for t in layout.labels()]
    n_scalar = len(OUTPUT_FIELDS)
    segments: list[dict[str, Any]] = [{"name": SCALAR_SEGMENT, "offset": 0, "size": n_scalar}]
    blocks = layout.to_dict()["blocks"]
    for b, (name, off) in zip(blocks, layout.offsets().items()):
        segments.append({"name": name, "offset": n_scalar + off, "size": int(np.prod(b["shape"])),
                         "dims": b["dims"], "shape": b["shape"], "quantities": b["quantities"]})
    return {"format": LABELS_FORMAT, "model": model_name, "elements": elements, "segments": segments,
            "layout": layout.to_dict()}


def parse_labels(json_str: str) -> dict[str, Any]:
    """The labels JSON back as a dict, checked; adds "layout_obj" (an InternalLayout) for convenience.

    Raises ValueError naming what is wrong when the text is not a labels document of this format.
    """
    try:
        doc = json.loads(json_str)
    except (TypeError, json.JSONDecodeError) as e:
        raise ValueError(f"internal_loads labels: not valid JSON ({e})") from None
    if not isinstance(doc, dict) or doc.get("format") != LABELS_FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise ValueError(f"internal_loads labels: format {got!r}, expected {LABELS_FORMAT!r}")
    for key in ("model", "elements", "segments", "layout"):
        if key not in doc:
            raise ValueError(f"internal_loads labels: missing key {key!r}")
    doc["layout_obj"] = InternalLayout(blocks=tuple(
        InternalBlock(b["name"], tuple(b["dims"]), tuple(b["shape"]),
                      tuple((q["name"], q["unit"]) for q in b["quantities"]))
        for b in doc["layout"]["blocks"]))
    return doc


def unpack_internal(msg: Float64MultiArray | np.ndarray, labels: dict[str, Any]) -> dict[str, np.ndarray]:
    """Name → array from one `~/internal_loads` message (or a rows × elements array of many).

    Scalars come out by their OUTPUT_FIELDS name (0-d, or one value per row), blocks by block
    name reshaped to the block's shape (with a leading row axis for 2-D input).
    """
    data = np.asarray(msg.data if hasattr(msg, "data") else msg, dtype=float)
    rows = data.shape[:-1]
    n = sum(s["size"] for s in labels["segments"])
    if data.shape[-1] != n:
        raise ValueError(f"internal_loads: {data.shape[-1]} elements, the labels describe {n}")
    out: dict[str, np.ndarray] = {}
    for seg in labels["segments"]:
        part = data[..., seg["offset"]: seg["offset"] + seg["size"]]
        if seg["name"] == SCALAR_SEGMENT:
            for k, el in enumerate(labels["elements"][: seg["size"]]):
                out[el["label"]] = part[..., k]
        else:
            out[seg["name"]] = part.reshape(rows + tuple(seg["shape"]))
    return out


class MessageMapper:
    """Outputs → ROS messages for one model's layout; the fixed parts are built once."""

    def __init__(self, layout: InternalLayout, model_name: str) -> None:
        self.layout = layout
        self.model_name = model_name
        self._names = [SCREW_JOINT, NUT_JOINT]
        self._fields = [n for n, _ in OUTPUT_FIELDS]
        self._size = len(self._fields) + layout.size
        dims = [MultiArrayDimension(label=SCALAR_SEGMENT, size=len(self._fields), stride=len(self._fields))]
        dims += [MultiArrayDimension(label=b.name, size=b.size, stride=b.size) for b in layout.blocks]
        self._multiarray_layout = MultiArrayLayout(dim=dims, data_offset=0)
        self._labels_json = json.dumps(labels_document(layout, model_name), ensure_ascii=False)

    @property
    def size(self) -> int:
        """Number of elements in `~/internal_loads` data."""
        return self._size

    def joint_state(self, out: Outputs, stamp_msg: Time | None = None) -> JointState:
        """`screw_joint`: rad, rad/s, applied N·m; `nut_joint`: m, m/s, N (nut_force_n)."""
        return JointState(
            header=_header(out.time_s, stamp_msg, ""), name=self._names,
            position=array.array("d", (out.screw_angle_rad, out.nut_position_m)),
            velocity=array.array("d", (out.screw_speed_rad_s, out.nut_velocity_m_s)),
            effort=array.array("d", (out.screw_torque_nm, out.nut_force_n)))

    def wrench(self, out: Outputs, stamp_msg: Time | None = None) -> WrenchStamped:
        """Axial thread force on the nut in force.z of `nut_link` (z along +x_nut)."""
        msg = WrenchStamped(header=_header(out.time_s, stamp_msg, NUT_FRAME))
        msg.wrench.force.z = float(out.nut_force_n)
        return msg

    def internal_loads(self, out: Outputs) -> Float64MultiArray:
        row = array.array("d", [getattr(out, f) for f in self._fields])
        if self.layout.size:
            row.frombytes(np.ascontiguousarray(out.internal, dtype=np.float64).tobytes())
        return Float64MultiArray(layout=self._multiarray_layout, data=row)

    def labels(self) -> String:
        return String(data=self._labels_json)

    def encoder(self):
        """The same per-step messages as CDR bytes, without message objects (`prsm_ros.node.cdr`)."""
        from prsm_ros.node.cdr import StepEncoder
        return StepEncoder(self.layout, tuple(self._names), NUT_FRAME,
                           [(d.label, d.size) for d in self._multiarray_layout.dim])

    @staticmethod
    def clock(time_s: float) -> Clock:
        return Clock(clock=stamp(time_s))

    def messages(self, out: Outputs) -> list[tuple[str, Any]]:
        """The per-step messages as (default full topic name, message), in STEP_TOPICS order."""
        st = stamp(out.time_s)
        msgs = (self.joint_state(out, st), self.wrench(out, st), self.internal_loads(out), Clock(clock=st))
        return [(TOPICS[k].resolved(), m) for k, m in zip(STEP_TOPICS, msgs)]


def _header(time_s: float, stamp_msg: Time | None, frame_id: str) -> Header:
    return Header(stamp=stamp_msg if stamp_msg is not None else stamp(time_s), frame_id=frame_id)

