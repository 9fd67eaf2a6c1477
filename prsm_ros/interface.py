"""The node's ROS 2 interface as plain data, and the one mapping from simulator outputs to messages.

Nothing here imports rclpy or a ROS message package: the bag tools, the Rerun converter and the
offline MCAP writer use this module on an install without the `ros` extra. `prsm_ros.messages`
binds the same definitions to rclpy (message classes, QoSProfile) for the node.

Topics (names as the node declares them; `~` is the node, default `/prsm_actuator`):

| key                    | declared name               | type                          | dir |
|------------------------|-----------------------------|-------------------------------|-----|
| screw_torque           | ~/screw_torque              | std_msgs/Float64 (N·m)        | in  |
| joint_commands         | ~/joint_commands            | sensor_msgs/JointState        | in  |
| nut_position_reference | ~/nut_position_reference    | sensor_msgs/JointState (m, m/s) | in (recorded only) |
| velocity_command       | ~/velocity_command          | std_msgs/Float64 (rad/s)      | in (command_interface velocity) |
| position_command       | ~/position_command          | std_msgs/Float64 (m)          | in (command_interface position) |
| inject_fault           | ~/inject_fault              | std_msgs/String ('kind=…,start_s=…') | in (with an actuator) |
| brake_command          | ~/brake_command             | std_msgs/Bool (true: engage)  | in (with an actuator) |
| joint_states           | joint_states                | sensor_msgs/JointState        | out (measured, with an actuator) |
| ground_truth           | ~/ground_truth/joint_states | sensor_msgs/JointState        | out (with an actuator) |
| wrench                 | ~/nut/wrench                | geometry_msgs/WrenchStamped   | out |
| internal_loads         | ~/internal_loads            | std_msgs/Float64MultiArray    | out |
| labels                 | ~/internal_loads/labels     | std_msgs/String (JSON)        | out, latched |
| command_echo           | ~/command_echo              | sensor_msgs/TimeReference     | out |
| clock                  | /clock                      | rosgraph_msgs/Clock           | out |
| diagnostics            | /diagnostics                | diagnostic_msgs/DiagnosticArray | out |
| events                 | ~/events                    | std_msgs/String (JSON)        | out, latched history |
| robot_description      | robot_description           | std_msgs/String (URDF)        | out, latched |

`~/events`: one JSON object per event (`event_document`): time_s (simulation time), source (what
raised it, e.g. "energy_guard"), severity ("info", "warn", "error"), code (a stable identifier),
message (one line for people), details (an object). Latched with a history of 100, so a late
subscriber still gets the recent events; the recorder writes them into the bag.

`~/nut_position_reference`: a controller's reference, recorded for the report: `nut_joint` with the
reference position (m) and velocity (m/s), `header.stamp` = the stamp of the state it answers, so
the report pairs each reference with that state (and the bag records it at that log time).

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

import json
import math
from dataclasses import dataclass
from typing import Any
from collections.abc import Callable, Mapping

import numpy as np

from prsm_sim import OUTPUT_FIELDS, InputError, InternalBlock, InternalLayout, Outputs

NODE_NAME = "prsm_actuator"
SCREW_JOINT = "screw_joint"
NUT_JOINT = "nut_joint"
NUT_FRAME = "nut_link"
LABELS_FORMAT = "prsm_internal_loads/1"
SCALAR_SEGMENT = "scalars"

# QoS policy values as rmw numbers them (rmw/types.h): the same integers rclpy's enums carry and
# rosbag2 records in `offered_qos_profiles`. 0 everywhere is the middleware's system default.
SYSTEM_DEFAULT = 0
KEEP_LAST, KEEP_ALL = 1, 2
RELIABLE, BEST_EFFORT = 1, 2
TRANSIENT_LOCAL, VOLATILE = 1, 2


@dataclass(frozen=True)
class QosSpec:
    """A QoS profile as plain data (rmw integers); deadline, lifespan and liveliness stay at their defaults."""

    history: int
    depth: int
    reliability: int
    durability: int


def qos(depth: int, *, reliable: bool = True, latched: bool = False) -> QosSpec:
    """Keep-last `depth`, reliable or best effort, transient local (latched) or volatile."""
    return QosSpec(KEEP_LAST, depth, RELIABLE if reliable else BEST_EFFORT, TRANSIENT_LOCAL if latched else VOLATILE)


SYSTEM_DEFAULT_QOS = QosSpec(SYSTEM_DEFAULT, 0, SYSTEM_DEFAULT, SYSTEM_DEFAULT)


def resolve_name(name: str, node_name: str = NODE_NAME, namespace: str = "/") -> str:
    """The full topic name of a declared name for a node of this name in this namespace (no remapping)."""
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    if name.startswith("/"):
        return name
    if name.startswith("~/"):
        return f"{ns}/{node_name}/{name[2:]}"
    return f"{ns}/{name}"


@dataclass(frozen=True)
class TopicDef:
    """A topic of the node's interface: `name` as declared (relative to the node), type, QoS, direction."""

    key: str
    name: str
    type_name: str  # pkg/msg/Type
    qos: QosSpec
    direction: str  # "in" | "out"

    def resolved(self, node_name: str = NODE_NAME, namespace: str = "/") -> str:
        return resolve_name(self.name, node_name, namespace)


TOPIC_DEFS: dict[str, TopicDef] = {t.key: t for t in (
    TopicDef("screw_torque", "~/screw_torque", "std_msgs/msg/Float64", qos(1), "in"),
    TopicDef("joint_commands", "~/joint_commands", "sensor_msgs/msg/JointState", qos(1), "in"),
    TopicDef("velocity_command", "~/velocity_command", "std_msgs/msg/Float64", qos(1), "in"),
    TopicDef("position_command", "~/position_command", "std_msgs/msg/Float64", qos(1), "in"),
    TopicDef("inject_fault", "~/inject_fault", "std_msgs/msg/String", qos(10), "in"),
    # the brake, owned like the commands (a service cannot tell who calls it)
    TopicDef("brake_command", "~/brake_command", "std_msgs/msg/Bool", qos(10), "in"),
    TopicDef("nut_position_reference", "~/nut_position_reference", "sensor_msgs/msg/JointState", qos(10), "in"),
    # keep-last 100: a reader that stalls up to 100 ms at 1 kHz loses no state
    TopicDef("joint_states", "joint_states", "sensor_msgs/msg/JointState", qos(100), "out"),
    TopicDef("ground_truth", "~/ground_truth/joint_states", "sensor_msgs/msg/JointState", qos(10), "out"),
    TopicDef("wrench", "~/nut/wrench", "geometry_msgs/msg/WrenchStamped", qos(10), "out"),
    TopicDef("internal_loads", "~/internal_loads", "std_msgs/msg/Float64MultiArray", qos(10), "out"),
    TopicDef("labels", "~/internal_loads/labels", "std_msgs/msg/String", qos(1, latched=True), "out"),
    # with the step that first applied a command: its stamp (time_ref) and topic (source)
    TopicDef("command_echo", "~/command_echo", "sensor_msgs/msg/TimeReference", qos(100), "out"),
    TopicDef("clock", "/clock", "rosgraph_msgs/msg/Clock", qos(1), "out"),
    TopicDef("diagnostics", "/diagnostics", "diagnostic_msgs/msg/DiagnosticArray", SYSTEM_DEFAULT_QOS, "out"),
    TopicDef("events", "~/events", "std_msgs/msg/String", qos(100, latched=True), "out"),
    # the actuator as configured (prsm_ros.node.urdf), as robot_state_publisher publishes it: reliable, transient local
    TopicDef("robot_description", "robot_description", "std_msgs/msg/String", qos(1, latched=True), "out"),
)}


EVENT_SEVERITIES = ("info", "warn", "error")


def event_document(time_s: float, source: str, severity: str, code: str, message: str,
                   details: Mapping[str, Any] | None = None) -> str:
    """The JSON text of one `~/events` entry (see the module doc); ValueError for an unknown severity."""
    if severity not in EVENT_SEVERITIES:
        raise InputError(f"severity = {severity!r}: must be one of {', '.join(EVENT_SEVERITIES)}")
    doc = {"time_s": float(time_s), "source": source, "severity": severity, "code": code, "message": message,
           "details": dict(details or {})}
    return json.dumps(doc, allow_nan=False, default=float)

# The per-step output topics, in the order `MessageBuilder.messages` returns them.
STEP_TOPICS = ("joint_states", "wrench", "internal_loads", "clock")

# Every message type `MessageBuilder` constructs (the classes a message kit must provide).
BUILT_TYPES = (
    "builtin_interfaces/msg/Time", "std_msgs/msg/Header", "sensor_msgs/msg/JointState",
    "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Wrench", "geometry_msgs/msg/WrenchStamped",
    "std_msgs/msg/MultiArrayDimension", "std_msgs/msg/MultiArrayLayout", "std_msgs/msg/Float64MultiArray",
    "std_msgs/msg/String", "std_msgs/msg/Float64", "rosgraph_msgs/msg/Clock",
)


def time_ns(time_s: float) -> int:
    """Simulation time in integer nanoseconds (rounded: step sums like 0.001 × k are not exact)."""
    return int(round(time_s * 1e9))


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
    from prsm_ros.limits import load_json  # nesting bounded before json.loads recurses
    doc = load_json(json_str, source="internal_loads labels", error=InputError)
    if not isinstance(doc, dict) or doc.get("format") != LABELS_FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise InputError(f"internal_loads labels: format {str(got)[:40]!r}, expected {LABELS_FORMAT!r}")
    for key in ("model", "elements", "segments", "layout"):
        if key not in doc:
            raise InputError(f"internal_loads labels: missing key {key!r}")
    _check_labels(doc)
    doc["layout_obj"] = InternalLayout(blocks=tuple(
        InternalBlock(b["name"], tuple(b["dims"]), tuple(b["shape"]),
                      tuple((q["name"], q["unit"]) for q in b["quantities"]))
        for b in doc["layout"]["blocks"]))
    return doc


LABELS_MAX_ELEMENTS = 1_000_000  # elements of one ~/internal_loads message described by its labels


def _is_count(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= LABELS_MAX_ELEMENTS


def _check_block(where: str, b, *, segment: bool) -> None:
    """InputError naming `where` unless `b` is a block: name, dims, shape (counts) and per-quantity name and unit."""
    if not isinstance(b, dict) or not isinstance(b.get("name"), str):
        raise InputError(f"internal_loads labels: {where}: expected an object with a name")
    if segment and not (_is_count(b.get("offset")) and _is_count(b.get("size"))):
        raise InputError(f"internal_loads labels: {where}: offset and size must be whole numbers 0…{LABELS_MAX_ELEMENTS}")
    if not segment or b["name"] != SCALAR_SEGMENT or "quantities" in b:
        dims, shape, qs = b.get("dims"), b.get("shape"), b.get("quantities")
        if not (isinstance(dims, list) and all(isinstance(d, str) for d in dims)
                and isinstance(shape, list) and shape and all(_is_count(n) for n in shape) and len(shape) == len(dims)
                and isinstance(qs, list) and len(qs) == shape[-1]
                and all(isinstance(q, dict) and isinstance(q.get("name"), str) and isinstance(q.get("unit"), str)
                        for q in qs)):
            raise InputError(f"internal_loads labels: {where}: dims, shape and quantities do not describe a block")
        if segment and math.prod(shape) != b["size"]:
            raise InputError(f"internal_loads labels: {where}: shape {shape} does not hold its size {b['size']}")


def _check_labels(doc: dict) -> None:
    """InputError naming the first part of a labels document that unpack_internal and the bag tools cannot use."""
    elements, segments, layout = doc["elements"], doc["segments"], doc["layout"]
    if not (isinstance(elements, list) and all(isinstance(e, dict) and isinstance(e.get("label"), str) for e in elements)):
        raise InputError("internal_loads labels: elements: expected a list of objects with a label")
    if not isinstance(segments, list) or not isinstance(layout, dict) or not isinstance(layout.get("blocks"), list):
        raise InputError("internal_loads labels: segments and layout.blocks must be lists")
    offset = 0
    names = {e["label"] for e in elements}
    for k, seg in enumerate(segments):
        _check_block(f"segment {k}", seg, segment=True)
        if seg["name"] != SCALAR_SEGMENT and seg["name"] in names:
            raise InputError(f"internal_loads labels: segment {k}: its name is taken by another segment or element")
        names.add(seg["name"])
        if seg["offset"] != offset or offset + seg["size"] > LABELS_MAX_ELEMENTS:
            raise InputError(f"internal_loads labels: segment {k}: offset {seg['offset']}, expected {offset}")
        if seg["name"] == SCALAR_SEGMENT and seg["size"] > len(elements):
            raise InputError(f"internal_loads labels: segment {k}: {seg['size']} scalars, {len(elements)} elements")
        offset += seg["size"]
    for k, b in enumerate(layout["blocks"]):
        _check_block(f"layout block {k}", b, segment=False)


def unpack_internal(msg, labels: dict[str, Any]) -> dict[str, np.ndarray]:
    """Name → array from one `~/internal_loads` message (or a rows × elements array of many).

    Scalars come out by their OUTPUT_FIELDS name (0-d, or one value per row), blocks by block
    name reshaped to the block's shape (with a leading row axis for 2-D input).
    """
    data = np.asarray(msg.data if hasattr(msg, "data") else msg, dtype=float)
    rows = data.shape[:-1]
    n = sum(s["size"] for s in labels["segments"])
    if data.shape[-1] != n:
        raise InputError(f"internal_loads: {data.shape[-1]} elements, the labels describe {n}")
    out: dict[str, np.ndarray] = {}
    for seg in labels["segments"]:
        part = data[..., seg["offset"]: seg["offset"] + seg["size"]]
        if seg["name"] == SCALAR_SEGMENT:
            for k, el in enumerate(labels["elements"][: seg["size"]]):
                out[el["label"]] = part[..., k]
        else:
            out[seg["name"]] = part.reshape(rows + tuple(seg["shape"]))
    return out


class MessageBuilder:
    """Outputs → ROS messages for one model's layout, built from any message kit.

    `classes` maps each name of `BUILT_TYPES` to a message class whose constructor takes the
    fields as keywords (rclpy's generated classes, or the dataclasses of a rosbags typestore);
    `float_array` turns a 1-D float64 ndarray into what the kit stores in a `float64[]` field.
    Every field is given, so kits without defaults work too. The fixed parts are built once.
    """

    def __init__(self, layout: InternalLayout, model_name: str, classes: Mapping[str, type],
                 float_array: Callable[[np.ndarray], Any], *, joint_names: tuple[str, str] = (SCREW_JOINT, NUT_JOINT),
                 nut_frame: str = NUT_FRAME) -> None:
        self.layout = layout
        self.model_name = model_name
        c = classes
        self._time, self._header = c["builtin_interfaces/msg/Time"], c["std_msgs/msg/Header"]
        self._joint_state = c["sensor_msgs/msg/JointState"]
        self._vector3, self._wrench = c["geometry_msgs/msg/Vector3"], c["geometry_msgs/msg/Wrench"]
        self._wrench_stamped = c["geometry_msgs/msg/WrenchStamped"]
        self._multiarray = c["std_msgs/msg/Float64MultiArray"]
        self._string, self._float64 = c["std_msgs/msg/String"], c["std_msgs/msg/Float64"]
        self._clock = c["rosgraph_msgs/msg/Clock"]
        self._float_array = float_array
        self._names = list(joint_names)  # screw, nut (the node's joints.* parameters)
        self._nut_frame = nut_frame
        self._fields = [n for n, _ in OUTPUT_FIELDS]
        self._size = len(self._fields) + layout.size
        dim, lay = c["std_msgs/msg/MultiArrayDimension"], c["std_msgs/msg/MultiArrayLayout"]
        dims = [dim(label=SCALAR_SEGMENT, size=len(self._fields), stride=len(self._fields))]
        dims += [dim(label=b.name, size=b.size, stride=b.size) for b in layout.blocks]
        self._multiarray_layout = lay(dim=dims, data_offset=0)
        self._labels_json = json.dumps(labels_document(layout, model_name), ensure_ascii=False)

    @property
    def size(self) -> int:
        """Number of elements in `~/internal_loads` data."""
        return self._size

    def stamp(self, time_s: float):
        """builtin_interfaces/Time for a simulation time in seconds."""
        sec, nanosec = divmod(time_ns(time_s), 1_000_000_000)
        return self._time(sec=sec, nanosec=nanosec)

    def _header_for(self, time_s: float, stamp_msg, frame_id: str):
        return self._header(stamp=stamp_msg if stamp_msg is not None else self.stamp(time_s), frame_id=frame_id)

    def joint_state(self, out: Outputs, stamp_msg=None):
        """`screw_joint`: rad, rad/s, applied N·m; `nut_joint`: m, m/s, N (nut_force_n)."""
        fa = self._float_array
        return self._joint_state(
            header=self._header_for(out.time_s, stamp_msg, ""), name=list(self._names),
            position=fa(np.array((out.screw_angle_rad, out.nut_position_m), dtype=np.float64)),
            velocity=fa(np.array((out.screw_speed_rad_s, out.nut_velocity_m_s), dtype=np.float64)),
            effort=fa(np.array((out.screw_torque_nm, out.nut_force_n), dtype=np.float64)))

    def wrench(self, out: Outputs, stamp_msg=None):
        """Axial thread force on the nut in force.z of `nut_link` (z along +x_nut)."""
        v = self._vector3
        return self._wrench_stamped(
            header=self._header_for(out.time_s, stamp_msg, self._nut_frame),
            wrench=self._wrench(force=v(x=0.0, y=0.0, z=float(out.nut_force_n)), torque=v(x=0.0, y=0.0, z=0.0)))

    def internal_loads(self, out: Outputs):
        n = len(self._fields)
        row = np.empty(self._size, dtype=np.float64)
        row[:n] = [getattr(out, f) for f in self._fields]
        if self.layout.size:
            row[n:] = np.ravel(out.internal)
        return self._multiarray(layout=self._multiarray_layout, data=self._float_array(row))

    def labels(self):
        return self._string(data=self._labels_json)

    def float64(self, value: float):
        """std_msgs/Float64: a command or reference value as a controller publishes it."""
        return self._float64(data=float(value))

    def reference(self, stamp_ns: int, position_m: float, velocity_m_s: float = math.nan):
        """`~/nut_position_reference`: the nut reference answering the state stamped `stamp_ns`."""
        fa = self._float_array
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        return self._joint_state(
            header=self._header(stamp=self._time(sec=sec, nanosec=nanosec), frame_id=""), name=[NUT_JOINT],
            position=fa(np.array((position_m,), dtype=np.float64)),
            velocity=fa(np.array((velocity_m_s,), dtype=np.float64)),
            effort=fa(np.array((math.nan,), dtype=np.float64)))  # no effort reference; not empty: a trailing empty
            # sequence gets 4 bytes of end padding from rclpy that rosbags reads as a size mismatch

    def clock(self, time_s: float):
        return self._clock(clock=self.stamp(time_s))

    def messages(self, out: Outputs) -> list[tuple[str, Any]]:
        """The per-step messages as (default full topic name, message), in STEP_TOPICS order."""
        st = self.stamp(out.time_s)
        msgs = (self.joint_state(out, st), self.wrench(out, st), self.internal_loads(out), self._clock(clock=st))
        return [(TOPIC_DEFS[k].resolved(), m) for k, m in zip(STEP_TOPICS, msgs)]
