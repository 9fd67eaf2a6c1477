"""Run a study on Ray: batches of runs as Ray tasks, results in `DIR/runs.parquet`, resumable.

Ray is the engine (embedded `ray.init()` on this machine by default, or an existing cluster by
address); nothing here schedules work. The driver keeps at most a few tasks per worker in
flight, writes each finished batch at once to `DIR/parts/` (so an interrupted study loses at
most the batches in flight) and folds the parts into `runs.parquet` at the end. A rerun reads
what is there and runs only the rest; the study's hash in `DIR/study.json` makes sure the
directory belongs to this study.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

from prsm_ros.ray_runner import (  # noqa: F401  (public names kept here)
    LOCAL_ONLY_ENV, LOOPBACK, RayUnavailable, connect, disconnect, reachable, start_embedded)
from prsm_ros.sweep import execute
from prsm_ros.sweep.study import StudyError, run_specs, study_hash

RUNS = "runs.parquet"
PARTS = "parts"
TRAJECTORIES = "trajectories"
STUDY_JSON = "study.json"
TASKS_PER_WORKER = 4  # batches per worker for `runs_per_task: auto`: enough to balance, few enough to amortise


def prepare_dir(out: Path, norm: dict, source_text: str | None = None) -> str:
    """Create or reopen the study directory; refuse one that holds anything but this study."""
    h = study_hash(norm)
    marker = out / STUDY_JSON
    if out.exists() and not out.is_dir():
        raise StudyError(f"-o {out}: exists and is not a directory")
    if marker.exists():
        try:
            held = json.loads(marker.read_text(encoding="utf-8")).get("hash")
        except (OSError, ValueError, AttributeError):
            held = None
        if held != h:
            raise StudyError(f"-o {out}: holds another study (hash {held}, this study is {h}); "
                             f"choose another output directory")
        return h
    if out.exists() and any(out.iterdir()):
        raise StudyError(f"-o {out}: not empty and holds no study ({STUDY_JSON} missing); choose another directory")
    out.mkdir(parents=True, exist_ok=True)
    _atomic_write(marker, json.dumps({"hash": h, "study": norm}, indent=2, sort_keys=True))
    if source_text is not None:
        (out / "study.yaml").write_text(source_text, encoding="utf-8")
    return h


def read_study_dir(out: Path) -> tuple[dict, str]:
    """(normalised study, hash) stored in a study directory."""
    try:
        data = json.loads((out / STUDY_JSON).read_text(encoding="utf-8"))
        return data["study"], data["hash"]
    except (OSError, ValueError, KeyError, TypeError):
        raise StudyError(f"{out}: not a study directory ({STUDY_JSON} missing or unreadable)") from None


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _write_table(path: Path, rows: list[dict]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq
    tmp = path.with_name(path.name + ".tmp")
    pq.write_table(pa.Table.from_pylist(rows), tmp)
    os.replace(tmp, path)


def recorded_rows(out: Path) -> list[dict]:
    """Every run recorded so far (runs.parquet and unfolded parts), last record of a run wins."""
    import pyarrow.parquet as pq
    files = ([out / RUNS] if (out / RUNS).exists() else []) + sorted((out / PARTS).glob("*.parquet"))
    by_id: dict[int, dict] = {}
    for f in files:
        for r in pq.read_table(f).to_pylist():
            by_id[int(r["run_id"])] = r
    return [by_id[k] for k in sorted(by_id)]


def consolidate(out: Path) -> int:
    """Fold the parts into runs.parquet (sorted by run_id); returns the number of rows."""
    rows = recorded_rows(out)
    parts = sorted((out / PARTS).glob("*.parquet"))
    if rows:
        _write_table(out / RUNS, rows)
    for f in parts:
        f.unlink()
    if (out / PARTS).exists() and not any((out / PARTS).iterdir()):
        (out / PARTS).rmdir()
    return len(rows)


def batch_size(n_runs: int, workers: int, runs_per_task) -> int:
    if runs_per_task != "auto":
        return int(runs_per_task)
    return max(1, min(64, math.ceil(n_runs / (workers * TASKS_PER_WORKER))))


def run_study(norm: dict, out: Path, *, address: str | None = None, workers: int | None = None,
              runs_per_task="auto", decimate: int | None = None, retry_failed: bool = False,
              progress: bool = True, source_text: str | None = None) -> dict:
    """Run every run of `norm` not yet recorded in `out`; returns counts and the wall time."""
    if address and address != "auto":
        reachable(address)  # before anything is written
    h = prepare_dir(out, norm, source_text)
    specs = run_specs(norm)
    done = {int(r["run_id"]): r["status"] for r in recorded_rows(out)}
    todo = [s for s in specs if s["run_id"] not in done or (retry_failed and done[s["run_id"]] != "ok")]
    summary = {"study": h, "dir": str(out), "runs": len(specs), "skipped": len(specs) - len(todo), "ran": 0,
               "failed": 0, "wall_time_s": 0.0}
    t0 = time.perf_counter()
    if todo:
        ray, owned, tmp = connect(address, workers)
        try:
            _run_batches(ray, owned, norm, out, todo, summary, workers=workers, runs_per_task=runs_per_task,
                         decimate=decimate, progress=progress)
        finally:
            disconnect(ray, owned, tmp)
        summary["wall_time_s"] = time.perf_counter() - t0
    else:
        consolidate(out)
    rows = recorded_rows(out)
    summary["failed"] = sum(1 for r in rows if r["status"] != "ok")
    summary["undefined"] = execute.undefined(rows, norm["metrics"])
    return summary


def _run_batches(ray, owned: bool, norm: dict, out: Path, todo: list[dict], summary: dict, *,
                 workers: int | None, runs_per_task, decimate: int | None, progress: bool) -> None:
    """Run `todo` in batches as Ray tasks, a bounded window in flight, each batch recorded as it ends."""
    n_workers = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
    # --workers N: at most N tasks at once (a cap on a shared cluster too); otherwise two per CPU,
    # so a CPU never waits for the driver to hand it the next batch
    window = workers or 2 * n_workers
    size = batch_size(len(todo), n_workers, runs_per_task)
    queue = [todo[i:i + size] for i in range(0, len(todo), size)]
    task = ray.remote(num_cpus=1)(execute.run_batch)
    norm_ref = ray.put(norm)
    (out / PARTS).mkdir(exist_ok=True)
    from tqdm import tqdm
    bar = tqdm(total=len(todo), unit="run", file=sys.stderr, disable=not progress, desc=f"study {summary['study']}")
    pending: dict = {}
    try:
        while queue or pending:
            while queue and len(pending) < window:  # a bounded window: memory stays flat
                b = queue.pop(0)
                pending[task.remote(norm_ref, b, decimate)] = b
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                batch = pending.pop(ref)
                try:
                    results = ray.get(ref)
                except (ray.exceptions.RayTaskError, ray.exceptions.WorkerCrashedError,
                        ray.exceptions.TaskCancelledError) as e:  # the task died, not a run: its runs failed
                    results = [(execute.failed_row(norm, spec, e), None) for spec in batch]
                _record(out, batch[0]["run_id"], results)
                summary["ran"] += len(results)
                bar.update(len(results))
    finally:
        bar.close()
        if not owned:  # our own embedded Ray ends its workers at shutdown; a shared cluster is asked
            # to stop ours. Never force=True: a batch finishing as its worker is killed makes Ray 2.60's
            # driver abort ("Tried to complete task that was not pending"), losing the exit status.
            for ref in pending:
                ray.cancel(ref)
        consolidate(out)


def _record(out: Path, first_id: int, results: list) -> None:
    """Write one finished batch at once: its rows as a part, its trajectories if kept."""
    _write_table(out / PARTS / f"part-{first_id:08d}.parquet", [row for row, _ in results])
    for row, frame in results:
        if frame is not None:
            d = out / TRAJECTORIES
            d.mkdir(exist_ok=True)
            frame.to_parquet(d / f"run-{row['run_id']:08d}.parquet", index=False)
