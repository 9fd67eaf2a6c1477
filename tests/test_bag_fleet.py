"""Fleet analysis of bags (issue 16): many bags → one Parquet table on Ray, group comparison, Parquet export.

The bags are made offline here: the demo's position law (prsm_sim.control) closed around
s30/fu2018 at 1 ms and written with the project's MCAP writer, two "controller versions"
(20 Hz and the demo's 8 Hz bandwidth) over a small spread of plants.
"""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
import tomllib
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from ray_local import embedded_ray  # noqa: F401 (a fixture)

# the slow tier (.ci/run runs it after the README's test command): many node or Ray start-ups
pytestmark = pytest.mark.slow

pytest.importorskip("mcap")
pq = pytest.importorskip("pyarrow.parquet")
pd = pytest.importorskip("pandas")
ray = pytest.importorskip("ray")

from prsm_sim import Simulator, preset  # noqa: E402
from prsm_sim.control import PositionController, run_position_loop, reference  # noqa: E402
from prsm_sim.models.ideal import reflected_inertia  # noqa: E402

from prsm_ros.cli.bag import main as bag_main  # noqa: E402
from prsm_ros.bag.fleet import report_many, expand  # noqa: E402
from prsm_ros.mcap.offline import write_trajectory_mcap  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LOAD_N = 2000.0


def _bag(path: Path, bandwidth_hz: float, mu: float) -> Path:
    nominal = preset("s30")
    p = nominal.with_overrides({"friction.mu_screw_roller": mu})
    sim = Simulator(p, "fu2018", 1e-3)
    ctl = PositionController(reflected_inertia(nominal), nominal.geometry.lead_per_rad_m, bandwidth_hz=bandwidth_hz,
                             load_n=LOAD_N)
    traj, _ = run_position_loop(sim, ctl, 0.6, LOAD_N)
    ref = np.array([reference(t, 0.02, 0.5)[0] for t in traj.time_s])
    return write_trajectory_mcap(path, traj, p, "fu2018", preset_name="s30", progress=False, reference_m=ref)


@pytest.fixture(scope="module")
def groups(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    for name, bw in (("a", 20.0), ("b", 8.0)):
        (root / name / "nested").mkdir(parents=True)
        for i, mu in enumerate((0.03, 0.05, 0.07, 0.09)):
            _bag(root / name / ("nested" if i % 2 else ".") / f"run{i}.mcap", bw, mu)
    (root / "a" / "broken.mcap").write_bytes(b"not an mcap file")  # one unreadable bag in group A
    return root


def _cli(argv) -> tuple[int, str]:
    buf = io.StringIO()
    with redirect_stdout(buf):
        rc = bag_main(argv)
    return rc, buf.getvalue()


def test_fleet_report_on_ray_writes_one_table_matching_single_reports(groups, embedded_ray, tmp_path):
    rc, out = _cli(["report", str(groups / "a"), "-o", str(tmp_path / "fleet"), "--json"])
    assert rc == 0
    s = json.loads(out)
    assert s["engine"] == "ray" and s["bags"] == 5 and s["ok"] == 4 and s["failed"] == 1
    df = pd.read_parquet(tmp_path / "fleet" / "fleet.parquet")
    table = pq.read_table(tmp_path / "fleet" / "fleet.parquet")
    assert len(df) == table.num_rows == 5
    broken = df[df["bag"].str.endswith("broken.mcap")].iloc[0]
    assert broken["status"] == "failed" and "MCAP" in broken["error"]
    # each row is the single-bag report of that bag (same code, run as a Ray task)
    one = sorted(groups.glob("a/run0.mcap"))[0]
    rc, text = _cli(["report", str(one), "-o", str(tmp_path / "one"), "--json", "--no-plots"])
    single = json.loads(text)
    row = df[df["bag"] == str(one)].iloc[0]
    assert row["tracking.rms_error_m"] == single["tracking"]["rms_error_m"]
    assert row["efficiency.forward"] == single["efficiency"]["forward"]
    assert row["life.l10_revolutions"] == single["life"]["l10_revolutions"]
    # the sequential engine (no Ray: `.[bag]` alone) gives the same rows
    seq = report_many(expand(str(groups / "a")), {}, use_ray=False, progress=False)
    for r in seq:
        got = df[df["bag"] == r["bag"]].iloc[0]
        for k, v in r.items():
            if k != "wall_time_s" and isinstance(v, float):
                assert (math.isnan(v) and math.isnan(got[k])) or got[k] == v, k


def test_compare_flags_the_slower_controller_as_a_regression(groups, embedded_ray):
    # the 8 Hz loop tracks the same stroke with several times the 20 Hz loop's error (test_sweep's tuning finds
    # the same trend); the comparison must flag B's tracking error, and not flag the reverse direction
    rc, out = _cli(["compare", str(groups / "a"), str(groups / "b"), "--json"])
    assert rc == 0
    c = json.loads(out)
    assert c["a_failed"] == 1 and c["b_failed"] == 0
    m = c["metrics"]["tracking.rms_error_m"]
    assert m["better"] == "lower" and m["relative_change"] > 1.0 and m["p_value"] < 0.05 and m["regression"]
    assert "tracking.rms_error_m" in c["regressions"] and "tracking.max_error_m" in c["regressions"]
    rc, out = _cli(["compare", str(groups / "b"), str(groups / "a"), "--json"])
    assert not any(r.startswith("tracking.") for r in json.loads(out)["regressions"])
    rc, text = _cli(["compare", str(groups / "a"), str(groups / "b"), "--fail-on-regression"])
    assert rc == 3 and "REGRESSION" in text


def test_export_parquet_matches_csv(tmp_path):
    bag = ROOT / "bags" / "heavy_load.mcap"
    for fmt in ("csv", "parquet"):
        rc, _ = _cli(["export", str(bag), "-t", "/joint_states", "-o", str(tmp_path / fmt), "--format", fmt])
        assert rc == 0
    a = pd.read_csv(tmp_path / "csv" / "joint_states.csv")
    b = pd.read_parquet(tmp_path / "parquet" / "joint_states.parquet")
    assert list(a.columns) == list(b.columns) and len(a) == len(b) > 100
    num = [c for c in a.columns if pd.api.types.is_numeric_dtype(b[c])]
    assert "time_s" in num and len(num) >= 7  # time, positions, velocities, efforts of both joints
    np.testing.assert_array_equal(a[num].to_numpy(float), b[num].to_numpy(float))
    assert pq.read_table(tmp_path / "parquet" / "joint_states.parquet").num_rows == len(a)


def test_bag_tools_stay_free_of_ray():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert not any("ray" in d for d in extras.get("bag", []))
    assert any(d.startswith("ray") for d in extras["sweep"]) and "sweep" in extras["all"][0]
    code = ("import sys, prsm_ros.cli.bag, prsm_ros.bag.fleet, prsm_ros.bag.compare, prsm_ros.bag.parquet; "
            "assert not any(m == 'ray' or m.startswith('ray.') for m in sys.modules), 'ray imported'")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
