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
# trajectory memory one offline run may hold: a run keeps every step's outputs until it ends, about
# 1.3 kB a step (ideal, jones2016) to 2.9 kB (elastic) on s30, so 10^7 steps would need 12-29 GB
MAX_RUN_BYTES = 4 << 30

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


def run_memory(n_steps: int, bytes_per_step: float, *, error: type[Exception] = ValueError) -> float:
    """The trajectory memory of a run of `n_steps` (bytes); `error`, with the figure, above MAX_RUN_BYTES."""
    need = n_steps * bytes_per_step
    if need > MAX_RUN_BYTES:
        raise error(f"a run of {n_steps} steps holds about {need / 2**30:.1f} GiB of outputs "
                    f"({bytes_per_step:.0f} bytes a step, measured on a short run of this model): more than the "
                    f"{MAX_RUN_BYTES / 2**30:.0f} GiB a run may hold; shorten the run or lengthen the step")
    return need


# ---- YAML and JSON from users and files ----------------------------------------------------------
# Loaded only after a pass over the parser's events (no objects built, no recursion) has bounded
# how deep the document nests and how large it becomes once its aliases are expanded: a 530-byte
# alias bomb expands to gigabytes when anything walks it (json.dumps, a copy, a comparison), and
# PyYAML's composer and json.loads recurse once per level.
YAML_MAX_DEPTH = 64              # nesting of mappings and sequences; a parameter set nests 3 deep
YAML_MAX_EXPANDED = 4_000_000    # nodes plus scalar characters, aliases counted at each use
NODE_PARAMS_MAX_SECTIONS = 256  # node sections in one ROS parameters file (rcl builds every one before the node starts)
JSON_MAX_DEPTH = 64              # labels and events documents in a bag nest 4 deep


def _yaml_weights(events, source: str, error: type[Exception], max_depth: int, max_expanded: int,
                  max_top_keys: int | None) -> None:
    """Walk parser events, refusing depth over `max_depth`, an expanded size over `max_expanded`,
    an alias to an anchor not yet complete (a recursive document) or more than `max_top_keys`
    entries in the top-level mapping."""
    import yaml

    stack: list[list] = []   # open collections: [anchor, weight, entries]
    sizes: dict[str, int] = {}
    total = 0

    def add(weight: int, mark) -> None:
        nonlocal total
        if stack:
            stack[-1][1] += weight
            stack[-1][2] += 1
            if len(stack) == 1 and max_top_keys is not None and stack[0][2] > 2 * max_top_keys:
                raise error(f"{source}: more than {max_top_keys} top-level entries (line {mark.line + 1})")
            if stack[-1][1] > max_expanded:
                raise error(f"{source}: expands to more than {max_expanded} nodes and characters once its "
                            f"aliases are expanded (line {mark.line + 1})")
        else:
            total += weight

    for ev in events:
        mark = ev.start_mark
        if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
            if len(stack) >= max_depth:
                raise error(f"{source}: nested more than {max_depth} levels deep (line {mark.line + 1})")
            stack.append([ev.anchor, 1, 0])
        elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
            anchor, weight, _ = stack.pop()
            if anchor is not None:
                sizes[anchor] = weight
            add(weight, mark)
        elif isinstance(ev, yaml.ScalarEvent):
            weight = 1 + len(ev.value)
            if ev.anchor is not None:
                sizes[ev.anchor] = weight
            add(weight, mark)
        elif isinstance(ev, yaml.AliasEvent):
            if ev.anchor not in sizes:
                raise error(f"{source}: an alias refers to a collection that contains it, or to no anchor "
                            f"(line {mark.line + 1})")
            add(sizes[ev.anchor], mark)


def load_yaml(text: str, *, source: str, error: type[Exception] = ValueError, max_depth: int = YAML_MAX_DEPTH,
              max_expanded: int = YAML_MAX_EXPANDED, max_top_keys: int | None = None):
    """The YAML document in `text` (safe types only), bounded before any object is built.

    `error` (one line naming `source` and the line, never quoting the text) for text that is not
    YAML, nests deeper than `max_depth`, expands past `max_expanded` nodes and characters through
    its aliases, refers to itself, holds more than one document or more than `max_top_keys`
    top-level entries. `text` itself is bounded by whoever read it (`read_text_file`).
    """
    import yaml

    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    try:
        _yaml_weights(yaml.parse(text, Loader=loader), source, error, max_depth, max_expanded, max_top_keys)
        return yaml.load(text, Loader=loader)
    except yaml.YAMLError as e:  # its str() quotes the text: give the place and the kind of problem only
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise error(f"{source}: not valid YAML{where} ({getattr(e, 'problem', None) or type(e).__name__})") from None


def json_depth(text: str) -> int:
    """How deep the arrays and objects of a JSON text nest (brackets inside strings not counted)."""
    import re
    bare = re.sub(r'"(?:[^"\\]|\\.)*"', "", text)
    depth = deepest = 0
    for ch in re.sub(r"[^\[\]{}]", "", bare):
        depth += 1 if ch in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


def load_json(text, *, source: str, error: type[Exception] = ValueError, max_depth: int = JSON_MAX_DEPTH):
    """json.loads of `text` after its nesting is checked; `error` (one line, no content) otherwise."""
    import json
    if isinstance(text, (bytes, bytearray)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as e:
            raise error(f"{source}: not UTF-8 text (byte {e.start})") from None
    if not isinstance(text, str):
        raise error(f"{source}: expected JSON text, got {type(text).__name__}")
    if json_depth(text) > max_depth:
        raise error(f"{source}: JSON nested more than {max_depth} levels deep")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise error(f"{source}: not valid JSON (line {e.lineno}, column {e.colno}: {e.msg})") from None
