"""`prsm-bag layout BAG`: a Foxglove layout for one bag, built with `foxglove.layouts` (foxglove-sdk).

Open the bag in Foxglove (File → Open local file), then import the layout (Layouts → Import
from file). Every panel names the bag's own topics, so a namespaced or remapped node works:

- **Motion**: nut position (measured and, with an actuator, ground truth) with the reference,
  screw speed, and the tracking error — computed by the layout's user script, which pairs each
  stamped reference with the state it answers (the same pairing as `prsm-bag report`);
- **Torque and force**: screw torque, nut force, the load, the nut wrench;
- **Efficiency**: input, output and dissipated power, the instantaneous efficiency, slip speed;
- **Rollers and teeth**: the normal force of every roller, and of every tooth of roller 0;
- **Events**: `~/events` (faults, energy guard, ownership), `/diagnostics`, and the actuator's
  states (brake, faults, torque limit) where recorded.

Array elements are addressed by index (Foxglove message paths cannot select a JointState entry
by name), taken from the bag itself: the joints' order in its first joint state and the element
labels of `~/internal_loads/labels`. Panels whose data the bag does not have are left out.
"""

from __future__ import annotations

import json

from prsm_ros.bag.reader import Bag, BagError, resolve_topics
from prsm_ros.interface import NUT_JOINT, SCREW_JOINT, TOPIC_DEFS, parse_labels

# Foxglove only accepts user-script outputs under this prefix
SCRIPT_PREFIX = "/studio_script/"
TRACKING_ERROR_TOPIC = SCRIPT_PREFIX + "prsm_tracking_error"
PER_TOOTH_ROLLER = 0
MAX_SERIES = 30  # per plot: more lines than this are unreadable

_TRACKING_SCRIPT = """\
// Tracking error: each stamped reference paired with the joint state of the same stamp (the state it
// answers), as `prsm-bag report` pairs them. Output: reference − nut position, at that stamp.
import { Input } from "./types.ts";

type Output = { header: { stamp: { sec: number; nsec: number }; frame_id: string }; error_m: number };

export const inputs = [%(state)s, %(reference)s];
export const output = %(output)s;

const states = new Map<string, number>();
const pending = new Map<string, number>();
const key = (s: { sec: number; nsec?: number; nanosec?: number }) => `${s.sec}.${s.nsec ?? s.nanosec ?? 0}`;

export default function script(event: Input<%(state)s> | Input<%(reference)s>): Output | undefined {
  const msg: any = event.message;
  const k = key(msg.header.stamp);
  if (event.topic === %(state)s) {
    const x = msg.position[%(nut_index)d];
    states.set(k, x);
    if (states.size > 4096) states.delete(states.keys().next().value);
    const ref = pending.get(k);
    if (ref === undefined) return undefined;
    pending.delete(k);
    return { header: { stamp: msg.header.stamp, frame_id: "" }, error_m: ref - x };
  }
  const ref = msg.position[0];
  const x = states.get(k);
  if (x === undefined) {
    pending.set(k, ref);
    if (pending.size > 4096) pending.delete(pending.keys().next().value);
    return undefined;
  }
  return { header: { stamp: msg.header.stamp, frame_id: "" }, error_m: ref - x };
}
"""


def _first(bag: Bag, topic: str):
    for m in bag.messages([topic]):
        return m.msg
    return None


def _labels(bag: Bag, roles: dict) -> dict | None:
    if not (roles.get("internal_loads") and roles.get("labels")):
        return None
    msg = _first(bag, roles["labels"])
    try:
        return parse_labels(msg.data) if msg is not None else None
    except ValueError:
        return None


def build_layout(bag: Bag, *, screw_joint: str = SCREW_JOINT, nut_joint: str = NUT_JOINT,
                 topics: dict | None = None):
    """The `foxglove.layouts.Layout` for `bag` (see the module doc); BagError when it has no joint states."""
    import foxglove.layouts as fl

    roles = resolve_topics(bag, topics)
    js = roles["joint_states"]
    if js is None:
        raise BagError("no joint states (sensor_msgs/msg/JointState) to lay out; choose one with --joint-states-topic")
    first = _first(bag, js)
    names = list(first.name) if first is not None else []
    if screw_joint not in names or nut_joint not in names:
        raise BagError(f"{js} has joints {names}; the layout needs {screw_joint!r} and {nut_joint!r} "
                       f"(name them with --screw-joint / --nut-joint)")
    b = _Panels(fl, bag, roles, names.index(screw_joint), names.index(nut_joint))
    motion, scripts = b.motion_tab()
    tabs = [("Motion", motion), ("Torque and force", b.torque_tab())]
    if b.index:
        tabs += [("Efficiency", b.efficiency_tab()), ("Rollers and teeth", b.rollers_tab())]
    tabs.append(("Events", b.events_tab()))
    content = fl.TabContainer(tabs=[fl.TabItem(title=title, content=c) for title, c in tabs if c is not None])
    return fl.Layout(content=content, user_scripts=scripts)


class _Panels:
    """The panels of one bag's layout: plotted message paths by the topics' roles and the labels' names."""

    def __init__(self, fl, bag: Bag, roles: dict, i_s: int, i_n: int) -> None:
        self.fl, self.bag, self.roles, self.i_s, self.i_n = fl, bag, roles, i_s, i_n
        self.js = roles["joint_states"]
        self.labels = _labels(bag, roles)
        self.index = {e["label"]: k for k, e in enumerate(self.labels["elements"])} if self.labels else {}
        self.il = roles["internal_loads"]
        truth = TOPIC_DEFS["ground_truth"].resolved()
        self.truth = truth if truth in bag.topics else None
        self._stamped: dict[str, bool] = {}

    def series(self, path: str, label: str, **kw):
        """One plotted message path; by header stamp where the topic has one (its log time otherwise)."""
        topic = path.split(".", 1)[0]
        if topic not in self._stamped:
            self._stamped[topic] = _stamped(self.bag, topic)
        return self.fl.PlotSeries(value=path, label=label,
                                  timestamp_method="headerStamp" if self._stamped[topic] else None, **kw)

    def internal(self, name: str, label: str | None = None, **kw):
        return self.series(f"{self.il}.data[{self.index[name]}]", label or name, **kw) if name in self.index else None

    def plot(self, title: str, paths, y_label: str):
        paths = [p for p in paths if p is not None][:MAX_SERIES]
        if not paths:
            return None
        fl = self.fl
        return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=paths, y_axis_label=y_label, show_legend=True,
                                                              legend_display="top", is_synced=True))

    def column(self, *panels):
        panels = [p for p in panels if p is not None]
        if not panels:
            return None
        if len(panels) == 1:
            return panels[0]
        return self.fl.SplitContainer(direction="column", items=[self.fl.SplitItem(content=p) for p in panels])

    def motion_tab(self):
        """(nut position against the reference, screw speed, tracking error; the user script that computes it)."""
        fl, js, truth, ref = self.fl, self.js, self.truth, self.roles["reference"]
        scripts, error_plot = None, None
        motion = [self.series(f"{js}.position[{self.i_n}]", "nut position [m]")]
        if truth:
            motion.append(self.series(f"{truth}.position[{self.i_n}]", "ground truth [m]", line_style="dashed"))
        if ref and _stamped(self.bag, ref):
            motion.append(self.series(f"{ref}.position[0]", "reference [m]", line_style="dashed"))
            scripts = {"prsm_tracking_error": fl.UserScript(name="prsm tracking error", source_code=_TRACKING_SCRIPT % {
                "state": json.dumps(js), "reference": json.dumps(ref), "output": json.dumps(TRACKING_ERROR_TOPIC),
                "nut_index": self.i_n})}
            error_plot = self.plot("Tracking error (reference − nut position)",
                                   [fl.PlotSeries(value=f"{TRACKING_ERROR_TOPIC}.error_m", label="error [m]",
                                                  timestamp_method="headerStamp")], "m")
        elif ref:
            motion.append(self.series(f"{ref}.data", "reference [m]", line_style="dashed", line_interpolation="step"))
        speed = [self.series(f"{js}.velocity[{self.i_s}]", "screw speed [rad/s]")]
        if truth:
            speed.append(self.series(f"{truth}.velocity[{self.i_s}]", "ground truth [rad/s]", line_style="dashed"))
        return self.column(self.plot("Nut position and reference", motion, "m"),
                           self.plot("Screw speed", speed, "rad/s"), error_plot), scripts

    def torque_tab(self):
        js, truth, wrench, i_n = self.js, self.truth, self.roles["wrench"], self.i_n
        return self.column(
            self.plot("Screw torque", [self.series(f"{js}.effort[{self.i_s}]", "screw torque [N·m]"),
                                       self.internal("actuator.motor_torque_nm", "motor torque [N·m]")], "N·m"),
            self.plot("Forces", [self.series(f"{js}.effort[{i_n}]", "nut force [N]"),
                                 self.series(f"{truth}.effort[{i_n}]", "ground truth [N]", line_style="dashed")
                                 if truth else None,
                                 self.internal("load_force_n", "load [N]", line_style="dashed"),
                                 self.series(f"{wrench}.wrench.force.z", "nut wrench force.z [N]") if wrench else None],
                      "N"))

    def efficiency_tab(self):
        internal = self.internal
        return self.column(
            self.plot("Power", [internal(k, k.removesuffix("_w").replace("_", " ") + " [W]")
                                for k in ("power_in_w", "power_out_w", "power_dissipated_w")], "W"),
            self.plot("Efficiency and slip", [internal("efficiency", "efficiency [1]"),
                                              internal("slip_speed_m_s", "slip speed [m/s]", use_right_y_axis=True)],
                      "1"))

    def rollers_tab(self):
        index, internal = self.index, self.internal
        q_roller, q_tooth = _force_quantity(self.labels, "per_roller"), _force_quantity(self.labels, "per_tooth")
        rollers = [internal(lab, lab.split(".")[0]) for lab in index
                   if lab.startswith("per_roller[") and lab.endswith(f"].{q_roller}")] if q_roller else []
        teeth = [internal(lab, lab.split(".")[0]) for lab in index
                 if lab.startswith(f"per_tooth[{PER_TOOTH_ROLLER},") and lab.endswith(f"].{q_tooth}")] if q_tooth else []
        carrier = [internal(lab) for lab in index if lab.startswith("carrier.") and lab.endswith("_n")]
        return self.column(
            self.plot(f"{q_roller}, per roller", rollers, "N") if q_roller else None,
            self.plot(f"{q_tooth}, roller {PER_TOOTH_ROLLER}, per tooth", teeth, "N") if q_tooth else None,
            self.plot("Carrier", carrier, "N"))

    def events_tab(self):
        """The node's events, diagnostics and the actuator's state transitions; None when the bag has none."""
        fl, bag = self.fl, self.bag
        panels = [fl.RawMessagesPanel(title=f"Events ({t})", config=fl.RawMessagesConfig(topic_path=t))
                  for t in bag.topics_of_type("std_msgs/msg/String") if t.endswith("/events")]
        if "/diagnostics" in bag.topics:
            panels.append(fl.DiagnosticsSummaryPanel(title="Diagnostics"))
        states = [fl.StateTransitionsSeries(value=f"{self.il}.data[{self.index[f'actuator.{q}']}]", label=q)
                  for q in ("brake_level", "faults_active", "torque_limited", "mode") if f"actuator.{q}" in self.index]
        if states:
            panels.append(fl.StateTransitionsPanel(title="Actuator states",
                                                   config=fl.StateTransitionsConfig(paths=states, is_synced=True)))
        return self.column(*panels) if panels else None


def _force_quantity(labels: dict, block: str) -> str | None:
    """The force a block's summary plots: the screw-side normal force where the model has it, else its first force."""
    for seg in labels["segments"]:
        if seg["name"] == block and "quantities" in seg:
            forces = [q["name"] for q in seg["quantities"] if q["unit"] == "N"]
            return "screw_normal_force_n" if "screw_normal_force_n" in forces else (forces[0] if forces else None)
    return None


def _stamped(bag: Bag, topic: str) -> bool:
    """Whether `topic`'s messages carry a header (plot them by their stamp, the simulation time)."""
    msg = _first(bag, topic) if topic in bag.topics else None
    return msg is not None and hasattr(msg, "header")


def layout_json(bag: Bag, **options) -> str:
    """The layout as Foxglove's JSON (what File → Import layout reads)."""
    return build_layout(bag, **options).to_json()


def referenced_topics(layout: dict) -> set[str]:
    """Every topic a layout's panels read (message paths, topic paths, user-script inputs), from its JSON."""
    found: set[str] = set()

    def topic_of(path: str) -> str:
        return path.split(".", 1)[0].split("{", 1)[0]

    def walk(node) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k in ("value", "topicPath") and isinstance(v, str) and v.startswith("/"):
                    found.add(topic_of(v))
                else:
                    walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(layout.get("content"))
    return found
