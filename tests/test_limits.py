"""Every input bounded: files, durations, sample counts, resampling, time windows, FIFOs.

Each probe used to end in a MemoryError, a ValueError traceback, a hang or (for /dev/zero as a
parameter file) a process growing to 23 GB; each must now be one line naming the limit, exit 2,
and never quote the file it read. The FIFO probes run in a child process with a timeout, so a
regression fails instead of hanging the suite.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from prsm_ros.limits import MAX_RUN_STEPS, MAX_STUDY_RUNS, MAX_TABLE_VALUES, TEXT_FILE_MAX_BYTES

ROOT = Path(__file__).resolve().parent.parent
SECRET = "hunter2-do-not-print"


def _sim(capsys, *args):
    from prsm_ros.cli.sim import main
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr().err


def _sweep(capsys, *args):
    from prsm_ros.cli.sweep import main
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr().err


def _bag(capsys, *args):
    from prsm_ros.cli.bag import main
    rc = main([str(a) for a in args])
    return rc, capsys.readouterr().err


def _one_line(err: str, *expected: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and all(e in lines[0] for e in expected), err
    assert SECRET not in err


def test_parameter_and_study_files_are_regular_bounded_and_never_echoed(tmp_path, capsys):
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * TEXT_FILE_MAX_BYTES + b"\n")
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"preset: s30\ngeometry: {{pitch_m: [oops\n  password: {SECRET}\n")
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"\xff\xfe" + SECRET.encode())
    for path, expected in (("/dev/zero", "a character device"), (big, f"more than {TEXT_FILE_MAX_BYTES} bytes"),
                           (bad, "not valid YAML"), (binary, "not UTF-8"), (tmp_path, "a directory"),
                           (tmp_path / "missing.yaml", "No such file")):
        rc, err = _sim(capsys, "params", "--params", path)
        assert rc == 2, (path, err)
        _one_line(err, str(path), expected)
    study = tmp_path / "study.yaml"
    study.write_text(f"params: {bad.name}\n")
    rc, err = _sweep(capsys, "run", study, "-o", tmp_path / "out")
    assert rc == 2
    _one_line(err, "not valid YAML", "line 3")
    rc, err = _sweep(capsys, "run", "/dev/zero", "-o", tmp_path / "out")
    assert rc == 2
    _one_line(err, "a character device, not a study file")


def test_a_node_params_file_is_bounded_before_rcl_reads_it(tmp_path):
    """Was: a 9 MB params file kept the node from starting for > 100 s (rcl parses it all)."""
    big = tmp_path / "big.yaml"
    big.write_text("prsm_actuator:\n  ros__parameters:\n" + "    # padding\n" * (TEXT_FILE_MAX_BYTES // 12))
    res = subprocess.run([sys.executable, "-m", "prsm_ros.cli.node", "--ros-args", "--params-file", str(big)],
                         capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT), "RERUN": "off"})
    assert res.returncode == 2, res.stderr
    _one_line(res.stderr, f"more than {TEXT_FILE_MAX_BYTES} bytes, the limit for a parameters file")


def test_durations_sample_counts_and_grids_are_bounded(tmp_path, capsys):
    rc, err = _sim(capsys, "run", "--preset", "s30", "--model", "ideal", "--duration", "1e12")
    assert rc == 2
    _one_line(err, f"more than the {MAX_RUN_STEPS} steps")
    rc, err = _sim(capsys, "steady-state", "--preset", "s30", "--model", "fu2018", "--duration", "1e12")
    assert rc == 2
    _one_line(err, f"more than the {MAX_RUN_STEPS} steps")
    for text, expected in (("samples: 100000000\n", f"more than the {MAX_STUDY_RUNS} runs"),
                           ("vary:\n  scenario.load_n: {linspace: [0, 1, 1000000000000]}\n",
                            f"more than the {MAX_STUDY_RUNS} runs"),
                           ("duration_s: 1.0e+12\n", f"more than the {MAX_RUN_STEPS} steps")):
        study = tmp_path / "s.yaml"
        study.write_text(text)
        rc, err = _sweep(capsys, "run", study, "-o", tmp_path / "out")
        assert rc == 2, text
        _one_line(err, expected)
    assert not (tmp_path / "out").exists()


def test_a_run_longer_than_memory_can_hold_is_refused_up_front(capsys):
    """Was: 10^6 ideal steps peaked at 1.24 GB and a 10^7-step run (allowed) ended in numpy's
    MemoryError after 122 s. Oracle: tracemalloc's peak of the same run at two lengths."""
    from prsm_sim import Simulator, preset
    from prsm_sim.scenarios import default_spec, run_scenario

    from prsm_ros.cli.sim import PROBE_STEPS, bytes_per_step
    from prsm_ros.limits import MAX_RUN_BYTES

    p = preset("s30")
    per_step = bytes_per_step(lambda: Simulator(p, "ideal", 1e-3), run_scenario, default_spec(p, "sine-motion"), 1e-3)
    assert 200 < per_step < 20_000  # a step's outputs: tens of float columns, with their row objects
    steps = int(MAX_RUN_BYTES / per_step * 1.5)  # well past the budget, well under MAX_RUN_STEPS
    assert PROBE_STEPS < steps < MAX_RUN_STEPS
    rc, err = _sim(capsys, "run", "--preset", "s30", "--model", "ideal", "--duration", str(steps * 1e-3),
                   "--scenario", "sine-motion")
    assert rc == 2
    _one_line(err, "GiB a run may hold")


def test_export_resampling_and_time_windows_are_bounded(tmp_path, capsys):
    from prsm_sim import Simulator, preset
    from prsm_sim.scenarios import default_spec, run_scenario
    from prsm_ros.mcap.offline import write_trajectory_mcap
    p = preset("s30")
    traj = run_scenario(Simulator(p, "ideal", 1e-3), default_spec(p, "step"), 0.1)
    bag = write_trajectory_mcap(tmp_path / "b.mcap", traj, p, "ideal", preset_name="s30", progress=False)
    rc, err = _bag(capsys, "export", bag, "-t", "/joint_states", "-o", tmp_path / "x.csv", "--resample", "1e10")
    assert rc == 2
    _one_line(err, f"more than the {MAX_TABLE_VALUES} values")
    for flag, v in (("--start", "nan"), ("--end", "inf"), ("--start", "1e300")):
        rc, err = _bag(capsys, "export", bag, "-t", "/joint_states", "-o", tmp_path / "x.csv", flag, v)
        assert rc == 2
        _one_line(err, flag, "must be a finite number of seconds")
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("argv, expected", [
    (["prsm_ros.cli.bag", "info", "{fifo}"], "a FIFO, not an MCAP file"),
    (["prsm_ros.cli.sim", "params", "--params", "{fifo}"], "a FIFO, not a parameter file"),
    (["prsm_ros.cli.sweep", "run", "{fifo}", "-o", "out"], "a FIFO, not a study file"),
    (["prsm_ros.cli.node", "--ros-args", "--params-file", "{fifo}"], "a FIFO, not a parameters file"),
])
def test_a_fifo_is_refused_not_waited_on(tmp_path, argv, expected):
    fifo = tmp_path / "f.mcap"
    os.mkfifo(fifo)
    args = [a.format(fifo=fifo) for a in argv]
    res = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                         env={**os.environ, "PYTHONPATH": str(ROOT), "RERUN": "off"})
    assert res.returncode == 2 and expected in res.stderr and "Traceback" not in res.stderr, res.stderr
