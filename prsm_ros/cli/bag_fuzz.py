"""Fuzzing `prsm-bag`: mutated copies of the shipped bags through every verb, under a memory limit.

    python -m prsm_ros.cli.bag_fuzz --cases 5000 [--seed 1] [--verbs info,check,...] [--memory-mib 2048]
                                [--timeout-s 60] [--keep DIR] [--plots] [BAG ...]

Each case applies one to four mutations (`apply`) to a bag (default: bags/*.mcap) and runs every
verb on it in a forked child whose address space may grow by --memory-mib beyond what the warm
worker has mapped (`resource.setrlimit`, RLIMIT_AS); the timeout is per verb. A verb must
end with exit 0, or exit 2 with one error line; a Python exception out of `main` (a traceback),
a MemoryError, a child killed by a signal or still running at the timeout is a failure. `repair`
must keep at least as many messages as the mcap library's stream reader reads from the same
file's data section (validating CRCs; it stops at the first damaged record; messages on a channel
no Channel record declared have no topic and are not counted), counted in the repaired file by
the mcap library's reader. The figures are printed at the end; failing inputs
are copied to --keep. The regression test (tests/test_bag_fuzz.py) drives `apply` with hypothesis.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import random
import resource
import shutil
import signal
import struct
import sys
import tempfile
import time
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

from prsm_sim.errors import InputError

from prsm_ros.interrupts import interrupt_handled

KINDS = ("flip", "set64", "set32", "truncate", "zero", "dup", "header")
# values a damaged length, size, count or offset takes
EDGE_VALUES = (0, 1, 0x7F, 0xFF, 0xFFFF, 2**31 - 1, 2**31, 2**32 - 1, 2**40, 2**62, 2**63 - 1, 2**64 - 1)
VERBS = ("info", "check", "export", "report", "layout", "repair", "play", "to-rrd")
DEFAULT_MEMORY_MIB = 2048
DEFAULT_TIMEOUT_S = 120.0
ROOT = Path(__file__).resolve().parents[2]


def record_starts(data: bytes) -> list[int]:
    """Offsets of the top-level records (opcode, length) the file's framing leads to."""
    out, pos = [], 8
    while pos + 9 <= len(data) and len(out) < 100_000:
        out.append(pos)
        _, length = struct.unpack_from("<BQ", data, pos)
        if length > len(data):
            break
        pos += 9 + length
    return out


def apply(data: bytes, ops) -> bytes:
    """`data` with each (kind, where, value) of `ops` applied in turn; `where` and `value` are any
    non-negative integers, folded into the file's size (and, for "header", onto a record's first
    48 bytes: opcode, length and the first fields)."""
    buf = bytearray(data)
    for kind, where, value in ops:
        if not buf:
            break
        if kind == "header":
            starts = record_starts(bytes(buf)) or [0]
            pos = starts[where % len(starts)] + (value >> 8) % 48
            kind, value = ("set64", EDGE_VALUES[value % len(EDGE_VALUES)]) if value & 1 else ("flip", value >> 1)
        else:
            pos = where % len(buf)
        if kind == "flip":
            if pos < len(buf):
                buf[pos] ^= (value % 255) + 1
        elif kind in ("set64", "set32"):
            width = 8 if kind == "set64" else 4
            v = value if value < 2**64 else EDGE_VALUES[value % len(EDGE_VALUES)]
            buf[pos:pos + width] = (v % 2 ** (8 * width)).to_bytes(width, "little")[: max(0, len(buf) - pos)]
        elif kind == "truncate":
            del buf[pos:]
        elif kind == "zero":
            n = 1 + value % 4096
            buf[pos:pos + n] = bytes(len(buf[pos:pos + n]))
        elif kind == "dup":
            n = 1 + value % 65536
            buf[pos:pos] = buf[pos:pos + n]
    return bytes(buf)


def random_ops(rng: random.Random) -> list[tuple[str, int, int]]:
    return [(rng.choice(KINDS), rng.getrandbits(32), rng.choice((rng.getrandbits(64), rng.choice(EDGE_VALUES),
                                                                 rng.getrandbits(8))))
            for _ in range(rng.randint(1, 4))]


def stream_count(path) -> int:
    """Messages the mcap library's stream reader reads from the data section (CRCs checked) before
    its first error, counting those on a channel a Channel record declared before them (what its
    non-seeking reader yields; it stops at the first other one): the lower bound for `repair`."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader
    n = 0
    channels: set[int] = set()
    try:
        with open(path, "rb") as f:
            for rec in StreamReader(f, validate_crcs=True, record_size_limit=64 << 20).records:
                if isinstance(rec, Channel):
                    channels.add(rec.id)
                elif isinstance(rec, Message) and rec.channel_id in channels:
                    n += 1
    except Exception:  # its first error ends its reading, whatever the error
        pass
    return n


def repaired_count(path) -> int:
    """Messages in a repaired file, read by the mcap library's reader through its summary."""
    from mcap.reader import make_reader
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def verb_args(verb: str, bag: Path, work: Path, topics: list[str], plots: bool) -> list[str]:
    out = work / verb
    if verb == "info":
        return ["info", str(bag), "--json", "--no-check"]
    if verb == "check":
        return ["info", str(bag), "--json", "--check"]
    if verb == "export":
        return ["export", str(bag), *[a for t in topics for a in ("-t", t)], "-o", str(out)]
    if verb == "report":
        return ["report", str(bag), "-o", str(out), *([] if plots else ["--no-plots"])]
    if verb == "layout":
        return ["layout", str(bag), "-o", str(out) + ".json"]
    if verb == "repair":
        return ["repair", str(bag), str(out) + ".mcap"]
    if verb == "play":
        return ["play", str(bag), "--rate", "1e6", "--delay", "0", "--no-clock"]
    if verb == "to-rrd":
        return ["to-rrd", str(bag), "-o", str(out) + ".rrd"]
    raise InputError(f"verbs: unknown verb {verb!r}; allowed: {', '.join(VERBS)}")


def _run_verb(argv: list[str]) -> dict:
    """One verb in this process: its exit status, error lines, and the exception that escaped, if any."""
    from prsm_ros.cli.bag import main
    out, err = io.StringIO(), io.StringIO()
    outcome: dict = {}
    try:
        with redirect_stdout(out), redirect_stderr(err):
            outcome["rc"] = main(argv)
    except MemoryError:
        outcome["failure"] = "out of memory (MemoryError)"
    except BaseException as e:  # anything escaping main is what the user would see as a traceback
        outcome["failure"] = f"traceback: {type(e).__name__}: {str(e)[:160]}"
    errors = [ln for ln in err.getvalue().splitlines() if ln.startswith(f"prsm-bag {argv[0]}: error:")]
    rc = outcome.get("rc")
    if "failure" not in outcome and (rc not in (0, 2) or (rc == 2 and len(errors) != 1) or "Traceback" in err.getvalue()):
        outcome["failure"] = f"exit {rc} with {len(errors)} error line(s): {err.getvalue()[-200:]!r}"
    return outcome


def _mapped_bytes() -> int:
    """This process's address space (VmSize): the libraries it has mapped count against RLIMIT_AS."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            return next(int(ln.split()[1]) << 10 for ln in f if ln.startswith("VmSize:"))
    except (OSError, StopIteration, ValueError):
        return 0


def _child(bag: Path, work: Path, verbs, topics, plots: bool, memory_bytes: int, results: Path) -> None:
    limit = _mapped_bytes() + memory_bytes  # memory_bytes beyond what the warm worker has mapped already
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    with open(results, "a", encoding="utf-8") as log:
        def put(d: dict) -> None:
            log.write(json.dumps(d) + "\n")
            log.flush()
        put({"stream_count": stream_count(bag)})
        for verb in verbs:
            put({"start": verb})
            outcome = _run_verb(verb_args(verb, bag, work, topics, plots))
            if verb == "repair" and outcome.get("rc") == 0:
                outcome["kept"] = repaired_count(work / "repair.mcap")
            put({"verb": verb, **outcome})


def _wait(pid: int, results: Path, timeout_s: float):
    """The child's wait status, or "timeout" after killing its group when a verb ran past `timeout_s`."""
    deadline = time.monotonic() + timeout_s
    status = None
    seen_bytes = 0
    while status is None:
        done, st = os.waitpid(pid, os.WNOHANG)
        grown = results.stat().st_size if results.exists() else 0
        if grown != seen_bytes:  # a verb started or ended: the timeout is per verb
            seen_bytes, deadline = grown, time.monotonic() + timeout_s
        if done:
            status = st
        elif time.monotonic() > deadline:
            os.killpg(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            status = "timeout"
        else:
            time.sleep(0.02)
    return status


def run_case(bag: Path, work: Path, verbs, topics, *, plots: bool = False, memory_bytes: int,
             timeout_s: float) -> dict:
    """Run `verbs` on `bag` in a forked child; verb → failure text (absent for a verb that passed).

    Call it from a process that has not started rclpy or Ray (imported is fine): a fork copies the
    locks their threads hold (a DDS participant's, Ray's) but not the threads, so `play`'s rclpy
    could wait in the child for ever. The fuzzer's own process starts neither; a test runs its
    cases in a spawned worker.
    """
    results = work / "results.jsonl"
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:  # the child: never returns into the caller
        code = 0
        try:
            os.setpgid(0, 0)
            _child(bag, work, verbs, topics, plots, memory_bytes, results)
        except BaseException:
            code = 3
        finally:
            os._exit(code)
    status = _wait(pid, results, timeout_s)
    lines = [json.loads(ln) for ln in results.read_text(encoding="utf-8").splitlines()] if results.exists() else []
    failures: dict[str, str] = {}
    floor = next((d["stream_count"] for d in lines if "stream_count" in d), None)
    seen = set()
    for d in lines:
        if "verb" in d:
            seen.add(d["verb"])
            if "failure" in d:
                failures[d["verb"]] = d["failure"]
            if d["verb"] == "repair" and floor is not None and d.get("rc") == 0 and d.get("kept", 0) < floor:
                failures["repair"] = f"kept {d.get('kept')} message(s), the stream reader reads {floor}"
    started = [d["start"] for d in lines if "start" in d]
    if status == "timeout":
        failures[started[-1] if started else "start"] = f"hang (still running after {timeout_s:g} s)"
    elif os.WIFSIGNALED(status):
        failures[started[-1] if started else "start"] = f"killed by signal {os.WTERMSIG(status)}"
    elif started and started[-1] not in seen:
        failures[started[-1]] = f"the child ended during the verb (exit {os.WEXITSTATUS(status)})"
    return failures


EXPORT_TYPES = ("sensor_msgs/msg/JointState", "std_msgs/msg/Float64MultiArray", "std_msgs/msg/String")


def export_topics(bag) -> list[str]:
    """The topics `export` is run on: one of each type that holds arrays, text or labels (EXPORT_TYPES)."""
    chosen = {}
    for name, info in sorted(bag.topics.items()):
        if info.type in EXPORT_TYPES:
            chosen.setdefault(info.type, name)
    return sorted(chosen.values()) or sorted(bag.topics)[:1]


def available_verbs(verbs) -> list[str]:
    """`verbs` without those whose optional dependency is missing (play: rclpy; to-rrd: rerun)."""
    import importlib.util
    need = {"play": "rclpy", "to-rrd": "rerun"}
    return [v for v in verbs if v not in need or importlib.util.find_spec(need[v]) is not None]


def preload(verbs) -> None:
    """Import what the verbs use before forking, so each child starts warm."""
    import mcap.reader  # noqa: F401
    import mcap_ros2.decoder  # noqa: F401
    import numpy  # noqa: F401

    import prsm_ros.bag.export  # noqa: F401
    import prsm_ros.bag.report  # noqa: F401
    import prsm_ros.bag.repair  # noqa: F401
    if "play" in verbs:
        import prsm_ros.bag.play  # noqa: F401
        import rclpy  # noqa: F401
    if "to-rrd" in verbs:
        # what a conversion imports on first use (2-3 s a child otherwise): Rerun and the views, pandas
        # (Rerun's first log), scipy.optimize (the scene's contact points)
        import pandas  # noqa: F401
        import rerun  # noqa: F401
        import scipy.optimize  # noqa: F401

        import prsm_ros.viz.blueprint  # noqa: F401
        import prsm_ros.viz.columns  # noqa: F401
        import prsm_ros.viz.from_bag  # noqa: F401
        import prsm_ros.viz.scene  # noqa: F401
        import prsm_ros.viz.series  # noqa: F401
    if "layout" in verbs:
        import prsm_ros.bag.foxglove_layout  # noqa: F401


def fuzz(bags: list[Path], cases: int, *, seed: int = 1, verbs=VERBS, memory_mib: int = DEFAULT_MEMORY_MIB,
         timeout_s: float = DEFAULT_TIMEOUT_S, plots: bool = False, keep: Path | None = None,
         progress: bool = True) -> dict:
    """Run `cases` random cases; returns the figures (cases, runs, failures by verb, examples)."""
    from prsm_ros.bag.reader import open_bag
    verbs = available_verbs(verbs)
    preload(verbs)
    rng = random.Random(seed)
    originals = [(p, p.read_bytes(), export_topics(open_bag(p))) for p in bags]
    failures: list[dict] = []
    t0 = time.monotonic()
    done = 0
    try:
        done = _cases(originals, cases, rng, verbs, failures, t0, memory_mib=memory_mib, timeout_s=timeout_s,
                      plots=plots, keep=keep, progress=progress)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM: the figures of the cases run so far
        interrupt_handled()
        done = len(_DONE)
    by_verb: dict[str, int] = {}
    for f in failures:
        for v in f["failures"]:
            by_verb[v] = by_verb.get(v, 0) + 1
    return {"cases": done, "verbs": verbs, "runs": done * len(verbs), "failing_cases": len(failures),
            "failures_by_verb": by_verb, "memory_mib": memory_mib, "timeout_s": timeout_s,
            "wall_s": round(time.monotonic() - t0, 1), "examples": failures[:20]}


_DONE: list[int] = []


def _cases(originals, cases: int, rng, verbs, failures: list, t0: float, *, memory_mib: int, timeout_s: float,
           plots: bool, keep: Path | None, progress: bool) -> int:
    _DONE.clear()
    for case in range(cases):
        path, data, topics = originals[case % len(originals)]
        ops = random_ops(rng)
        with tempfile.TemporaryDirectory(prefix="prsm-fuzz-") as d:
            work = Path(d)
            bag = work / path.name
            bag.write_bytes(apply(data, ops))
            found = run_case(bag, work, verbs, topics, plots=plots, memory_bytes=memory_mib << 20,
                             timeout_s=timeout_s)
            if found:
                failures.append({"case": case, "bag": path.name, "ops": ops, "failures": found})
                if keep is not None:
                    keep.mkdir(parents=True, exist_ok=True)
                    shutil.copy(bag, keep / f"case{case}_{path.name}")
        _DONE.append(case)
        if progress and (case + 1) % 50 == 0:
            print(f"{case + 1}/{cases} cases, {len(failures)} failing, {time.monotonic() - t0:.0f} s"
                  + (f"; last failure: {json.dumps(failures[-1], default=str)[:300]}" if failures else ""),
                  file=sys.stderr, flush=True)
    return cases


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m prsm_ros.cli.bag_fuzz", description=__doc__.split("\n\n")[0])
    ap.add_argument("bags", nargs="*", type=Path, help="bags to mutate (default: the shipped bags/*.mcap)")
    ap.add_argument("--cases", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--verbs", default=",".join(VERBS), help=f"comma-separated (default {','.join(VERBS)})")
    ap.add_argument("--memory-mib", type=int, default=DEFAULT_MEMORY_MIB,
                    help="address space a case may add to the warm worker's")
    ap.add_argument("--timeout-s", type=float, default=DEFAULT_TIMEOUT_S, help="a verb running longer is a hang")
    ap.add_argument("--plots", action="store_true", help="report draws its plots (slower)")
    ap.add_argument("--keep", type=Path, help="copy failing inputs here")
    args = ap.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")  # play's publishers stay on this host
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # stopped: print the figures so far
    bags = args.bags or sorted((ROOT / "bags").glob("*.mcap"))
    verbs = [v for v in args.verbs.split(",") if v]
    unknown = [v for v in verbs if v not in VERBS]
    if not bags or unknown or args.cases < 1:
        print(f"fuzz: error: {'unknown verb ' + unknown[0] if unknown else 'no bags' if not bags else '--cases < 1'}",
              file=sys.stderr)
        return 2
    r = fuzz(bags, args.cases, seed=args.seed, verbs=verbs, memory_mib=args.memory_mib, timeout_s=args.timeout_s,
             plots=args.plots, keep=args.keep)
    print(json.dumps(r, indent=1, default=str))
    return 1 if r["failing_cases"] else 0


if __name__ == "__main__":
    sys.exit(main())
