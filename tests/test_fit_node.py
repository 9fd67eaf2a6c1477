"""prsm-fit on prsm-node recordings (the slow tier): the full identification loop, and the starts on Ray.

The hidden plant is another screw size than the base's friction came from (a 39 × 6 catalogue-style
row) with its own moved mass, screw–roller friction and seal drag; `prsm-node` runs it in lockstep
while `prsm-ctl play` sends a multisine around a PID hold at two constant loads, and a chirp at a
third load is held out. The base is `prsm-sim params --datasheet` of the row's geometry without
efficiencies or no-load torque. Pass criteria are the issue's: the fitted plant's `prsm-sim
datasheet` η and η′ within 0.02 of the hidden plant's and its no-load torque within 15 %, the moved
mass within 10 %, and on the held-out run the fitted plant's RMS nut-position error at most half
the base's. The hidden values are the reference: nothing here is fitted to them.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from prsm_sim import preset
from prsm_sim.datasheet import model_datasheet
from prsm_ros.cli import ctl
from prsm_ros.fit import cli
from prsm_ros.fit.excite import main as excite
from prsm_ros.param_files import load_params_file

from ros_procs import CEILING_FACTOR, NodeProcess, RosClient, ros_test_env
from ray_local import embedded_ray  # noqa: F401  (fixture)

pytestmark = pytest.mark.slow

ENV = ros_test_env("test_fit_node")
SHEET = """nominal_diameter_m: 0.039
lead_m: 0.006
starts: 6
nut_length_m: 0.08
nut_outer_diameter_m: 0.08
dynamic_load_rating_n: 150000
static_load_rating_n: 300000
"""
HIDDEN = {"mass.moved_mass_kg": 120.0, "friction.mu_screw_roller": 0.08, "drag.enabled": True,
          "drag.seal_friction_n_per_m": 70.0}
LOADS = (1500.0, 6000.0)
HELD_LOAD = 3000.0


def _physics(params) -> dict:
    """The node's physics.* parameters that differ from its s30 preset's."""
    mine, s30 = params.to_dict(), preset("s30").to_dict()
    return {f"physics.{g}.{k}": v for g, d in mine.items() if isinstance(d, dict)
            for k, v in d.items() if v is not None and v != s30[g][k]}


def _record(hidden, excitation, load, path, workdir):
    params = {"model": "fu2018", "preset": "s30", "time_mode": "lockstep", "record": True, "record_path": str(path),
              "cmd_timeout": 0.0, "load_force": load, **_physics(hidden)}
    saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    os.environ.update({k: ENV[k] for k in saved})
    try:
        with NodeProcess(ENV, params, workdir=workdir) as proc, RosClient(ENV) as client:
            client.wait_for_node(proc)
            assert ctl.main(["--timeout", str(30 * CEILING_FACTOR), "play", str(excitation),
                             "--kp", "4000", "--kd", "80", "--ki", "20000"]) == 0
            assert proc.stop() == 0, proc.stderr
    finally:
        for k, v in saved.items():
            os.environ.pop(k, None) if v is None else os.environ.__setitem__(k, v)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    d = tmp_path_factory.mktemp("fitnode")
    (d / "sheet.yaml").write_text(SHEET)
    subprocess.run([sys.executable, "-m", "prsm_ros.cli.sim", "params", "--datasheet", str(d / "sheet.yaml"),
                    "--model", "fu2018", "-o", str(d / "base.yaml")], check=True, env=ENV, capture_output=True)
    base = load_params_file(d / "base.yaml")
    hidden = base.with_overrides(HIDDEN)
    assert excite(["-o", str(d / "ms.csv"), "--duration", "4", "--amplitude", "3"]) == 0
    assert excite(["-o", str(d / "chirp.csv"), "--duration", "2", "--amplitude", "3", "--kind", "chirp"]) == 0
    for load in LOADS:
        _record(hidden, d / "ms.csv", load, d / f"run{load:g}.mcap", d / f"w{load:g}")
    _record(hidden, d / "chirp.csv", HELD_LOAD, d / "held.mcap", d / "wheld")
    return d, base, hidden


def test_fit_of_node_recordings_matches_the_hidden_plants_datasheet(bench, capsys):
    d, base, hidden = bench
    out = d / "out"
    rc = cli.main([*(f"{d / f'run{f:g}.mcap'}@{f:g}" for f in LOADS), "--validate", f"{d / 'held.mcap'}@{HELD_LOAD:g}",
                   "--params", str(d / "base.yaml"), "--model", "fu2018", "--serial", "--starts", "2", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    doc = json.loads((out / "fit.json").read_text())
    fitted = load_params_file(out / "params.yaml")
    want, got = model_datasheet(hidden, "fu2018"), model_datasheet(fitted, "fu2018")
    assert abs(got.efficiency_forward - want.efficiency_forward) <= 0.02, (got, want)
    assert abs(got.efficiency_backward - want.efficiency_backward) <= 0.02, (got, want)
    assert abs(got.no_load_torque_nm / want.no_load_torque_nm - 1) <= 0.15, (got, want)
    assert abs(fitted.mass.moved_mass_kg / HIDDEN["mass.moved_mass_kg"] - 1) <= 0.10
    v = doc["validation"]["held.mcap"]
    assert v["rms_nut_position_m"] <= 0.5 * v["base"]["rms_nut_position_m"], v


def test_starts_run_on_ray(bench, embedded_ray, capsys):  # noqa: F811
    d, _, _ = bench
    out = d / "ray"
    rc = cli.main([*(f"{d / f'run{f:g}.mcap'}@{f:g}" for f in LOADS), "--params", str(d / "base.yaml"),
                   "--model", "fu2018", "--free", "mass.moved_mass_kg", "friction.mu_screw_roller",
                   "drag.seal_friction_n_per_m", "--starts", "2", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    doc = json.loads((out / "fit.json").read_text())
    assert len(doc["starts"]) == 2
    assert abs(doc["parameters"]["mass.moved_mass_kg"]["value"] / HIDDEN["mass.moved_mass_kg"] - 1) < 0.1
