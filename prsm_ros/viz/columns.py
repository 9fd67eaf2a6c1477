"""Columns sent to Rerun in few calls: `BatchedStream` gathers `send_columns` calls into one record batch per index.

Rerun's cost of a batch of steps is per call more than per row: each `send_columns` converts its
arguments in Python and becomes a chunk on the SDK's side, so a batch of the PRSM's ~50 series
entities and ~25 scene entities costs about as much at 40 rows as at 4,000 (`prsm-bench --only
rerun`). `BatchedStream` stands in for a `RecordingStream`: `send_columns` only stores the Arrow
columns, and `flush_columns` sends every entity that shares an index column as one Arrow record
batch (`RecordingStream.send_record_batch`: one Python call, one chunk per entity made by the
SDK), each column carrying its entity path and component in Rerun's column metadata. The file or
viewer holds the same entities, components and rows as one `send_columns` per entity would give.

`scalars_column` builds the `Scalars:scalars` column of a steps × lines table straight from numpy,
instead of `rr.Scalars.columns`' per-call conversion.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

import numpy as np
import pyarrow as pa
import rerun as rr

from prsm_sim.errors import InputError

_INDEX_META = b"index"
_DATA_META = b"data"


class ArrowColumn:
    """The minimal component-batch interface `rr.ComponentColumn` needs around a ready Arrow array."""

    def __init__(self, array: pa.Array) -> None:
        self._array = array

    def as_arrow_array(self) -> pa.Array:
        return self._array


def _column(descriptor: Any, array: pa.Array, rows: int, per_row: int) -> rr.ComponentColumn:
    """A component column of `rows` rows of `per_row` values each, its row offsets given outright
    (what `ComponentColumn.partition` computes from lengths with a cumulative sum)."""
    return rr.ComponentColumn(descriptor, ArrowColumn(array), offsets=np.arange(0, rows * per_row + 1, per_row,
                                                                              dtype=np.int32))


def scalars_column(values: np.ndarray) -> rr.ComponentColumn:
    """`Scalars:scalars` of a steps (× lines) array: one row per step, one scalar per line (float64)."""
    v = np.ascontiguousarray(values, dtype=np.float64)
    per_row = int(np.prod(v.shape[1:], dtype=np.int64))
    return _column(rr.Scalars.descriptor_scalars(), pa.array(v.reshape(-1)), v.shape[0], per_row)


def vectors_column(descriptor: Any, values: np.ndarray, per_row: int | None = None) -> rr.ComponentColumn:
    """A column of float32 vectors (Vec3D, Quaternion, …): `values` is rows × width, or (rows × per_row) ×
    width with `per_row` vectors a row (the arrows of every roller), as Rerun's own conversion gives."""
    v = np.ascontiguousarray(values, dtype=np.float32)
    width = v.shape[-1]
    kind = pa.list_(pa.field("item", pa.float32(), nullable=False), width)
    vectors = len(v.reshape(-1, width))
    per_row = per_row or 1
    return _column(descriptor, pa.FixedSizeListArray.from_arrays(pa.array(v.reshape(-1)), type=kind),
                   vectors // per_row, per_row)


def colors_column(descriptor: Any, rgba: np.ndarray, per_row: int) -> rr.ComponentColumn:
    """A column of colours from RGBA bytes ((rows × per_row) × 4), packed 0xRRGGBBAA as Rerun's `Color` is."""
    c = np.asarray(rgba, dtype=np.uint32).reshape(-1, 4)
    packed = (c[:, 0] << 24) | (c[:, 1] << 16) | (c[:, 2] << 8) | c[:, 3]
    return _column(descriptor, pa.array(packed), len(c) // per_row, per_row)


def _field(name: str, array: pa.Array, meta: dict[bytes, bytes]) -> pa.Field:
    return pa.field(name, array.type, metadata=meta)


class BatchedStream:
    """A `RecordingStream` whose `send_columns` waits for `flush_columns` (module docstring).

    Calls sharing one index (the same `TimeColumn` objects, as a batch's entities do) are sent
    together, at most `columns_per_send` columns a call; everything else (`log`, `flush`,
    `send_blueprint`, …) goes straight to the stream. With `yield_s` > 0 the thread sleeps that long
    after each gathered call and each send: building columns holds the interpreter lock, which a
    1 kHz loop woken on its deadline would otherwise wait for up to the switch interval (5 ms).
    """

    def __init__(self, rec: Any, *, yield_s: float = 0.0, columns_per_send: int = 4) -> None:
        self._rec = rec
        self.yield_s = yield_s
        self.columns_per_send = columns_per_send
        # index objects' ids → (timeline name → Arrow times, [(entity, descriptor, column)], the index objects:
        # held so that their ids stay theirs until the flush)
        self._groups: dict[tuple[int, ...], tuple[dict[str, pa.Array], list[tuple[str, Any, pa.Array]], list]] = {}

    def _yield(self) -> None:
        if self.yield_s > 0:
            time.sleep(self.yield_s)  # a real sleep: sleep(0) lets this thread win the lock back

    def send_columns(self, entity_path: str, indexes: Iterable[Any], columns: Iterable[Any]) -> None:
        indexes = list(indexes)
        key = tuple(id(i) for i in indexes)
        group = self._groups.get(key)
        if group is None:
            group = self._groups[key] = ({i.timeline_name(): i.as_arrow_array() for i in indexes}, [], indexes)
        n = len(next(iter(group[0].values())))
        for c in columns:
            array = c.as_arrow_array()
            if len(array) != n:
                raise InputError(f"{entity_path}: a column of {len(array)} rows beside an index of {n}")
            group[1].append((entity_path, c.component_descriptor(), array))
        self._yield()

    def flush_columns(self) -> None:
        """Send what `send_columns` gathered: record batches of one index each."""
        groups, self._groups = self._groups, {}
        for timelines, comps, _ in groups.values():
            index_fields = [_field(name, a, {b"rerun:kind": _INDEX_META, b"rerun:index_name": name.encode()})
                            for name, a in timelines.items()]
            # an entity's columns stay in one send (one chunk per entity and send)
            sends: list[list[tuple[str, Any, pa.Array]]] = []
            for c in comps:
                if sends and (c[0] == sends[-1][-1][0] or len(sends[-1]) < self.columns_per_send):
                    sends[-1].append(c)
                else:
                    sends.append([c])
            for part in sends:
                fields, arrays = list(index_fields), list(timelines.values())
                for path, d, a in part:
                    fields.append(_field(f"{path}:{d.component}", a, _column_meta(path, d)))
                    arrays.append(a)
                self._rec.send_record_batch(pa.RecordBatch.from_arrays(arrays, schema=pa.schema(fields)))
                self._yield()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._rec, name)


def _column_meta(path: str, d: Any) -> dict[bytes, bytes]:
    """Rerun's column metadata naming a component column's entity and component."""
    meta = {b"rerun:kind": _DATA_META, b"rerun:entity_path": path.encode(), b"rerun:component": d.component.encode()}
    if d.archetype:
        meta[b"rerun:archetype"] = d.archetype.encode()
    if d.component_type:
        meta[b"rerun:component_type"] = d.component_type.encode()
    return meta
