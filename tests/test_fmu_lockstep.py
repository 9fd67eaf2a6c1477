"""The same torque sequence through prsm-node in lockstep (over DDS) and through the FMU gives the same states.

Both run the library's `Session`: the node advances `lockstep_steps` steps per received command, the
FMU as many sub-steps per communication step of that length. Oracle: each other, bit for bit
(CDR and FMI both carry float64 exactly), at every communication point.
"""

from __future__ import annotations

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from prsm_sim import preset  # noqa: E402
from prsm_ros.fmu.build import build_fmu  # noqa: E402
from prsm_ros.fmu.config import make_config  # noqa: E402
from prsm_ros.fmu.driver import OK, FmuDriver  # noqa: E402
from test_node_lockstep import LOAD_N, STEPS_PER_COMMAND, TORQUES, lockstep_params, run_lockstep  # noqa: E402

DT = 1e-3


@pytest.mark.slow
@pytest.mark.parametrize("fmi", [2, 3])
def test_node_in_lockstep_and_the_fmu_give_the_same_states(tmp_path, fmi):
    node_params = lockstep_params("fu2018", tmp_path)
    config = make_config(preset(node_params["preset"]), "fu2018", DT, None, interface="effort", load_n=LOAD_N,
                         max_effort_nm=node_params["max_effort"], fmi=fmi)
    assert node_params["cmd_timeout"] == 0.0  # no watchdog in the node either (the FMU has none)
    path = build_fmu(config, tmp_path / "plant.fmu")
    h = STEPS_PER_COMMAND * DT
    names = ["screw_angle_rad", "nut_position_m", "screw_speed_rad_s", "nut_velocity_m_s", "nut_force_n"]
    fmu_states = []
    with FmuDriver(path) as drv:
        torque, out = drv.refs(["screw_torque_nm"]), drv.refs(names)
        for k, tau in enumerate(TORQUES):
            drv.set(torque, [tau])
            assert drv.do_step(k * h, h) == OK, drv.messages
            fmu_states.append(drv.get(out))
    js = run_lockstep(tmp_path, "fu2018", TORQUES)["joint_states"]
    node_states = [[m.position[0], m.position[1], m.velocity[0], m.velocity[1], m.effort[1]]
                   for m in js[STEPS_PER_COMMAND - 1::STEPS_PER_COMMAND]]
    assert len(node_states) == len(fmu_states) == len(TORQUES)
    assert node_states == fmu_states
