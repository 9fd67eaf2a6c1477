"""Tables of the bag tools as Parquet (pyarrow; `prsm-bag export --format parquet`, fleet reports).

pyarrow comes with the `sweep` extra; without it these writers say so in one line.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from prsm_ros.bag.reader import BagError


def require_pyarrow():
    """pyarrow and pyarrow.parquet, or a BagError saying how to install them."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise BagError("Parquet output needs pyarrow: pip install 'prsm[sweep]' (or use --format csv)") from None
    return pa, pq


def write_parquet(path: Path, columns: list[str], rows) -> None:
    """Rows (lists, time first) as a Parquet table: numeric columns as float64, others as strings.

    Missing trailing cells (a message shorter than the widest one) become nulls, as in the CSV.
    """
    pa, pq = require_pyarrow()
    rows = [list(r) + [None] * (len(columns) - len(r)) for r in rows]
    arrays = []
    for j, _ in enumerate(columns):
        col = [r[j] for r in rows]
        numeric = all(v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)) for v in col)
        if numeric:
            arrays.append(pa.array([math.nan if v is None else float(v) for v in col], type=pa.float64()))
        else:
            arrays.append(pa.array([None if v is None else str(v) for v in col], type=pa.string()))
    write_table(path, pa.Table.from_arrays(arrays, names=list(columns)))


def write_table(path: Path, table) -> None:
    """Write a pyarrow Table atomically (a reader never sees half a file)."""
    _, pq = require_pyarrow()
    tmp = Path(path).with_name(Path(path).name + ".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, path)
