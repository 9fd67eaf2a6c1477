"""`prsm-bag export`: chosen topics to CSV, one column per field, time in seconds.

Columns: `time_s` (the message's log time in s; simulation time for our bags) then every field
of the message flattened to a dotted name: JointState arrays by joint (`screw_joint.position`),
`~/internal_loads` by the labels its latched labels topic gives (`screw_speed_rad_s`,
`per_roller[3].screw_slip_axial_m_s`), stamps (`builtin_interfaces/Time`) as seconds, other arrays
by index (`data[2]`). With `resample_hz` every numeric column is interpolated onto a uniform grid
(linear, or `hold` = zero-order hold, the right choice for commands); text columns are dropped
then. Time ranges are given in seconds from the bag's first message.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import re
from pathlib import Path

import numpy as np

from prsm_ros.bag.reader import Bag, BagError, resolve_topics
from prsm_ros.interface import parse_labels
from prsm_ros.limits import MAX_TABLE_VALUES


def _is_time(obj) -> bool:
    return hasattr(obj, "sec") and hasattr(obj, "nanosec") and len(getattr(obj, "__slots__", ())) == 2


def _fields(obj) -> list[str]:
    return list(getattr(obj, "__slots__", ()))


def flatten(obj, prefix: str, names: list[str], values: list) -> None:
    """Append the dotted names and values of a decoded message's leaves to `names` / `values`."""
    if _is_time(obj):
        names.append(prefix)
        values.append(obj.sec + obj.nanosec * 1e-9)
        return
    keys = _fields(obj)
    if keys and keys[:4] == ["header", "name", "position", "velocity"]:  # sensor_msgs/JointState
        flatten(obj.header, f"{prefix}header.", names, values)
        for i, joint in enumerate(obj.name):
            for attr in ("position", "velocity", "effort"):
                arr = getattr(obj, attr)
                if i < len(arr):
                    names.append(f"{prefix}{joint}.{attr}")
                    values.append(arr[i])
        return
    for key in keys:
        if key == "layout" and "data" in keys:  # MultiArray layout: description, not data
            continue
        v = getattr(obj, key)
        name = f"{prefix}{key}"
        if isinstance(v, (list, tuple, np.ndarray)) or type(v).__name__ == "array":
            for i, item in enumerate(v):
                if _fields(item):
                    flatten(item, f"{name}[{i}].", names, values)
                else:
                    names.append(f"{name}[{i}]")
                    values.append(item)
        elif _fields(v):
            if _is_time(v):
                flatten(v, name, names, values)
            else:
                flatten(v, f"{name}.", names, values)
        else:
            names.append(name)
            values.append(v)


MAX_LAYOUTS = 10_000      # different field lists within one topic (JointStates naming other joints)
MAX_COLUMNS = 1_000_000   # columns of one exported table (the union of its messages' fields)


def _plain(v):
    """A cell value as JSON holds it (numbers, text, booleans, None); anything else as its text."""
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, np.generic):
        return v.item()
    return str(v)


class Table:
    """Columns of one topic: `time_s` then fields (the union of columns if they vary).

    Rows go to an unnamed temporary file as they are decoded (beside the output, gone when the
    table is closed or the process ends), so a table never has to fit in memory to be written as
    CSV: `rows()` streams them back at the full width. `numeric()` and Parquet output build the
    table in memory and refuse, with the figure, one of more than MAX_TABLE_VALUES values.
    """

    def __init__(self, topic: str, spill_dir=None) -> None:
        import tempfile
        self.topic = topic
        self.columns: list[str] = ["time_s"]
        self._index: dict[str, int] = {"time_s": 0}
        self._layouts: dict[tuple, int] = {}
        self._where: list[list[int]] = []  # layout id → column index of each of its values
        self._text: set[int] = set()       # columns whose first value is not a number
        self._typed: set[int] = {0}
        self.count = 0
        self._file = tempfile.TemporaryFile("w+", encoding="utf-8", dir=spill_dir)

    def add(self, time_s: float, names: list[str], values: list) -> None:
        key = tuple(names)
        lid = self._layouts.get(key)
        if lid is None:
            if len(self._layouts) >= MAX_LAYOUTS:
                raise BagError(f"{self.topic}: messages with more than {MAX_LAYOUTS} different field lists; "
                               "export them in parts (--start/--end)")
            where = []
            for n in names:
                k = self._index.get(n)
                if k is None:
                    if len(self.columns) >= MAX_COLUMNS:
                        raise BagError(f"{self.topic}: more than {MAX_COLUMNS} columns")
                    k = self._index[n] = len(self.columns)
                    self.columns.append(n)
                where.append(k)
            lid = self._layouts[key] = len(self._where)
            self._where.append(where)
        plain = [_plain(v) for v in values]
        if len(self._typed) < len(self.columns):
            for k, v in zip(self._where[lid], plain):
                if k not in self._typed and v is not None:
                    self._typed.add(k)
                    if not isinstance(v, (int, float, bool)):
                        self._text.add(k)
        self._file.write(json.dumps([lid, time_s, plain]) + "\n")
        self.count += 1

    def rows(self):
        """Each row at the table's full width (None where a message has no such field), in order."""
        self._file.flush()
        self._file.seek(0)
        width = len(self.columns)
        for line in self._file:
            lid, t, values = json.loads(line)
            row = [None] * width
            row[0] = t
            for k, v in zip(self._where[lid], values):
                row[k] = v
            yield row

    def first_last_time(self) -> tuple[float, float] | None:
        first = last = None
        for row in self.rows():
            first = row[0] if first is None else first
            last = row[0]
        return None if first is None else (first, last)

    def require_memory(self, what: str) -> None:
        """BagError, with the figure, when the table is over MAX_TABLE_VALUES values (built in memory for `what`)."""
        n = self.count * len(self.columns)
        if n > MAX_TABLE_VALUES:
            raise BagError(f"{self.topic}: {self.count} rows × {len(self.columns)} columns = {n} values, more than "
                           f"the {MAX_TABLE_VALUES} {what} may hold in memory; narrow --start/--end"
                           + (" or export CSV without --resample (written as it is read)" if what != "CSV" else ""))

    def numeric(self) -> tuple[list[str], np.ndarray]:
        """Numeric columns (time first) as a float array; missing values are NaN, text columns dropped."""
        keep = [k for k in range(len(self.columns)) if k not in self._text]
        self.require_memory("resampling")
        data = np.full((self.count, len(keep)), np.nan)
        for i, r in enumerate(self.rows()):
            for j, k in enumerate(keep):
                v = r[k]
                if isinstance(v, (int, float)):
                    data[i, j] = float(v)
        return [self.columns[k] for k in keep], data

    def close(self) -> None:
        self._file.close()


def _labels_for(bag: Bag, roles: dict) -> list[str] | None:
    """Element labels of ~/internal_loads from its latched labels topic, None when unavailable."""
    if not roles.get("labels"):
        return None
    for m in bag.messages([roles["labels"]]):
        try:
            return [el["label"] for el in parse_labels(m.msg.data)["elements"]]
        except (ValueError, KeyError, AttributeError):
            return None
    return None


def read_table(bag: Bag, topic: str, start_ns: int | None = None, end_ns: int | None = None, *,
               labels: list[str] | None = None, progress: bool = True, spill_dir=None) -> Table:
    """Decode `topic` into a Table; `labels` names the elements of a Float64MultiArray's data."""
    table = Table(topic, spill_dir)
    try:
        for m in bag.messages([topic], start_ns, end_ns, progress=progress, desc=topic):
            if m.msg is None:
                raise BagError(f"{bag.path.name}: topic {topic} ({m.type or 'no schema'}) cannot be decoded "
                               f"(needs a ros2msg schema and cdr encoding)")
            data = getattr(m.msg, "data", None)
            if labels is not None and isinstance(data, list) and len(data) == len(labels):
                table.add(m.log_time_ns * 1e-9, labels, data)
                continue
            names: list[str] = []
            values: list = []
            flatten(m.msg, "", names, values)
            table.add(m.log_time_ns * 1e-9, names, values)
    except BaseException:
        table.close()
        raise
    return table


def resample(names: list[str], data: np.ndarray, hz: float, method: str = "linear",
             t0: float | None = None, t1: float | None = None) -> np.ndarray:
    """Numeric table (time in column 0) on a uniform grid at `hz` from t0 to t1 (default: its span)."""
    if not (math.isfinite(hz) and hz > 0):
        raise BagError(f"--resample {hz!r}: must be a rate in Hz > 0")
    if method not in ("linear", "hold"):
        raise BagError(f"--method {method!r}: must be linear or hold")
    t = data[:, 0]
    if t.size == 0:
        return np.empty((0, len(names)))
    t0 = t[0] if t0 is None else t0
    t1 = t[-1] if t1 is None else t1
    grid = t0 + np.arange(grid_length(t0, t1, hz, len(names))) / hz
    out = np.empty((grid.size, len(names)))
    out[:, 0] = grid
    if method == "hold":
        k = np.searchsorted(t, grid, side="right") - 1
        valid = k >= 0
        out[:, 1:] = np.nan
        out[valid, 1:] = data[k[valid], 1:]
    else:
        for j in range(1, len(names)):
            col = data[:, j]
            ok = np.isfinite(col)
            out[:, j] = np.interp(grid, t[ok], col[ok], left=np.nan, right=np.nan) if ok.any() else np.nan
    return out


def grid_length(t0: float, t1: float, hz: float, columns: int) -> int:
    """Points of the uniform grid from t0 to t1 at `hz`; BagError when the table would exceed MAX_TABLE_VALUES."""
    n = int(math.floor(max(t1 - t0, 0.0) * hz + 1e-9)) + 1
    if n * max(columns, 1) > MAX_TABLE_VALUES:
        raise BagError(f"--resample {hz:g} Hz over {t1 - t0:.6g} s gives {n} rows × {columns} columns: more than "
                       f"the {MAX_TABLE_VALUES} values export may build; lower the rate or narrow --start/--end")
    return n


# A spreadsheet runs a cell that starts with one of these as a formula (OWASP, "CSV Injection"):
# text cells that do are written behind a single quote. Numbers are written as numbers.
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return "'" + v if v.startswith(FORMULA_START) else v
    return str(v)


def write_csv(path: Path, columns: list[str], rows) -> None:
    """Write rows (lists) under `columns`, through a temporary file renamed into place when complete."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.part")
    try:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow([_fmt(c) for c in columns])
            for r in rows:
                w.writerow([_fmt(v) for v in r] + [""] * (len(columns) - len(r)))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def csv_name(topic: str) -> str:
    """File name for a topic: "/prsm_actuator/nut/wrench" → "prsm_actuator__nut__wrench.csv"."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", topic.strip("/").replace("/", "__")) + ".csv"


MAX_STEM = 150  # characters of a topic's file name before its suffix (file systems allow 255 bytes)


def file_stems(topics: list[str]) -> dict[str, str]:
    """topic → file name stem, distinct for distinct topics: `csv_name`'s, with a digest of the topic
    appended where it would be empty, a dot name, too long, or shared with another topic (`/` and `""`;
    `/a b` and `/a_b`; names differing in case, for case-insensitive file systems)."""
    stems = {t: csv_name(t).removesuffix(".csv") for t in topics}
    taken: dict[str, int] = {}
    for s in stems.values():
        taken[s.lower()] = taken.get(s.lower(), 0) + 1
    out = {}
    for t, s in stems.items():
        if taken[s.lower()] > 1 or not s.strip(".") or len(s) > MAX_STEM:
            s = f"{s[:MAX_STEM] or 'topic'}-{hashlib.sha256(t.encode('utf-8', 'surrogatepass')).hexdigest()[:10]}"
        out[t] = s
    return out


def export(bag: Bag, topics: list[str], out, *, start_s: float | None = None, end_s: float | None = None,
           resample_hz: float | None = None, method: str = "linear", merge: bool = False,
           progress: bool = True, fmt: str = "csv") -> list[Path]:
    """Write CSV (or, with fmt="parquet", Parquet) files; returns their paths.

    `out`: a .csv file for one topic (or with `merge`), else a directory (one file per topic).
    `merge` puts all topics on one resampled grid, columns prefixed with the topic name.
    """
    if not topics:
        raise BagError("export: name at least one topic with -t/--topic; topics in the bag: "
                       + ", ".join(sorted(bag.topics)))
    bag.require_topics(topics)
    if merge and resample_hz is None:
        raise BagError("--merge needs --resample HZ: topics at different times share one grid only after resampling")
    start_ns, end_ns = bag.window_ns(start_s, end_s)
    out = Path(out)
    if fmt not in ("csv", "parquet"):
        raise BagError(f"--format {fmt!r}: must be csv or parquet")
    suffix, write = ".csv", write_csv
    if fmt == "parquet":
        from prsm_ros.bag.parquet import write_parquet as write
        suffix = ".parquet"
    single_file = out.suffix.lower() == suffix
    if single_file and len(topics) > 1 and not merge:
        raise BagError(f"{out}: one {suffix} file holds one topic; give a directory for {len(topics)} topics, or --merge")
    if not single_file:
        out.mkdir(parents=True, exist_ok=True)
    roles = resolve_topics(bag)
    labels = _labels_for(bag, roles)
    spill = out.parent if single_file else out

    def table(topic: str) -> Table:
        lab = labels if topic == roles.get("internal_loads") else None
        return read_table(bag, topic, start_ns, end_ns, labels=lab, progress=progress, spill_dir=spill)

    t0 = None if start_ns is None else start_ns * 1e-9
    t1 = None if end_ns is None else end_ns * 1e-9
    if merge:
        path = out if single_file else out / f"merged{suffix}"
        _export_merged([table(t) for t in topics], path, write, resample_hz, method, t0, t1)
        return [path]
    stems = file_stems(topics)
    written: list[Path] = []
    for topic in topics:  # one table at a time: each is written and closed before the next is read
        path = out if single_file else out / (stems[topic] + suffix)
        tb = table(topic)
        try:
            if resample_hz is not None:
                names, data = tb.numeric()
                write(path, names, resample(names, data, resample_hz, method, t0, t1).tolist() if len(data) else [])
            else:
                if fmt != "csv":
                    tb.require_memory("a Parquet table")
                write(path, tb.columns, tb.rows() if fmt == "csv" else list(tb.rows()))
        finally:
            tb.close()
        written.append(path)
    return written


def _export_merged(tables: list[Table], path: Path, write, resample_hz: float, method: str,
                   t0: float | None, t1: float | None) -> None:
    """Every table resampled onto one grid from t0 to t1 (default: the span of all), columns `topic:field`."""
    try:
        spans = [s for s in (tb.first_last_time() for tb in tables) if s is not None]
        if not spans:
            raise BagError("export: no messages of these topics in the chosen time range")
        t0 = t0 if t0 is not None else min(a for a, _ in spans)
        t1 = t1 if t1 is not None else max(b for _, b in spans)
        grid_length(t0, t1, resample_hz, sum(len(tb.columns) for tb in tables))
        columns, blocks = ["time_s"], []
        for tb in tables:
            names, data = tb.numeric()
            res = resample(names, data, resample_hz, method, t0, t1) if len(data) else None
            grid_len = grid_length(t0, t1, resample_hz, len(names))
            blocks.append(res[:, 1:] if res is not None else np.full((grid_len, len(names) - 1), np.nan))
            columns += [f"{tb.topic}:{n}" for n in names[1:]]
    finally:
        for tb in tables:
            tb.close()
    grid = t0 + np.arange(blocks[0].shape[0]) / resample_hz
    write(path, columns, np.column_stack([grid, *blocks]).tolist())
