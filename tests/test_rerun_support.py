"""Helpers for the Rerun tests (this module holds no tests): the rerun CLI and reading .rrd files back.

Files are checked two ways: the `rerun` CLI (`rrd verify`, `rrd print`, as a user would) and the
SDK's chunk reader (`rerun.chunk.RrdReader`) for the values.
"""

from __future__ import annotations

import re
import subprocess
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import rerun_cli

# The real viewer/CLI binary: the venv's `rerun` script is a Python wrapper that runs it as a
# child, so a signal sent to the wrapper would leave the binary running.
RERUN_BIN = Path(rerun_cli.__file__).parent / "rerun"
_CHUNK = re.compile(r"^Chunk\(\S+\) with (\d+) rows \([^)]*\) - (\S+) - data columns: \[(.*)\]")


def rrd_verify(path) -> subprocess.CompletedProcess:
    return subprocess.run([str(RERUN_BIN), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)


def rrd_rows(path) -> dict[tuple[str, str], int]:
    """(entity, component) → rows holding it, summed over chunks, from `rerun rrd print` (all stores)."""
    res = subprocess.run([str(RERUN_BIN), "rrd", "print", "--continue-on-error=true", str(path)],
                         capture_output=True, text=True, timeout=120)
    rows: dict[tuple[str, str], int] = defaultdict(int)
    for line in res.stdout.splitlines():
        m = _CHUNK.match(line.strip())
        if m:
            for comp in m.group(3).split():
                rows[(m.group(2), comp)] += int(m.group(1))
    return dict(rows)


def entities(rows: dict[tuple[str, str], int]) -> set[str]:
    return {e for e, _ in rows}


def rrd_component(path, entity: str, component: str) -> tuple[np.ndarray, list]:
    """(sim_time ns, values) of one component of one entity, sorted by time, via the SDK reader."""
    from rerun.chunk import RrdReader
    times, values = [], []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path != entity:
            continue
        rb = chunk.to_record_batch()
        if component not in rb.schema.names:
            continue
        col = rb.column(component).to_pylist()
        t = rb.column("sim_time").cast("int64").to_pylist() if "sim_time" in rb.schema.names else [None] * len(col)
        times += t
        values += col
    order = np.argsort(np.array([-1 if t is None else t for t in times]), kind="stable")
    return np.array([times[i] for i in order]), [values[i] for i in order]


def has_blueprint(path) -> bool:
    from rerun.chunk import RrdReader
    return len(RrdReader(path).blueprints()) > 0


@pytest.fixture
def strict_rerun(monkeypatch):
    """Rerun raises on misuse instead of warning, and RERUN=off from the environment is cleared.

    Use with `pytestmark = pytest.mark.usefixtures("strict_rerun")` after importing it.
    """
    import rerun as rr
    monkeypatch.delenv("RERUN", raising=False)
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)
