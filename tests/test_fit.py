"""prsm_sim.identify and prsm-fit: a hidden plant's parameters recovered within their intervals, what the
data cannot reach reported non-identifiable, bad recordings refused in one line with nothing written.

The hidden plants are recorded by tests/fit_plant.py (a PD hold plus a multisine torque on a Session);
the fit sees only the recording. Sources: the hidden values themselves (the fit must cover them), and
for the unreachable parameters the model's own law: the ideal model's mesh loss is |τ_L|(1/η − 1) with
τ_L = F L/2π, so at zero load the efficiencies act on nothing.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from prsm_sim import preset
from prsm_sim.errors import InputError
from prsm_sim.identify import Recording, fit_recordings, validate
from prsm_ros.fit import cli
from prsm_ros.param_files import load_params_file

from fit_plant import record, write_csv

HIDDEN = {"mass.moved_mass_kg": 80.0, "ideal.efficiency_forward": 0.9, "ideal.efficiency_backward": 0.75}
FREE = ["mass.moved_mass_kg", "ideal.efficiency_forward", "ideal.efficiency_backward"]


@pytest.fixture(scope="module")
def hidden():
    return preset("s30").with_overrides(HIDDEN)


def _covers(entry, value):
    lo, hi = entry["ci95"]
    return lo <= value <= hi


def test_fit_recovers_mass_and_efficiencies_within_their_intervals(hidden):
    recs = [record(hidden, "ideal", load_n=f, duration_s=1.0, seed=i, name=f"L{f:g}")
            for i, f in enumerate((500.0, 5000.0))]
    res = fit_recordings(recs, preset("s30"), "ideal", FREE + ["command.delay_steps"], starts=2)
    for name, value in HIDDEN.items():
        p = res.parameters[name]
        assert p["identifiable"], (name, p)
        assert _covers(p, value), (name, p)
        assert p["ci95"][1] > p["ci95"][0]  # noise-free: the resolution floor keeps a width
        assert abs(p["value"] / value - 1) < 0.01, (name, p)
    assert res.parameters["command.delay_steps"]["value"] == 0
    held = validate(res, record(hidden, "ideal", load_n=2000.0, duration_s=0.5, seed=7, name="held"))
    assert held["rms_nut_position_m"] < 0.1 * held["base"]["rms_nut_position_m"]


def test_what_the_excitation_cannot_reach_is_not_identifiable(hidden):
    """An unloaded run: τ_L = 0, so η and η′ act on nothing (held at the base, flagged); a rigid model's
    recording does not depend on the axial stiffness of a chain it does not have."""
    base = preset("s30")
    rec = record(hidden, "ideal", load_n=0.0, duration_s=0.6, name="unloaded")
    res = fit_recordings([rec], base, "ideal", FREE + ["elastic.housing_stiffness_n_per_m"], starts=1)
    for name in ("ideal.efficiency_forward", "ideal.efficiency_backward", "elastic.housing_stiffness_n_per_m"):
        p = res.parameters[name]
        assert not p["identifiable"] and p["why_not"], (name, p)
        assert p["value"] == p["base"]
    assert res.params.ideal.efficiency_forward == base.ideal.efficiency_forward
    m = res.parameters["mass.moved_mass_kg"]
    assert m["identifiable"] and _covers(m, HIDDEN["mass.moved_mass_kg"])


@pytest.mark.slow
def test_quantised_noisy_csv_intervals_cover_the_hidden_plant(hidden, tmp_path, capsys):
    """4096 counts/rev on the screw, 1 µm of noise on the nut, no speed column: every 95 % interval covers."""
    files = []
    for i, f in enumerate((500.0, 5000.0)):
        rec = record(hidden, "ideal", load_n=f, duration_s=1.5, seed=10 + i, counts_per_rev=4096, nut_noise_m=1e-6,
                     speed=False)
        write_csv(tmp_path / f"run{i}.csv", rec, speed=False)
        files.append(f"{tmp_path / f'run{i}.csv'}@{f:g}")
    held = record(hidden, "ideal", load_n=2000.0, duration_s=0.5, seed=20, counts_per_rev=4096, nut_noise_m=1e-6)
    write_csv(tmp_path / "held.csv", held)
    out = tmp_path / "out"
    rc = cli.main(files + ["--validate", f"{tmp_path / 'held.csv'}@2000", "--model", "ideal", "--serial",
                           "--starts", "1", "--free", *FREE, "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    doc = json.loads((out / "fit.json").read_text())
    for name, value in HIDDEN.items():
        p = doc["parameters"][name]
        assert p["identifiable"] and _covers(p, value), p
    v = doc["validation"]["held.csv"]
    assert v["rms_nut_position_m"] <= 0.5 * v["base"]["rms_nut_position_m"]
    assert set(doc["residual_rms"]) >= {"nut_position_m", "screw_speed_rad_s"}
    params = load_params_file(out / "params.yaml")  # a parameter file like any other
    assert math.isclose(params.mass.moved_mass_kg, doc["parameters"]["mass.moved_mass_kg"]["value"])
    assert {p.name for p in out.iterdir()} == {"params.yaml", "fit.json", "fit_run0.png", "fit_run1.png",
                                                "validate_held.png"}


def _table(tmp_path, name="t.csv", n=200, **change):
    t = np.arange(n) * 1e-3
    cols = {"time_s": t, "screw_torque_nm": np.sin(t * 20), "screw_position_rad": np.sin(t * 20),
            "nut_position_m": 1e-3 * np.sin(t * 20)} | change
    path = tmp_path / name
    with open(path, "w") as f:
        f.write(",".join(cols) + "\n")
        f.writelines(",".join(repr(float(c[k])) for c in cols.values()) + "\n" for k in range(n))
    return path


@pytest.mark.parametrize("change, message", [
    ({"screw_position_rad": None}, "no column screw_position_rad"),
    ({"time_s": np.r_[np.arange(100) * 1e-3, np.arange(100) * 1e-3]}, "time_s goes back"),
    ({"nut_position_m": np.r_[np.zeros(50), np.nan, np.zeros(149)]}, "nut_position_m[50]"),
    ({"screw_position_rad": np.zeros(200)}, "never moves the screw"),
    ({"time_s": np.arange(20) * 1e-3, "screw_torque_nm": np.ones(20), "screw_position_rad": np.arange(20.0),
      "nut_position_m": np.zeros(20)}, "too short"),
])
def test_bad_tables_exit_2_in_one_line_and_write_nothing(tmp_path, capsys, change, message):
    if change.get("screw_position_rad", 0) is None:
        path = tmp_path / "t.csv"
        path.write_text("time_s,screw_torque_nm,nut_position_m\n0,1,0\n")
    else:
        n = len(change["time_s"]) if "time_s" in change else 200
        path = _table(tmp_path, n=n, **change)
    out = tmp_path / "out"
    assert cli.main([f"{path}@100", "--serial", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["t.csv"]


def test_bad_bags_and_sources_exit_2(tmp_path, capsys):
    from pathlib import Path
    bag = Path(__file__).resolve().parents[1] / "bags" / "heavy_load.mcap"
    for argv, message in (([str(bag)], "no load signal"),
                          ([f"{bag}@1", "--command-topic", "/nope"], "no command topic '/nope'"),
                          ([f"{bag}@1", "--screw-joint", "motor"], "the fit needs motor and nut_joint"),
                          ([f"{bag}@x"], "must be a constant load"),
                          ([f"{tmp_path}/none.csv@1"], "no such file")):
        assert cli.main(argv + ["--serial", "-o", str(tmp_path / "out")]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "keep.txt").write_text("x")
    assert cli.main([f"{bag}@1", "--serial", "-o", str(tmp_path / "full")]) == 2
    assert "not an empty folder" in capsys.readouterr().err


def test_recording_refuses_irregular_steps():
    t = np.r_[np.arange(100) * 1e-3, 0.2 + np.arange(100) * 1e-3]
    with pytest.raises(InputError, match="a recording at a fixed step"):
        Recording(name="r", time_s=t, screw_torque_nm=np.ones(200), screw_position_rad=np.linspace(0, 1, 200),
                  nut_position_m=np.zeros(200), load_n=np.zeros(200))


def test_excite_writes_a_bounded_signal(tmp_path, capsys):
    from prsm_ros.fit.excite import main
    out = tmp_path / "ex.csv"
    assert main(["-o", str(out), "--duration", "2", "--amplitude", "3", "--kind", "prbs"]) == 0
    data = np.loadtxt(out, delimiter=",", skiprows=2)
    assert data.shape == (2001, 2) and np.isclose(np.abs(data[:, 1]).max(), 3.0)
    assert main(["-o", str(tmp_path / "no.csv"), "--amplitude", "80"]) == 2  # above the 50 N·m effort limit
    assert "must lie in (0, 50]" in capsys.readouterr().err and not (tmp_path / "no.csv").exists()
    assert cli.main(["excite", "-o", str(tmp_path / "ms.csv"), "--duration", "1"]) == 0


@pytest.mark.slow
def test_ctrl_c_leaves_nothing_and_exits_130(hidden, tmp_path):
    import signal
    import subprocess
    import sys
    import time
    rec = record(hidden, "ideal", load_n=500.0, duration_s=1.0)
    write_csv(tmp_path / "run.csv", rec)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "prsm_ros.fit.cli", f"{tmp_path / 'run.csv'}@500",
                             "--model", "ideal",
                             # starts enough for minutes of fitting: the Ctrl-C lands while it fits, never after
                             "--serial", "--starts", "400", "-o", str(out)], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not any(p.name.startswith(".prsm-fit-") for p in tmp_path.iterdir()):  # the fit has started
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "interrupted; nothing written" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]
