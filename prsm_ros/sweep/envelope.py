"""`prsm-sim envelope`: thousands of envelope cases (prsm_sim.envelope) on Ray, each failure kept as YAML.

    prsm-sim envelope --runs 10000 -o envelope-out [--address HOST:PORT] [--workers N] [--first-seed S]
    prsm-sim envelope --seed 31                  # one case, run here: its case and what it broke
    prsm-sim envelope --case envelope-out/failures/seed-31.yaml [--node]   # --node: also through prsm-node

Cases are drawn from consecutive seeds (`case_from_seed`), run in batches as Ray tasks (an
embedded Ray on this machine by default, or a cluster by address), and every case that breaks an
invariant is written to OUT/failures/seed-N.yaml: the case itself (plain data), what it broke and
the one command that reproduces it. OUT/summary.json holds the counts, the time and the workers.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

BATCH = 25  # cases per Ray task: a task runs for seconds, long enough to amortise its scheduling


def _run_batch(seeds: list[int]) -> list[dict]:
    from prsm_sim.envelope import case_from_seed, run_case
    out = []
    for s in seeds:
        case = case_from_seed(s)
        t = time.perf_counter()
        r = run_case(case)
        out.append({"seed": s, "violations": r.violations, "steps": r.steps, "seconds": time.perf_counter() - t,
                    "model": case["model"], "interface": case["interface"]})
    return out


def failure_yaml(case: dict, violations: list[str]) -> str:
    """The YAML of a failing case: the case, what it broke, and the command that reproduces it."""
    import yaml
    doc = {"reproduce": f"prsm-sim envelope --seed {case['seed']}",
           "reproduce_on_node": f"prsm-sim envelope --seed {case['seed']} --node", "violations": violations, "case": case}
    return yaml.safe_dump(doc, sort_keys=False)


def run_envelope(runs: int, out: Path, *, first_seed: int = 0, address: str | None = None,
                 workers: int | None = None, progress=None) -> dict:
    """Run `runs` cases from `first_seed` on Ray; write failures and the summary under `out`.

    Ctrl-C stops the run and keeps what finished: the failures written so far and a summary with
    `interrupted: true` and `next_seed`, the first seed not run (to go on with `--first-seed`).
    """
    from prsm_ros.ray_runner import connect, disconnect

    out.mkdir(parents=True, exist_ok=True)
    ray, owned, tmp = connect(address, workers)
    t0 = time.time()
    seeds = list(range(first_seed, first_seed + runs))
    done_rows: list[dict] = []
    interrupted = False
    n_workers = 0
    try:
        n_workers = int(ray.cluster_resources().get("CPU", 1))
        _run_batches(ray, seeds, n_workers, out / "failures", done_rows, progress)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        disconnect(ray, owned, tmp)
    failed = [r for r in done_rows if r["violations"]]
    by_kind: dict[str, int] = {}
    for r in failed:
        key = r["violations"][0].split(" at t =")[0].split(":")[0][:60]
        by_kind[key] = by_kind.get(key, 0) + 1
    summary = {"runs": len(done_rows), "failed": len(failed), "first_seed": first_seed, "workers": n_workers,
               "wall_s": round(time.time() - t0, 1), "cpu_s": round(sum(r["seconds"] for r in done_rows), 1),
               "steps": sum(r["steps"] for r in done_rows), "failures_by_kind": by_kind,
               "failed_seeds": [r["seed"] for r in failed][:200]}
    if interrupted:
        ran = {r["seed"] for r in done_rows}
        summary.update(interrupted=True, requested=runs, next_seed=min(s for s in seeds if s not in ran))
    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    return summary


def _run_batches(ray, seeds: list[int], n_workers: int, fail_dir: Path, done_rows: list[dict], progress) -> None:
    """Run `seeds` in batches as Ray tasks, two per CPU in flight; each failure written as its batch ends."""
    from prsm_sim.envelope import case_from_seed
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
                done_rows.append(row)
                if row["violations"]:
                    fail_dir.mkdir(exist_ok=True)
                    (fail_dir / f"seed-{row['seed']}.yaml").write_text(
                        failure_yaml(case_from_seed(row["seed"]), row["violations"]), encoding="utf-8")
        if progress:
            progress(len(done_rows), len(seeds))


def run_one(case: dict) -> dict:
    """Run one case here (no Ray): what it broke and its figures."""
    from prsm_sim.envelope import run_case
    r = run_case(case)
    return {"seed": case.get("seed"), "ok": r.ok, "violations": r.violations, "steps": r.steps,
            "max_penetration_m": r.max_penetration_m}
