"""`bag_to_rrd`: the Rerun scene and series of a recorded MCAP bag (`prsm-bag to-rrd BAG -o FILE.rrd`).

What a bag gives, in order of preference:

1. `…/internal_loads` + `…/internal_loads/labels` (our node, `prsm-sim run --mcap`): every scalar
   output and the internal loads, decoded with `prsm_ros.interface.parse_labels`/`unpack_internal`
   — the same recording `RerunSink` makes live.
2. otherwise `…joint_states` (sensor_msgs/JointState): `screw_joint` and `nut_joint` give the screw
   angle/speed/torque and nut position/velocity/force series and move the screw and the nut in 3D;
   other joints become series `series/inputs/joint_states/<joint>/<position|velocity|effort>`.

Topics are found by `prsm_ros.bag.reader.resolve_topics` (type and name suffix, so a namespaced or
remapped node still converts). The `…/nut_position_reference` input (stamped: at the stamp of the state it
answers; or a plain Float64) is plotted beside the outputs, as the live recording does; the `…/screw_torque`
command is not (it is the applied screw torque, already a series). Other joint names than
`screw_joint` / `nut_joint` are given with `screw_joint=` / `nut_joint=`; when the joint states
name neither, the summary warns that the scene cannot move. Geometry comes from the run metadata
(`prsm_run` parameters_yaml, written by our recorder); a bag without it gets its `preset`, else a schematic
geometry (preset s30), and the summary says so. Time: our bags are stamped with simulation time
and keep it; a foreign bag's `sim_time` is the time since its first message.
"""

from __future__ import annotations

import math
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from prsm_sim import InputError, InternalLayout, ParamError, Params, preset

from prsm_ros.interface import NUT_JOINT, SCREW_JOINT, parse_labels, unpack_internal
from prsm_ros.viz.sink import APPLICATION_ID, RecordingWriter, rerun_forced_off

RUN_METADATA = "prsm_run"
SCHEMATIC_PRESET = "s30"
_JOINT_COLUMNS = {  # joint → (position, velocity, effort) output names
    SCREW_JOINT: ("screw_angle_rad", "screw_speed_rad_s", "screw_torque_nm"),
    NUT_JOINT: ("nut_position_m", "nut_velocity_m_s", "nut_force_n"),
}


def _joint_columns(screw_joint: str, nut_joint: str) -> dict[str, tuple[str, str, str]]:
    """The joints of a bag that names them otherwise → the output names they stand for."""
    return {screw_joint: _JOINT_COLUMNS[SCREW_JOINT], nut_joint: _JOINT_COLUMNS[NUT_JOINT]}
_UNITS = {"nut_position_reference": "m", "screw_torque": "N·m"}


def _params_from(meta: dict[str, str], explicit: Params | None) -> tuple[Params, str]:
    if explicit is not None:
        return explicit, "given by the caller"
    text = meta.get("parameters_yaml")
    if text:
        from prsm_ros.limits import load_yaml
        try:
            return Params.from_dict(load_yaml(text, source="parameters_yaml", error=ParamError)), "bag run metadata"
        except ParamError as e:
            raise InputError(f"bag run metadata {RUN_METADATA}.parameters_yaml is not a valid parameter set: "
                             f"{e}") from None
    if meta.get("preset"):
        try:
            return preset(meta["preset"]), f"preset {meta['preset']} named in the run metadata"
        except ParamError:
            pass
    return preset(SCHEMATIC_PRESET), f"schematic (preset {SCHEMATIC_PRESET}; the bag carries no parameters)"


def _stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class _Conversion:
    """The rows of one bag on their way to a RecordingWriter: collected, batched, sent."""

    def __init__(self, writer: RecordingWriter, source: str, labels: dict | None, scalar_names: list[str],
                 input_topics: set[str], *, ours: bool, batch_rows: int, joints: dict | None = None) -> None:
        self.writer, self.source, self.labels = writer, source, labels
        self.joints = joints if joints is not None else _JOINT_COLUMNS
        self.joints_seen: set[str] = set()
        self.names_seen: set[str] = set()
        self.scalar_names = scalar_names
        self.n_scalar = labels["segments"][0]["size"] if labels else 0
        self.i_time = scalar_names.index("time_s") if labels and "time_s" in scalar_names else None
        self.input_topics = input_topics
        self.batch_rows = batch_rows
        self.t0_ns = 0 if ours else None
        self.rows: list[tuple[float, Any]] = []
        self.inputs: dict[str, tuple[list[float], list[float], str]] = {}
        self.t_span = [math.inf, -math.inf]

    def sim_time(self, t_ns: int) -> float:
        """Seconds: our bags keep their simulation time; a foreign bag's starts at its first message
        (subtracted in integer ns: wall-clock epoch stamps do not survive a float subtraction)."""
        if self.t0_ns is None:
            self.t0_ns = t_ns
        return (t_ns - self.t0_ns) * 1e-9

    def take(self, m) -> None:
        """One decoded bag message (prsm_ros.bag.reader.BagMessage)."""
        msg = m.msg
        if m.topic in self.input_topics:
            name = m.topic.rstrip("/").rsplit("/", 1)[-1]
            if hasattr(msg, "header"):  # a stamped reference: at the state it answers, the nut joint's position
                names = list(msg.name)
                k = names.index(NUT_JOINT) if NUT_JOINT in names else 0
                value = float(msg.position[k]) if len(msg.position) > k else math.nan
                self._input(name, self.sim_time(_stamp_ns(msg)), value)
            else:
                self._input(name, self.sim_time(m.log_time_ns), float(msg.data))
            return
        if self.source == "internal_loads":
            row = np.asarray(msg.data, dtype=float)
            t = float(row[self.i_time]) if self.i_time is not None else self.sim_time(m.log_time_ns)
        else:
            stamped = msg.header.stamp.sec or msg.header.stamp.nanosec
            t = self.sim_time(_stamp_ns(msg) if stamped else m.log_time_ns)
            row = {}
            for k, name in enumerate(msg.name):
                vals = [seq[k] if k < len(seq) else math.nan for seq in (msg.position, msg.velocity, msg.effort)]
                self.names_seen.add(name)
                if name in self.joints:
                    self.joints_seen.add(name)
                    row.update(zip(self.joints[name], vals, strict=True))
                else:
                    for field, v in zip(("position", "velocity", "effort"), vals, strict=True):
                        self._input(f"joint_states/{name}/{field}", t, v)
        self.rows.append((t, row))
        self.t_span = [min(self.t_span[0], t), max(self.t_span[1], t)]
        if len(self.rows) >= self.batch_rows:
            self.flush()

    def _input(self, name: str, t: float, v: float) -> None:
        ts, vs, _ = self.inputs.setdefault(name, ([], [], _UNITS.get(name, "")))
        ts.append(t)
        vs.append(v)

    def flush(self) -> None:
        if not self.rows:
            return
        t = np.array([r[0] for r in self.rows])
        if self.source == "internal_loads":
            data = np.asarray([r[1] for r in self.rows], dtype=float)
            cols = unpack_internal(data, self.labels)
            columns = {n: cols[n] for n in self.scalar_names}
            columns["time_s"] = t  # the row's own time_s, else its log time
            self.writer.send(columns, data[:, self.n_scalar:])
        else:
            columns = {"time_s": t}
            for name in self.scalar_names[1:]:
                vals = np.array([r[1].get(name, math.nan) for r in self.rows])
                if not np.all(np.isnan(vals)):
                    columns[name] = vals
            self.writer.send(columns, None)
        self.rows = []

    def finish(self) -> None:
        self.flush()
        for name, (ts, vs, unit) in self.inputs.items():
            self.writer.send_input(name, np.array(ts), np.array(vs), unit)


def bag_to_rrd(bag, rrd_path, *, progress: bool = True, params: Params | None = None,
               scene_rate_hz: float = 30.0, batch_rows: int = 20_000, screw_joint: str = SCREW_JOINT,
               nut_joint: str = NUT_JOINT, topics: dict[str, str | None] | None = None) -> dict[str, Any]:
    """Convert a recorded MCAP bag into an .rrd with the default blueprint; returns a summary dict.

    Summary keys: bag, rrd, source ("internal_loads" | "joint_states"), model, geometry, rows,
    scene_frames, duration_s, topics (used), inputs, warnings (what the conversion could not do),
    notes (what reading the bag recovered or skipped: an unfinished file, malformed messages; the
    `Bag`'s own notes, so a caller that prints those itself leaves this key out).
    `bag`: a path, opened with `prsm_ros.bag.reader` (so an unfinished recording converts as far as
    it goes), or an open `Bag`; a bag that cannot be used raises its `BagError`, an unusable output
    (or RERUN=off in the environment, which would make the SDK write nothing) ValueError, and a
    conversion that fails half-way removes its partial output.
    """
    from prsm_ros.bag.reader import Bag, open_bag, resolve_topics

    if rerun_forced_off():  # the SDK would silently write nothing
        raise InputError("the environment variable RERUN=off turns the Rerun SDK off, so no .rrd can be written; "
                         "unset it for this command")
    out = Path(rrd_path)
    if not out.parent.is_dir():
        raise InputError(f"output directory {str(out.parent)!r} does not exist")
    if not isinstance(bag, Bag):
        bag = open_bag(bag)
    if out.resolve() == bag.path.resolve():
        raise InputError(f"output {str(out)!r} would overwrite the bag")
    warnings: list[str] = []
    roles = resolve_topics(bag, topics)
    src = _source(bag, roles, warnings)
    run_params, geometry = _params_from(bag.run_metadata, params)
    # the reference only: the recorded torque command is the applied screw torque, plotted once
    input_topics = {roles["reference"]} if roles["reference"] else set()
    used_topics = [src["data_topic"], *sorted(input_topics)]
    writer, conv = _write(out, bag, src, run_params, input_topics, used_topics, progress=progress,
                          scene_rate_hz=scene_rate_hz, batch_rows=batch_rows,
                          joints=_joint_columns(screw_joint, nut_joint))
    warnings += _conversion_warnings(writer, conv, src, screw_joint, nut_joint)
    used = ([roles["labels"]] if src["labels"] is not None else []) + used_topics
    return {"bag": str(bag.path), "rrd": str(out), "source": src["source"], "model": src["model"],
            "geometry": geometry, "rows": writer.rows, "scene_frames": writer.scene_frames,
            "duration_s": conv.t_span[1] - conv.t_span[0] if writer.rows else 0.0, "topics": used,
            "inputs": list(writer.inputs), "warnings": warnings, "notes": [*bag.notes, *bag.reading_notes()]}


def _source(bag, roles: dict, warnings: list[str]) -> dict[str, Any]:
    """What the conversion reads: internal loads with their labels, else the joint states."""
    labels = None
    if roles["internal_loads"] and roles["labels"]:
        for m in bag.messages([roles["labels"]]):
            labels = parse_labels(m.msg.data)
            break
    elif roles["internal_loads"]:
        warnings.append(f"{roles['internal_loads']} has no labels topic beside it: read the joint states instead")
    if labels is not None:
        return {"source": "internal_loads", "data_topic": roles["internal_loads"], "labels": labels,
                "layout": labels["layout_obj"], "model": labels["model"],
                "scalar_names": [e["label"] for e in labels["elements"][: labels["segments"][0]["size"]]]}
    if roles["joint_states"]:
        return {"source": "joint_states", "data_topic": roles["joint_states"], "labels": None,
                "layout": InternalLayout(blocks=()), "model": bag.run_metadata.get("model"),
                "scalar_names": ["time_s"] + [c for cols in _JOINT_COLUMNS.values() for c in cols]}
    raise InputError(f"{bag.path.name}: nothing to convert — no …/internal_loads with labels and no joint "
                     f"states topic (topics: {', '.join(sorted(bag.topics)) or 'none'})")


def _write(out: Path, bag, src: dict, run_params: Params, input_topics: set[str], topics: list[str], *,
           progress: bool, scene_rate_hz: float, batch_rows: int, joints: dict) -> tuple[RecordingWriter, _Conversion]:
    """The recording: static scene, every message of `topics`, the blueprint; no half-written file on failure."""
    import rerun as rr

    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.save(out)
    try:
        model = src["model"]
        rec.send_recording_name(f"{bag.path.name} · {model or 'unknown model'}")
        writer = RecordingWriter(rec, run_params, src["layout"], model or "unknown", scalar_names=src["scalar_names"],
                                 scene_rate_hz=scene_rate_hz)
        writer.log_static()
        conv = _Conversion(writer, src["source"], src["labels"], src["scalar_names"], input_topics,
                           ours=src["labels"] is not None or bool(bag.run_metadata), batch_rows=batch_rows,
                           joints=joints)
        for m in bag.messages(topics, progress=progress, desc=f"to-rrd {bag.path.name}"):
            conv.take(m)
        conv.finish()
        writer.send_blueprint()
        rec.flush(timeout_sec=60.0)
        rec.disconnect()
    except BaseException:  # a bag that fails to decode half-way, Ctrl-C: leave no half-written .rrd behind
        rec.disconnect()
        out.unlink(missing_ok=True)
        raise
    return writer, conv


def _conversion_warnings(writer: RecordingWriter, conv: _Conversion, src: dict, screw_joint: str,
                         nut_joint: str) -> list[str]:
    if writer.rows == 0:
        return [f"{src['data_topic']} has no messages: the recording holds only the static scene"]
    if src["source"] == "joint_states" and conv.joints_seen != {screw_joint, nut_joint}:
        missing = sorted({screw_joint, nut_joint} - conv.joints_seen)
        return [f"{src['data_topic']} has no joint {' or '.join(repr(j) for j in missing)} (its joints: "
                f"{', '.join(sorted(conv.names_seen)) or 'none'}): the scene does not move with it; "
                "name the joints with --screw-joint / --nut-joint"]
    return []
