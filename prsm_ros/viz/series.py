"""Time series of a PRSM run in Rerun, sent column-wise with `send_columns`.

Every scalar output goes to `series/<name>` (one entity per quantity, so each plot has one unit)
and every quantity of the internal loads' (roller, quantity) and (quantity,) blocks to
`series/<block>/<quantity>`, with one line per roller (or one line). Inputs read back from a bag that are not model
outputs (a controller's nut position reference, say) go to `series/inputs/<name>`.

Units follow `prsm-bag report`: lengths in mm (`nut_position_mm`, the reference, deflections) and slip
speeds in mm/s (`slip_speed_mm_s`, `…_slip_…_mm_s`), so a figure and the viewer read the same numbers;
the entity name carries the unit shown (`shown`). The 3D scene stays in metres (REP 103).

All rows carry the `sim_time` timeline: a duration, the simulation time of the step's end, in
integer nanoseconds rounded like `prsm_ros.messages.time_ns`, so a bag and a live run of the same
steps land on the same instants. Nothing here logs one value per call: a batch of steps is one
`send_columns` call per entity.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
import rerun as rr

from prsm_sim import OUTPUT_FIELDS, InternalBlock, InternalLayout

from prsm_ros.viz.columns import scalars_column

TIMELINE = "sim_time"
SERIES_ROOT = "series"
INPUTS_ROOT = f"{SERIES_ROOT}/inputs"
UNITS: dict[str, str] = dict(OUTPUT_FIELDS)


def shown(name: str, unit: str) -> tuple[str, str, float]:
    """(entity name, unit, scale) a quantity is shown with: m → mm, a slip's m/s → mm/s, else as it is."""
    if unit == "m" and name.endswith("_m"):
        return name[:-2] + "_mm", "mm", 1e3
    if unit == "m/s" and "slip" in name and name.endswith("_m_s"):
        return name[:-4] + "_mm_s", "mm/s", 1e3
    return name, unit, 1.0


def sim_time_index(time_s: np.ndarray) -> rr.TimeColumn:
    """The `sim_time` index column for step-end times in seconds (rounded to whole nanoseconds)."""
    ns = np.round(np.asarray(time_s, dtype=float) * 1e9).astype(np.int64)
    return rr.TimeColumn(TIMELINE, duration=ns.astype("timedelta64[ns]"))


def scalar_path(name: str) -> str:
    """The entity of a scalar output (by its OUTPUT_FIELDS name), in the unit it is shown with."""
    return f"{SERIES_ROOT}/{shown(name, UNITS.get(name, ''))[0]}"


def block_path(block: str, quantity: str, unit: str = "") -> str:
    return f"{SERIES_ROOT}/{block}/{shown(quantity, unit)[0]}"


def input_path(name: str) -> str:
    return f"{INPUTS_ROOT}/{name}"


def series_blocks(layout: InternalLayout) -> list[InternalBlock]:
    """Blocks that plot as time series: (quantity,) — one line per quantity — and (<index>, quantity),
    e.g. (roller, quantity) — one line per roller. Larger blocks (roller × tooth) are heat maps."""
    return [b for b in layout.blocks if b.dims[-1] == "quantity" and len(b.dims) <= 2]


@dataclass(frozen=True)
class SeriesEntity:
    """One plotted entity: its path, the unit of its values and the legend name of each series."""

    path: str
    unit: str
    names: tuple[str, ...]


def series_entities(scalar_names: Iterable[str], layout: InternalLayout) -> list[SeriesEntity]:
    """What `send_series` writes for these scalar columns and this layout (time_s is the index, not a series)."""
    out = []
    for n in scalar_names:
        if n != "time_s":
            name, unit, _ = shown(n, UNITS.get(n, ""))
            out.append(SeriesEntity(scalar_path(n), unit, (f"{name} [{unit or '?'}]",)))
    for b in series_blocks(layout):
        for q, unit in b.quantities:
            name, shown_unit, _ = shown(q, unit)
            names = (tuple(f"{b.dims[0]} {i}" for i in range(b.shape[0])) if len(b.dims) == 2
                     else (f"{name} [{shown_unit}]",))
            out.append(SeriesEntity(block_path(b.name, q, unit), shown_unit, names))
    return out


def log_series_styles(rec: rr.RecordingStream, entities: Iterable[SeriesEntity]) -> None:
    """Legend names, static: the viewer shows `nut_force_n [N]` and `roller 3` instead of entity paths."""
    for e in entities:
        rec.log(e.path, rr.SeriesLines(names=list(e.names)), static=True)


def send_series(rec: rr.RecordingStream, columns: Mapping[str, np.ndarray], internal: np.ndarray | None,
                layout: InternalLayout) -> int:
    """Send a batch of steps: `columns` maps OUTPUT_FIELDS names (a subset is fine) to 1-D arrays with
    `time_s` among them; `internal` is steps × layout.size (or None when the source has none).

    Returns the number of rows sent per entity.
    """
    n = send_scalars(rec, columns)
    if n:
        send_blocks(rec, columns["time_s"], internal, layout)
    return n


def send_scalars(rec: rr.RecordingStream, columns: Mapping[str, np.ndarray]) -> int:
    """The scalar outputs of a batch of steps (`send_series` without the internal loads); returns its rows."""
    t = np.asarray(columns["time_s"], dtype=float)
    n = len(t)
    if n == 0:
        return 0
    index = [sim_time_index(t)]
    for name, values in columns.items():
        if name == "time_s":
            continue
        scale = shown(name, UNITS.get(name, ""))[2]
        rec.send_columns(scalar_path(name), indexes=index, columns=[scalars_column(np.asarray(values) * scale)])
    return n


def send_blocks(rec: rr.RecordingStream, time_s: np.ndarray, internal: np.ndarray | None,
                layout: InternalLayout) -> None:
    """The internal loads' series (`series_blocks`) of a batch of steps ending at `time_s`, s."""
    n = len(time_s)
    if internal is None or not layout.size or n == 0:
        return
    index = [sim_time_index(np.asarray(time_s, dtype=float))]
    internal = np.asarray(internal, dtype=float).reshape(n, layout.size)
    offsets = layout.offsets()
    for b in series_blocks(layout):
        block = internal[:, offsets[b.name]: offsets[b.name] + b.size].reshape((n,) + b.shape)
        for k, (q, unit) in enumerate(b.quantities):
            scale = shown(q, unit)[2]
            rec.send_columns(block_path(b.name, q, unit), indexes=index,
                             columns=[scalars_column(block[..., k] * scale)])


def log_input_style(rec: rr.RecordingStream, name: str, unit: str = "") -> None:
    """The legend of an input, in the unit it is shown with (a reference in m is shown in mm)."""
    unit = shown(name + "_m", unit)[1] if unit == "m" else unit
    rec.log(input_path(name), rr.SeriesLines(names=[f"{name} [{unit}]" if unit else name]), static=True)


def send_input(rec: rr.RecordingStream, name: str, time_s: np.ndarray, values: np.ndarray, unit: str = "") -> None:
    """A recorded input stream (e.g. a controller's reference) beside the outputs, at its own times."""
    scale = 1e3 if unit == "m" else 1.0
    if len(time_s):
        rec.send_columns(input_path(name), indexes=[sim_time_index(time_s)],
                         columns=[scalars_column(np.asarray(values, dtype=float) * scale)])
