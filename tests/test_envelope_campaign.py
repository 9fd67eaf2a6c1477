"""`prsm-sim envelope` as a long campaign: each result kept as it lands, Ctrl-C keeps what finished (exit 130),
the same command resumes (skipping the seeds done), seed ranges run apart merge into one report."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from prsm_ros.cli import sim
from prsm_ros.sweep import envelope


class _FakeRay:
    def cluster_resources(self):
        return {"CPU": 1}


def _row(seed: int, broken: bool = False) -> dict:
    return {"seed": seed, "violations": ["a broken invariant at t = 0.1 s"] if broken else [], "steps": 10,
            "seconds": 0.01, "model": "ideal", "interface": "effort", "controller": "hold", "dt_s": 1e-3}


@pytest.fixture
def fake_ray(monkeypatch):
    monkeypatch.setattr("prsm_ros.ray_runner.connect", lambda address, workers: (_FakeRay(), True, None))
    monkeypatch.setattr("prsm_ros.ray_runner.disconnect", lambda ray, owned, tmp: None)


def test_ctrl_c_keeps_the_results_and_the_same_command_resumes(tmp_path, monkeypatch, capsys, fake_ray):
    """Interrupted after two cases: they stay (one a failure file), exit 130 names the seed it goes on from; the
    same command runs only the seeds not done, and the summary reports all ten."""
    asked: list[list[int]] = []

    def two_cases_then_ctrl_c(ray, seeds, n_workers, sink, before, total, progress):
        asked.append(list(seeds))
        sink.add(envelope._run_batch(seeds[:1])[0])
        sink.add(_row(seeds[2], broken=True))
        raise KeyboardInterrupt

    monkeypatch.setattr(envelope, "_run_batches", two_cases_then_ctrl_c)
    argv = ["envelope", "--runs", "10", "--first-seed", "100", "-o", str(tmp_path), "--no-progress"]
    with pytest.raises(SystemExit) as e:
        sim.main(argv)
    assert e.value.code == 130
    err = capsys.readouterr().err
    assert "prsm-sim: interrupted: 2 of 10 runs done, 1 of the 2" in err and "goes on from seed 101" in err
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["interrupted"] and summary["runs"] == 2 and summary["next_seed"] == 101
    assert (tmp_path / "failures" / "seed-102.yaml").is_file()

    def the_rest(ray, seeds, n_workers, sink, before, total, progress):
        asked.append(list(seeds))
        for s in seeds:
            sink.add(_row(s))

    monkeypatch.setattr(envelope, "_run_batches", the_rest)
    assert sim.main([*argv, "--json"]) == 0
    assert asked[1] == [101, *range(103, 110)]  # the seeds done are skipped
    summary = json.loads(capsys.readouterr().out)
    assert summary["runs"] == 10 and summary["failed"] == 1 and summary["failed_seeds"] == [102]
    assert summary["seed_ranges"] == [[100, 109]] and "interrupted" not in summary


def test_a_torn_last_line_is_dropped_and_seed_ranges_merge(tmp_path, capsys):
    """A kill mid-write leaves a partial line: it is dropped (that case runs again). Two directories of
    seed ranges run apart merge into one report, their failures with them."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "results.jsonl").write_text("".join(json.dumps(_row(s, broken=s == 3)) + "\n" for s in range(5))
                                     + '{"seed": 5, "viol', encoding="utf-8")
    (b / "results.jsonl").write_text("".join(json.dumps(_row(s)) + "\n" for s in range(5, 9)), encoding="utf-8")
    assert sorted(envelope.read_results(a / "results.jsonl")) == list(range(5))
    assert (a / "results.jsonl").read_text().endswith("\n")
    assert sim.main(["envelope", "--merge", str(a), str(b), "-o", str(tmp_path / "m"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["runs"] == 9 and summary["seed_ranges"] == [[0, 8]] and summary["failed_seeds"] == [3]
    assert (tmp_path / "m" / "failures" / "seed-3.yaml").is_file()
    assert sim.main(["envelope", "--merge", str(tmp_path / "none"), "-o", str(tmp_path / "m")]) == 2
    assert "no results.jsonl there" in capsys.readouterr().err


@pytest.mark.slow
def test_a_tiny_campaign_on_ray_interrupted_and_resumed(tmp_path):
    """The real thing: Ray on loopback, one worker; SIGINT once a result has landed → exit 130 and the results
    kept; the same command finishes the range; every seed once, the report merged."""
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "prsm_ros.cli.sim", "envelope", "--runs", "8", "--first-seed", "2", "--workers", "1",
           "-o", str(out), "--no-progress"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    results = out / "results.jsonl"
    deadline = time.monotonic() + 300
    while not (results.is_file() and results.read_text().count("\n") >= 1):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "no result within 300 s"
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    kept = envelope.read_results(results)
    if proc.returncode == 130:  # else the run finished before the signal landed
        assert "goes on from seed" in err and 1 <= len(kept) < 8
    r = subprocess.run(cmd + ["--json"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["runs"] == 8 and summary["seed_ranges"] == [[2, 9]]
    assert summary["requested"]["done"] == 8 and summary["ran_now"] == 8 - len(kept)
    lines = results.read_text().splitlines()
    assert sorted(json.loads(x)["seed"] for x in lines) == list(range(2, 10))


@pytest.mark.parametrize("args,expect", [
    (["--seed", "3", "--runs", "5"], "--runs: --seed/--case run one case here"),
    (["--seed", "3", "--merge", "x"], "--merge: --seed/--case run one case here"),
    (["--merge", "x", "--first-seed", "7"], "--first-seed: --merge runs nothing"),
])
def test_options_a_mode_does_not_take_are_refused(args, expect, tmp_path, capsys):
    assert sim.main(["envelope", *args, "-o", str(tmp_path)]) == 2
    assert expect in capsys.readouterr().err


def test_each_result_names_the_core_it_ran_on_and_the_report_splits_ranges_by_it(tmp_path, capsys):
    """Oracle: hashlib over the package's sources, recomputed here; a source byte changed (a copy of the package)
    gives another digest. Seed ranges run on two cores merge into one report that says which ran on which."""
    import hashlib
    import shutil
    from pathlib import Path

    import prsm_sim
    root = Path(prsm_sim.__file__).parent
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes() + b"\0")
    digest = envelope.physics_digest()
    assert digest == h.hexdigest()[:12]
    assert envelope._run_batch([5])[0]["physics"] == digest
    copy = tmp_path / "pkg" / "prsm_sim"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("__pycache__"))
    (copy / "envelope.py").write_text((root / "envelope.py").read_text(encoding="utf-8") + "\n", encoding="utf-8")
    r = subprocess.run([sys.executable, "-c", "from prsm_ros.sweep.envelope import physics_digest as d; print(d())"],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path,
                       env={**os.environ, "PYTHONPATH": f"{tmp_path / 'pkg'}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"})
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() not in ("", digest)
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    (a / "results.jsonl").write_text("".join(json.dumps({**_row(s), "physics": digest}) + "\n" for s in range(4)),
                                     encoding="utf-8")
    (b / "results.jsonl").write_text("".join(json.dumps({**_row(s), "physics": "0123456789ab"}) + "\n"
                                             for s in range(4, 6)), encoding="utf-8")
    assert sim.main(["envelope", "--merge", str(a), str(b), "-o", str(tmp_path / "m")]) == 0
    assert f"mixed cores: {digest}: 4 runs, 0123456789ab: 2 runs" in capsys.readouterr().out
    summary = json.loads((tmp_path / "m" / "summary.json").read_text())
    assert summary["physics"] == {digest: [[0, 3]], "0123456789ab": [[4, 5]]}


def test_the_kept_campaign_results_ran_each_seed_once_on_one_core_with_nothing_broken():
    """The results kept in docs/validation/data (docs/studies.md says how they were made and how a run goes on
    from them), read here with gzip and json alone: each file's cases ran on the core its name gives, each seed
    once, within the campaign's range, no invariant broken. The command's own report (`summarize`) agrees."""
    import gzip
    from pathlib import Path

    kept = sorted((Path(__file__).resolve().parent.parent / "docs" / "validation" / "data").glob("envelope-*.jsonl.gz"))
    assert kept, "no campaign results kept"
    for path in kept:
        digest = path.name.removeprefix("envelope-").removesuffix(".jsonl.gz")
        with gzip.open(path, "rt", encoding="utf-8") as f:
            rows = [json.loads(line) for line in f]
        seeds = sorted(r["seed"] for r in rows)
        assert len(set(seeds)) == len(seeds), f"{path.name}: a seed kept twice"
        assert {r["physics"] for r in rows} == {digest}, path.name
        assert [r["seed"] for r in rows if r["violations"]] == [], path.name
        assert 0 <= seeds[0] and seeds[-1] < 100_000, f"{path.name}: seeds {seeds[0]}..{seeds[-1]}"
        report = envelope.summarize(rows)
        assert (report["runs"], report["failed"], report["physics"]) == (len(rows), 0, {digest: report["seed_ranges"]})
