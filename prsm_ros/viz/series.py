"""Time series of a PRSM run in Rerun, sent column-wise with `send_columns`.

Every scalar output goes to `series/<name>` (one entity per quantity, so each plot has one unit)
and every quantity of the internal loads' (roller, quantity) and (quantity,) blocks to
`series/<block>/<quantity>`, with one line per roller (or one line). Inputs read back from a bag that are not model
outputs (a controller's nut position reference, say) go to `series/inputs/<name>`.

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

TIMELINE = "sim_time"
SERIES_ROOT = "series"
INPUTS_ROOT = f"{SERIES_ROOT}/inputs"
UNITS: dict[str, str] = dict(OUTPUT_FIELDS)


def sim_time_index(time_s: np.ndarray) -> rr.TimeColumn:
    """The `sim_time` index column for step-end times in seconds (rounded to whole nanoseconds)."""
    ns = np.round(np.asarray(time_s, dtype=float) * 1e9).astype(np.int64)
    return rr.TimeColumn(TIMELINE, duration=ns.astype("timedelta64[ns]"))


def scalar_path(name: str) -> str:
    return f"{SERIES_ROOT}/{name}"


def block_path(block: str, quantity: str) -> str:
    return f"{SERIES_ROOT}/{block}/{quantity}"


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
    out = [SeriesEntity(scalar_path(n), UNITS.get(n, ""), (f"{n} [{UNITS.get(n, '?')}]",))
           for n in scalar_names if n != "time_s"]
    for b in series_blocks(layout):
        for q, unit in b.quantities:
            names = (tuple(f"{b.dims[0]} {i}" for i in range(b.shape[0])) if len(b.dims) == 2
                     else (f"{q} [{unit}]",))
            out.append(SeriesEntity(block_path(b.name, q), unit, names))
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
    t = np.asarray(columns["time_s"], dtype=float)
    n = len(t)
    if n == 0:
        return 0
    index = [sim_time_index(t)]
    for name, values in columns.items():
        if name == "time_s":
            continue
        rec.send_columns(scalar_path(name), indexes=index,
                         columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))
    if internal is not None and layout.size:
        internal = np.asarray(internal, dtype=float).reshape(n, layout.size)
        offsets = layout.offsets()
        for b in series_blocks(layout):
            block = internal[:, offsets[b.name]: offsets[b.name] + b.size].reshape((n,) + b.shape)
            for k, (q, _) in enumerate(b.quantities):
                rec.send_columns(block_path(b.name, q), indexes=index,
                                 columns=rr.Scalars.columns(scalars=np.ascontiguousarray(block[..., k])))
    return n


def log_input_style(rec: rr.RecordingStream, name: str, unit: str = "") -> None:
    rec.log(input_path(name), rr.SeriesLines(names=[f"{name} [{unit}]" if unit else name]), static=True)


def send_input(rec: rr.RecordingStream, name: str, time_s: np.ndarray, values: np.ndarray) -> None:
    """A recorded input stream (e.g. a controller's reference) beside the outputs, at its own times."""
    if len(time_s):
        rec.send_columns(input_path(name), indexes=[sim_time_index(time_s)],
                         columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=float)))
