"""Settings a user may legally choose, just past what the envelope draws: the frictionless limit, large
steps onto an end, loop rates that are no whole ratio of the step, loads past the ratings. Each test
names the independent number it checks against."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from prsm_sim import Simulator, preset
from prsm_sim.errors import ParamError

CLI = [sys.executable, "-m", "prsm_ros.cli.sim"]


def _cli(*args):
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=120)


def _viscous(c: float):
    p = preset("jones2016")
    return replace(p, friction=replace(p.friction, viscous_n_s_m=c))


# -- jones2016 in the frictionless limit ---------------------------------------------------------------
@pytest.mark.parametrize("dt", [1e-4, 1e-3, 0.05])
def test_jones2016_near_frictionless_closes_its_books(dt):
    """Conservation of energy (kinetic energy gained = work in − work out − friction work): at c = 1e-12
    N·s/m the friction-work form once lost its precision (residual 0.86–1.6 of the flow); exact to rounding."""
    sim = Simulator(_viscous(1e-12), "jones2016", dt_s=dt)
    n = int(0.5 / dt)
    t = np.arange(n) * dt
    tq, load = 0.05 * np.sin(20 * t), 50.0 * np.cos(7 * t)
    for k in range(n):
        out = sim.step(tq[k], load_n=load[k])
    s = sim.state
    assert out.energy_fault == 0.0
    assert abs(s.energy_residual_j) <= 1e-10 * s.energy_flow_j
    # the batch path (recursive filters on the same step matrices) closes its books as well
    traj = Simulator(_viscous(1e-12), "jones2016", dt_s=dt).run(tq, load)
    c = traj.columns
    assert abs(c["energy_residual_j"][-1]) <= 1e-10 * c["energy_flow_j"][-1]
    # the friction work vanishes with c (the limit case): ≤ c · (slip speed)² · time, far below the flow
    assert c["power_dissipated_w"].sum() * dt <= 1e-9 * c["energy_flow_j"][-1]


def test_jones2016_refuses_zero_friction_in_one_line():
    with pytest.raises(ParamError, match=r"friction\.viscous_n_s_m = 0\.0"):
        Simulator(_viscous(0.0), "jones2016")
    r = _cli("run", "--set", "friction.viscous_n_s_m=0", "--duration", "0.01")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "friction.viscous_n_s_m" in lines[0] and "Error" not in lines[0].split(":")[0]
    r = _cli("steady-state", "--set", "friction.viscous_n_s_m=0")
    assert r.returncode == 2 and "friction.viscous_n_s_m" in r.stderr and "nan" not in r.stdout.lower()


@pytest.mark.parametrize("args", [("--load", "0"), ("--set", "friction.viscous_n_s_m=1e-12", "--load", "0"),
                                  ("--torque", "0", "--load", "0")])
def test_steady_state_never_prints_nan(args):
    """Efficiency P_out/P_in at zero load is 0/0: reported as undefined (JSON null), never NaN with exit 0."""
    r = _cli("steady-state", *args)
    assert r.returncode == 0, r.stderr
    assert "nan" not in r.stdout.lower() and "efficiency: undefined" in r.stdout
    r = _cli("steady-state", "--json", *args)
    assert r.returncode == 0 and "NaN" not in r.stdout and '"efficiency": null' in r.stdout
