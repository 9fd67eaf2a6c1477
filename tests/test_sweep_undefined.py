"""A study whose finished runs measure nothing says so: how many runs, which metric, and why.

Oracle: runs built to stall. Under the `heavy` scenario's 20 kN the fu2018 screw's speed reference
ramps over 0.1 s and static friction holds the screw for the first 0.05 s (the screw speed stays
0, so no power reaches the load and the efficiency is undefined, NaN, by its definition as power
out over power in); after 0.3 s every run turns and measures an efficiency. No Ray: the runs are
recorded into the study directory here, and `prsm-sweep run` then finds nothing left to run.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

pytest.importorskip("pyarrow")
pytest.importorskip("pandas")

from prsm_ros.cli.sweep import main as sweep_main  # noqa: E402
from prsm_ros.sweep import execute, report, runner, study  # noqa: E402

STUDY = """\
preset: s30
model: fu2018
scenario: heavy
duration_s: {duration}
vary:
  friction.mu_screw_roller: {{values: [0.02, 0.11]}}
metrics: [efficiency, speed_ratio, peak_nut_force_n]
"""


def recorded_study(tmp_path: Path, duration: float) -> tuple[Path, Path, dict]:
    path = tmp_path / "study.yaml"
    path.write_text(STUDY.format(duration=duration), encoding="utf-8")
    _, norm, _ = study.load(str(path))
    out = tmp_path / "out"
    runner.prepare_dir(out, norm)
    specs = study.run_specs(norm)
    (out / runner.PARTS).mkdir()
    runner._record(out, 0, execute.run_batch(norm, specs))
    runner.consolidate(out)
    return path, out, norm


def test_runs_that_measure_nothing_are_counted_with_the_reason(tmp_path, capsys):
    path, out, norm = recorded_study(tmp_path, 0.05)
    rows = runner.recorded_rows(out)
    assert [r["status"] for r in rows] == ["ok", "ok"] and all(math.isnan(r["efficiency"]) for r in rows)
    assert sweep_main(["run", str(path), "-o", str(out)]) == 0  # nothing left to run: no Ray started
    printed = capsys.readouterr().out
    assert "efficiency: NaN in 2 of 2 finished runs: no net power reached the load" in printed
    assert "speed_ratio: NaN in 2 of 2 finished runs: the screw did not turn" in printed
    assert "peak_nut_force_n" not in printed  # it has a value in every run

    r = report.build(out, make_plots=True)
    assert r["undefined"]["efficiency"] == {"runs": 2, "of": 2, "why": execute.UNDEFINED_WHY["efficiency"]}
    txt = report.text(r)
    assert "efficiency: NaN in 2 of 2 finished runs" in txt
    assert "no plots of efficiency, speed_ratio: fewer than 2 runs with a value" in txt
    assert not any("efficiency" in Path(p).name for p in r["plots"])  # no empty or one-point plot
    assert any("peak_nut_force_n" in Path(p).name for p in r["plots"])


def test_a_study_that_runs_long_enough_measures_every_run(tmp_path):
    _, out, norm = recorded_study(tmp_path, 0.3)
    rows = runner.recorded_rows(out)
    assert all(0.0 < r["efficiency"] < 1.0 for r in rows)  # friction loses power, none is created
    assert rows[0]["efficiency"] > rows[1]["efficiency"]  # more screw–roller friction, lower efficiency
    assert execute.undefined(rows, norm["metrics"]) == {}
