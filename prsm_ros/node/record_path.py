"""Where the node records, never over an existing file, pure Python (several actuators).

Two actuators started in the same second in one directory must not get the same file: the
default name carries the node's namespace and name, and every path is claimed with an exclusive create
(`O_CREAT | O_EXCL`), which the OS makes atomic between processes: a default name that is taken
gets a `_2`, `_3`, ... suffix; a path the user gave that exists is refused, never overwritten.
"""

from __future__ import annotations

import os
import re
from datetime import datetime, timezone
from pathlib import Path

from prsm_sim import PrsmError

MAX_SUFFIX = 1000


class RecordPathError(PrsmError, ValueError):
    """The requested bag path exists (or cannot be created); the message says which and why."""


def default_name(fully_qualified_node_name: str, now: datetime | None = None) -> str:
    """prsm_<namespace and node, '/' → '_'>_<UTC yyyymmdd_HHMMSS>.mcap, e.g. prsm_arm1_prsm_actuator_20261123_170000.mcap."""
    now = now or datetime.now(timezone.utc)
    who = re.sub(r"[^A-Za-z0-9_]+", "_", fully_qualified_node_name.strip("/")) or "node"
    return f"prsm_{who}_{now.strftime('%Y%m%d_%H%M%S')}.mcap"


def _claim(path: Path) -> bool:
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        return False
    os.close(fd)
    return True


def claim_record_path(requested: str, fully_qualified_node_name: str, *, directory: Path | None = None,
                      now: datetime | None = None) -> Path:
    """Create (empty) and return the file this node will record to; the recorder then writes it.

    `requested` '' → a unique default name in `directory` (default: the working directory).
    Raises RecordPathError for a given path that exists, or an OSError's reason in words.
    """
    try:
        if requested:
            path = Path(requested)
            if not _claim(path):
                raise RecordPathError(f"{path} exists; the node never overwrites a recording "
                                      "(choose another record_path, or '' for a unique default name)")
            return path
        base = Path(directory or ".") / default_name(fully_qualified_node_name, now)
        for k in range(1, MAX_SUFFIX + 1):
            path = base if k == 1 else base.with_name(f"{base.stem}_{k}{base.suffix}")
            if _claim(path):
                return path
        raise RecordPathError(f"{base}: {MAX_SUFFIX} recordings of this name already exist")
    except OSError as e:
        raise RecordPathError(f"{requested or base}: {e.strerror or e}") from None
