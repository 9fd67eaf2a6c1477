"""Recordings for the fit from what a bench writes: ROS 2 MCAP bags or CSV/Parquet tables.

Only the motion, the command and the load are read, never a bag's run metadata, internal loads or
ground-truth topics: a bench has none, and a fit that peeked at them would not be a fit.

A source is `PATH` or `PATH@LOAD_N` (a constant nut load in N for a recording without a load signal).
Bags: the screw and nut joints of a `sensor_msgs/JointState` topic (positions; the screw's velocity
when present), the torque command (`std_msgs/Float64`, or the screw joint's effort of a JointState
command topic), the load from `--load-topic` (`std_msgs/Float64`, N). The command in force over the
interval from one joint state to the next is the last one logged at or before the first of them
(a lockstep node logs a command at the step it is applied from). Tables: columns `time_s`,
`screw_torque_nm`, `screw_position_rad`, `nut_position_m`, optionally `screw_speed_rad_s`, `load_n`.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from prsm_sim.errors import InputError
from prsm_sim.identify import Recording

from prsm_ros.interface import NUT_JOINT, SCREW_JOINT, TOPIC_DEFS
from prsm_ros.limits import read_text_file

_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
REQUIRED = ("time_s", "screw_torque_nm", "screw_position_rad", "nut_position_m")
OPTIONAL = ("screw_speed_rad_s", "load_n")
TABLE_SUFFIXES = (".csv", ".parquet")


@dataclass(frozen=True)
class BagTopics:
    """Where a bag's signals are: topic and joint names (defaults: prsm-node's)."""

    joint_states: str = "/" + TOPIC_DEFS["joint_states"].name
    command: str = TOPIC_DEFS["screw_torque"].resolved()
    load: str | None = None
    screw_joint: str = SCREW_JOINT
    nut_joint: str = NUT_JOINT


def parse_source(text: str) -> tuple[Path, float | None]:
    """`PATH` or `PATH@LOAD_N` → (path, constant load in N or None)."""
    path, sep, load = text.rpartition("@")
    if not sep or not path:
        return Path(text), None
    value = float(load) if _NUMBER.fullmatch(load.strip()) else math.nan
    if not math.isfinite(value):
        raise InputError(f"{text}: the part after @ must be a constant load, a finite number of N "
                         "(e.g. bench1.mcap@3000)")
    return Path(path), value


def read_source(text: str, topics: BagTopics | None = None) -> Recording:
    """The recording `text` names (`parse_source`); InputError (one line naming what) when unusable."""
    path, load = parse_source(text)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    if path.suffix.lower() in TABLE_SUFFIXES:
        return read_table(path, load)
    return read_bag(path, load, topics or BagTopics())


def _columns_csv(path: Path) -> dict[str, np.ndarray]:
    text = read_text_file(path, what="recording table", max_bytes=1 << 30, error=InputError)
    rows = list(csv.reader(io.StringIO("\n".join(ln for ln in text.splitlines() if not ln.startswith("#")))))
    if not rows:
        raise InputError(f"{path}: empty table: a header row with {', '.join(REQUIRED)} is needed")
    header = [h.strip() for h in rows[0]]
    cols: dict[str, list[float]] = {h: [] for h in header}
    for k, row in enumerate(rows[1:], 2):
        if len(row) != len(header):
            raise InputError(f"{path}: line {k} has {len(row)} values, the header {len(header)}")
        for h, v in zip(header, row):
            try:
                cols[h].append(float(v))
            except ValueError:
                raise InputError(f"{path}: line {k}, column {h}: {v!r} is not a number") from None
    return {h: np.asarray(v) for h, v in cols.items()}


def _columns_parquet(path: Path) -> dict[str, np.ndarray]:
    import pyarrow.parquet as pq
    try:
        table = pq.read_table(path)
    except Exception as e:  # pyarrow's many error types for a damaged file: one line naming it
        first = str(e).splitlines()[0] if str(e) else ""
        raise InputError(f"{path}: not a readable Parquet file ({type(e).__name__}: {first})") from None
    out = {}
    for name in table.column_names:
        try:
            out[name] = np.asarray(table.column(name).to_numpy(zero_copy_only=False), dtype=float)
        except (TypeError, ValueError):
            if name in REQUIRED + OPTIONAL:
                raise InputError(f"{path}: column {name} is not numeric") from None
    return out


def read_table(path: Path, load: float | None = None) -> Recording:
    """A CSV or Parquet table (module docstring) as a Recording; `load` when it has no `load_n` column."""
    cols = _columns_parquet(path) if path.suffix.lower() == ".parquet" else _columns_csv(path)
    missing = [c for c in REQUIRED if c not in cols]
    if missing:
        raise InputError(f"{path}: no column {', '.join(missing)}; a table needs {', '.join(REQUIRED)} "
                         f"(optional {', '.join(OPTIONAL)})")
    if "load_n" in cols and load is not None:
        raise InputError(f"{path}@{load:g}: the table has a load_n column; give the load one way only")
    if "load_n" not in cols and load is None:
        raise InputError(f"{path}: no load_n column: give the constant load as {path}@LOAD_N")
    return Recording(name=path.name, time_s=cols["time_s"], screw_torque_nm=cols["screw_torque_nm"],
                     screw_position_rad=cols["screw_position_rad"], nut_position_m=cols["nut_position_m"],
                     screw_speed_rad_s=cols.get("screw_speed_rad_s"),
                     load_n=cols["load_n"] if "load_n" in cols else np.full(len(cols["time_s"]), load))


def _joint_rows(msgs, topic: str, joints: tuple[str, str], path: Path):
    """(times s, screw position, nut position, screw speed or None) of a JointState topic's messages."""
    t, th, x, w = [], [], [], []
    has_speed = True
    for m in msgs:
        names = list(m.msg.name)
        try:
            i, j = names.index(joints[0]), names.index(joints[1])
        except ValueError:
            raise InputError(f"{path}: {topic} has joints {', '.join(names) or 'none'}; the fit needs "
                             f"{joints[0]} and {joints[1]} (--screw-joint, --nut-joint)") from None
        pos, vel = list(m.msg.position), list(m.msg.velocity)
        if len(pos) <= max(i, j):
            raise InputError(f"{path}: {topic} at {m.log_time_ns * 1e-9:.6f} s has no position for every joint")
        stamp = m.msg.header.stamp
        t.append(stamp.sec + stamp.nanosec * 1e-9 if (stamp.sec or stamp.nanosec) else m.log_time_ns * 1e-9)
        th.append(pos[i])
        x.append(pos[j])
        has_speed = has_speed and len(vel) > i
        w.append(vel[i] if len(vel) > i else math.nan)
    return np.asarray(t), np.asarray(th), np.asarray(x), (np.asarray(w) if has_speed else None)


def _held(times_ns: list[int], values: list[float], at_ns: np.ndarray, what: str, path: Path) -> np.ndarray:
    """The last value logged at or before each of `at_ns` (zero-order hold)."""
    if not times_ns:
        raise InputError(f"{path}: no {what} message")
    order = np.argsort(np.asarray(times_ns), kind="stable")
    tn, v = np.asarray(times_ns)[order], np.asarray(values, dtype=float)[order]
    k = np.searchsorted(tn, at_ns, side="right") - 1
    return v[np.maximum(k, 0)]


def _scalar(m, screw_joint: str) -> float:
    """A Float64's data, or the screw joint's effort of a JointState command."""
    if hasattr(m.msg, "data"):
        return float(m.msg.data)
    names = list(m.msg.name)
    return float(m.msg.effort[names.index(screw_joint)]) if screw_joint in names and len(m.msg.effort) > \
        names.index(screw_joint) else math.nan


def read_bag(path: Path, load: float | None, topics: BagTopics) -> Recording:
    """An MCAP bag (module docstring) as a Recording; `load` when it has no load topic."""
    from prsm_ros.bag.reader import BagError, open_bag
    try:
        bag = open_bag(path)
        wanted = [topics.joint_states, topics.command] + ([topics.load] if topics.load else [])
        for name, t in zip(("joint states", "command", "load"), wanted):
            if t not in bag.topics:
                raise InputError(f"{path}: no {name} topic {t!r} (topics: {', '.join(sorted(bag.topics)) or 'none'})")
        if topics.load and load is not None:
            raise InputError(f"{path}@{load:g}: --load-topic given too; give the load one way only")
        if not topics.load and load is None:
            raise InputError(f"{path}: no load signal: give the constant load as {path}@LOAD_N or --load-topic")
        js, cmd_t, cmd_v, load_t, load_v = [], [], [], [], []
        for m in bag.messages(wanted, desc=f"reading {path.name}"):
            if m.topic == topics.joint_states:
                js.append(m)
            elif m.topic == topics.command:
                cmd_t.append(m.log_time_ns)
                cmd_v.append(_scalar(m, topics.screw_joint))
            else:
                load_t.append(m.log_time_ns)
                load_v.append(float(m.msg.data))
    except BagError as e:
        raise InputError(str(e)) from None
    if not cmd_t:
        raise InputError(f"{path}: no message on the command topic {topics.command}")
    js = [m for m in js if m.log_time_ns >= min(cmd_t)]  # before the first command the torque is unknown
    if len(js) < 2:
        raise InputError(f"{path}: {len(js)} joint states on {topics.joint_states} after the first command: too short")
    t, th, x, w = _joint_rows(js, topics.joint_states, (topics.screw_joint, topics.nut_joint), path)
    at_ns = np.asarray([m.log_time_ns for m in js])
    u = _held(cmd_t, cmd_v, at_ns, f"command ({topics.command})", path)
    f = _held(load_t, load_v, at_ns, f"load ({topics.load})", path) if topics.load else np.full(len(t), load)
    return Recording(name=path.name, time_s=t, screw_torque_nm=u, screw_position_rad=th, nut_position_m=x,
                     screw_speed_rad_s=w, load_n=f)
