"""`prsm-sim envelope`: many envelope cases (prsm_sim.envelope) on Ray, resumable, each failure kept as YAML.

    prsm-sim envelope --runs 100000 -o envelope-out [--address HOST:PORT] [--workers N] [--first-seed S]
    prsm-sim envelope --merge run-a run-b -o merged     # one report of seed ranges run apart
    prsm-sim envelope --seed 31                  # one case, run here: its case and what it broke
    prsm-sim envelope --case envelope-out/failures/seed-31.yaml [--node]   # --node: also through prsm-node

Cases are drawn from consecutive seeds (`case_from_seed`) and run in small batches as Ray tasks (an
embedded Ray on this machine by default, or a cluster by address). Every case run is appended to
OUT/results.jsonl as its batch returns (one JSON line: seed, what it broke, steps, seconds and the digest
of the core it ran on, `physics_digest`), so a
run stopped by Ctrl-C, a reboot or a kill keeps what finished, and the same command run again skips
the seeds already there. Every case that broke an invariant is also written to
OUT/failures/seed-N.yaml: the case itself (plain data), what it broke and the one command that
reproduces it. OUT/summary.json is the report of every result in OUT: seed ranges run into one
directory, or merged from several (`--merge`), report as one.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import time
from pathlib import Path

from prsm_ros.interrupts import interrupt_handled

BATCH = 4  # cases per Ray task: seconds of work, and little lost to a Ctrl-C
RESULTS = "results.jsonl"


@functools.lru_cache(maxsize=1)
def physics_digest() -> str:
    """The first 12 hex digits of the SHA-256 of the prsm_sim package's Python sources as this process imports
    them (paths and bytes, in path order): results of one digest come from one core, so seed ranges run
    apart (other days, other machines) add up to one campaign only where their digests agree."""
    import prsm_sim
    root = Path(prsm_sim.__file__).parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:12]


def _run_batch(seeds: list[int]) -> list[dict]:
    from prsm_sim.envelope import case_from_seed, run_case
    digest = physics_digest()
    out = []
    for s in seeds:
        case = case_from_seed(s)
        t = time.perf_counter()
        r = run_case(case)
        out.append({"seed": s, "violations": r.violations, "steps": r.steps, "seconds": time.perf_counter() - t,
                    "model": case["model"], "interface": case["interface"], "controller": case["controller"],
                    "dt_s": case["dt_s"], "physics": digest})
    return out


def failure_yaml(case: dict, violations: list[str]) -> str:
    """The YAML of a failing case: the case, what it broke, and the command that reproduces it."""
    import yaml
    doc = {"reproduce": f"prsm-sim envelope --seed {case['seed']}",
           "reproduce_on_node": f"prsm-sim envelope --seed {case['seed']} --node", "violations": violations, "case": case}
    return yaml.safe_dump(doc, sort_keys=False)


def read_results(path: Path) -> dict[int, dict]:
    """The results in a results file by seed (the first of a seed kept). A last line cut short by a kill
    mid-write is dropped from the file, so the next append starts on a line of its own."""
    rows: dict[int, dict] = {}
    if not path.exists():
        return rows
    data = path.read_bytes()
    good = 0
    for n, line in enumerate(data.splitlines(keepends=True), 1):
        if not line.endswith(b"\n"):
            break  # a torn last line
        try:
            row = json.loads(line)
            rows.setdefault(int(row["seed"]), row)
        except (ValueError, KeyError, TypeError):
            from prsm_sim.errors import InputError
            raise InputError(f"{path}: line {n} is no envelope result (a JSON object with a seed)") from None
        good += len(line)
    if good < len(data):
        with path.open("r+b") as f:
            f.truncate(good)
    return rows


class _Sink:
    """Where each finished case goes: a line of the results file (flushed and synced), and its failure file."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.file = (out / RESULTS).open("a", encoding="utf-8")
        self.rows: list[dict] = []

    def add(self, row: dict) -> None:
        self.file.write(json.dumps(row) + "\n")
        self.file.flush()
        os.fsync(self.file.fileno())
        self.rows.append(row)
        if row["violations"]:
            _write_failure(self.out, row)

    def close(self) -> None:
        self.file.close()


def _write_failure(out: Path, row: dict) -> None:
    from prsm_sim.envelope import case_from_seed
    fail_dir = out / "failures"
    fail_dir.mkdir(exist_ok=True)
    (fail_dir / f"seed-{row['seed']}.yaml").write_text(failure_yaml(case_from_seed(row["seed"]), row["violations"]),
                                                      encoding="utf-8")


def run_envelope(runs: int, out: Path, *, first_seed: int = 0, address: str | None = None,
                 workers: int | None = None, progress=None) -> dict:
    """Run the cases of seeds first_seed … first_seed + runs − 1 not yet in OUT/results.jsonl on Ray;
    append each result there, write failures and the summary of every result in OUT.

    Ctrl-C stops the run and keeps what finished; the summary then says `interrupted: true`, and
    the same call again goes on where it stopped. `progress(done, total)` is called as batches end,
    counting the seeds of the range done before this call.
    """
    from prsm_ros.ray_runner import connect, disconnect

    out.mkdir(parents=True, exist_ok=True)
    done = read_results(out / RESULTS)
    wanted = range(first_seed, first_seed + runs)
    seeds = [s for s in wanted if s not in done]
    t0 = time.time()
    interrupted = False
    n_workers = 0
    sink = _Sink(out)
    try:
        if progress:
            progress(runs - len(seeds), runs)
        if seeds:
            ray, owned, tmp = connect(address, workers)
            try:
                n_workers = int(ray.cluster_resources().get("CPU", 1))
                _run_batches(ray, seeds, n_workers, sink, runs - len(seeds), runs, progress)
            finally:
                disconnect(ray, owned, tmp)
    except KeyboardInterrupt:
        interrupt_handled()
        interrupted = True
    finally:
        sink.close()
    rows = read_results(out / RESULTS)
    summary = summarize(rows.values())
    left = [s for s in wanted if s not in rows]
    summary.update(requested={"first_seed": first_seed, "runs": runs, "done": runs - len(left)},
                   ran_now=len(sink.rows), workers=n_workers, wall_s=round(time.time() - t0, 1))
    if interrupted:
        summary.update(interrupted=True, next_seed=left[0] if left else None)
    write_summary(out, summary)
    return summary


def _run_batches(ray, seeds: list[int], n_workers: int, sink: _Sink, before: int, total: int, progress) -> None:
    """Run `seeds` in batches as Ray tasks, two per CPU in flight; each result kept as its batch ends."""
    task = ray.remote(_run_batch)
    batches = [seeds[i:i + BATCH] for i in range(0, len(seeds), BATCH)]
    pending: list = []
    next_batch = 0
    while next_batch < len(batches) or pending:
        while next_batch < len(batches) and len(pending) < 2 * n_workers:
            pending.append(task.remote(batches[next_batch]))
            next_batch += 1
        ready, pending = ray.wait(pending, num_returns=1)
        for rows in ray.get(ready):
            for row in rows:
                sink.add(row)
        if progress:
            progress(before + len(sink.rows), total)


def summarize(rows) -> dict:
    """The report of a set of results: counts, steps, CPU time, seed ranges, failures by kind and seed."""
    rows = sorted(rows, key=lambda r: r["seed"])
    failed = [r for r in rows if r["violations"]]
    by_kind: dict[str, int] = {}
    by_model: dict[str, list[int]] = {}
    for r in failed:
        key = r["violations"][0].split(" at t =")[0].split(":")[0][:60]
        by_kind[key] = by_kind.get(key, 0) + 1
        by_model.setdefault(r.get("model", "?"), []).append(r["seed"])
    physics: dict[str, list[list[int]]] = {}
    for r in rows:  # seed ranges by the core they ran on ("?": results written before digests were kept)
        physics.setdefault(r.get("physics", "?"), []).append(r["seed"])
    return {"runs": len(rows), "failed": len(failed), "seed_ranges": _ranges([r["seed"] for r in rows]),
            "physics": {d: _ranges(seeds) for d, seeds in physics.items()},
            "cpu_s": round(sum(r["seconds"] for r in rows), 1), "steps": sum(r["steps"] for r in rows),
            "failures_by_kind": by_kind, "failed_seeds_by_model": by_model, "failed_seeds": [r["seed"] for r in failed][:200]}


def _ranges(seeds: list[int]) -> list[list[int]]:
    """Sorted seeds as [first, last] runs of consecutive seeds."""
    out: list[list[int]] = []
    for s in seeds:
        if out and s == out[-1][1] + 1:
            out[-1][1] = s
        else:
            out.append([s, s])
    return out


def write_summary(out: Path, summary: dict) -> None:
    """OUT/summary.json, replaced whole (never half-written)."""
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2), encoding="utf-8")
    tmp.replace(out / "summary.json")


def merge_results(sources: list[Path], out: Path) -> dict:
    """One report of the results of several envelope directories (seed ranges run apart): their results
    (the first of a seed kept) in OUT/results.jsonl, their failure files, and the summary of them all."""
    from prsm_sim.errors import InputError
    rows: dict[int, dict] = {}
    for src in sources:
        if not (src / RESULTS).is_file():
            raise InputError(f"--merge {src}: no {RESULTS} there (not a prsm-sim envelope output directory)")
        for seed, row in read_results(src / RESULTS).items():
            rows.setdefault(seed, row)
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / (RESULTS + ".tmp")
    tmp.write_text("".join(json.dumps(rows[s]) + "\n" for s in sorted(rows)), encoding="utf-8")
    tmp.replace(out / RESULTS)
    for row in rows.values():
        if row["violations"]:
            _write_failure(out, row)
    summary = summarize(rows.values())
    summary["merged_from"] = [str(s) for s in sources]
    write_summary(out, summary)
    return summary


def run_one(case: dict) -> dict:
    """Run one case here (no Ray): what it broke and its figures."""
    from prsm_sim.envelope import run_case
    r = run_case(case)
    return {"seed": case.get("seed"), "ok": r.ok, "violations": r.violations, "steps": r.steps,
            "max_penetration_m": r.max_penetration_m}
