"""The sizes every input is held to, and the one reader of small text files (parameters, studies).

An input decides how much memory and time a command takes: a parameter file, a duration, a
sample count, a resampling rate. Each is checked against the limit here before the work starts
and refused with one line naming the limit, so `/dev/zero` as a parameter file, `--duration 1e12`
or `samples: 1e8` end with exit 2 instead of filling memory. Errors never quote a file's content:
a file given by mistake (a key, a log) is not printed back.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

TEXT_FILE_MAX_BYTES = 1 << 20   # parameter and study files: a full parameter set is ~3 KB
MAX_RUN_STEPS = 10_000_000      # one offline run (prsm-sim run, a study's run): its trajectory is kept in memory
MAX_STUDY_RUNS = 200_000        # runs of one study: each is a spec, a task and a result row
MAX_TABLE_VALUES = 20_000_000   # values of one exported table after resampling (rows × columns)

_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"))


def file_kind(mode: int) -> str:
    """"a FIFO", "a directory", … for a file that is not a regular one; "" for a regular file."""
    return next((name for test, name in _KINDS if test(mode)), "" if stat.S_ISREG(mode) else "not a regular file")


def read_text_file(path, *, what: str, max_bytes: int = TEXT_FILE_MAX_BYTES, error: type[Exception] = ValueError) -> str:
    """The UTF-8 text of a regular file of at most `max_bytes`; `error` (one line, no content quoted) otherwise.

    Opened without blocking (a FIFO would wait for a writer forever) and read up to the limit
    plus one byte, so a file that grows while being read is refused too.
    """
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise error(f"{p}: cannot read {what} ({e.strerror or e})") from None
    try:
        kind = file_kind(os.fstat(fd).st_mode)
        if kind:
            raise error(f"{p}: {kind}, not a {what} (a regular file)")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise error(f"{p}: cannot read {what} ({e.strerror or e})") from None
    finally:
        os.close(fd)
    if len(data) > max_bytes:
        raise error(f"{p}: more than {max_bytes} bytes, the limit for a {what}")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{p}: not UTF-8 text (byte {e.start}); a {what} is YAML text") from None


def run_steps(duration_s: float, dt_s: float, *, error: type[Exception] = ValueError) -> int:
    """Steps of a run of `duration_s` at `dt_s` (both already finite and > 0); `error` above MAX_RUN_STEPS."""
    n = duration_s / dt_s
    if n > MAX_RUN_STEPS:
        raise error(f"duration_s / dt_s = {duration_s!r} / {dt_s!r} = {n:.3g} steps: more than the "
                    f"{MAX_RUN_STEPS} steps a run may take (its trajectory is kept in memory); "
                    "shorten the run or lengthen the step")
    return int(round(n))
