"""Command safety over DDS (issue 4 item 4): bad inputs never crash the node and are counted.

Lockstep mode makes each check exact: every command message advances the same number of steps,
and the applied torque is visible as the `screw_joint` effort of joint_states.
"""

from __future__ import annotations

import math

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from ros_procs import NodeProcess, RosClient, diagnostics_of, ros_test_env  # noqa: E402

ENV = ros_test_env("test_node_safety")
TORQUE = "/prsm_actuator/screw_torque"
JOINTS = "/prsm_actuator/joint_commands"


def start(tmp_path, **params):
    base = {"time_mode": "lockstep", "lockstep_steps": 1, "cmd_timeout": 0.0, "max_effort": 2.0,
            "diagnostics_rate": 50.0, "record": False}
    return NodeProcess(ENV, {**base, **params}, workdir=tmp_path)


def connect(cli, proc):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    js = cli.subscribe("/joint_states", JointState)
    diag = cli.subscribe("/diagnostics", DiagnosticArray)
    cli.publisher(TORQUE, Float64)
    cli.publisher(JOINTS, JointState)
    cli.wait_for_node(proc)
    return js, diag


def send(cli, js, topic, msg, steps_after: int) -> None:
    cli.publish(topic, msg)
    cli.spin_until(lambda: len(js) >= steps_after, 10.0, f"step {steps_after}")


def latest_diagnostics(cli, diag, steps: int) -> tuple[int, str, dict[str, str]]:
    """The first diagnostics report that has seen `steps` steps."""
    start = len(diag)
    cli.spin_until(lambda: any(diagnostics_of(m)[2]["steps"] == str(steps) for m in diag[start:]), 10.0,
                   f"diagnostics at {steps} steps")
    return next(diagnostics_of(m) for m in diag[start:] if diagnostics_of(m)[2]["steps"] == str(steps))


def joint_command(names, effort, position=(), velocity=()):
    from sensor_msgs.msg import JointState
    return JointState(name=list(names), effort=list(effort), position=list(position), velocity=list(velocity))


@pytest.mark.slow
def test_nan_is_rejected_over_limit_saturated_bad_joint_state_rejected(tmp_path):
    from std_msgs.msg import Float64
    with start(tmp_path) as proc, RosClient(ENV) as cli:
        js, diag = connect(cli, proc)
        send(cli, js, TORQUE, Float64(data=1.5), 1)
        send(cli, js, TORQUE, Float64(data=math.nan), 2)  # rejected: 1.5 stays in force
        send(cli, js, TORQUE, Float64(data=math.inf), 3)
        send(cli, js, TORQUE, Float64(data=5.0), 4)  # saturated to max_effort = 2
        send(cli, js, TORQUE, Float64(data=-7.0), 5)
        send(cli, js, JOINTS, joint_command(["screw_joint"], [0.75]), 6)
        send(cli, js, JOINTS, joint_command(["other_joint"], [1.0]), 7)  # no screw_joint
        # packed as ros2_control's topic-based interface writes it: one effort for the one joint with an
        # effort command interface (issue 14); arrays of inactive interfaces are ignored
        send(cli, js, JOINTS, joint_command(["screw_joint", "x"], [1.0]), 8)
        send(cli, js, JOINTS, joint_command(["screw_joint", "x", "y"], [1.25, 2.0]), 9)  # 2 efforts for 3 names
        send(cli, js, JOINTS, joint_command(["x", "screw_joint"], [9.0, -0.5], velocity=[0.0, 0.0]), 10)
        assert [m.effort[0] for m in js] == [1.5, 1.5, 1.5, 2.0, -2.0, 0.75, 0.75, 1.0, 1.0, -0.5]
        level, text, v = latest_diagnostics(cli, diag, 10)
        assert (v["commands_received"], v["commands_accepted"]) == ("10", "6")
        assert (v["rejected_non_finite"], v["rejected_malformed"], v["saturated"]) == ("2", "2", "2")
        assert level == 0 and v["fault"] == ""
        assert proc.stop() == 0
    err = proc.stderr
    assert "not a finite number" in err
    assert "has no 'screw_joint'" in err
    # throttled: the two malformed joint commands arrive within the throttle window → one warning
    assert err.count("/prsm_actuator/joint_commands:") == 1, err
    assert "Traceback" not in err


@pytest.mark.slow
@pytest.mark.parametrize("behaviour, after", [("zero", 0.0), ("hold", 1.25)])
def test_watchdog_acts_after_cmd_timeout_of_simulation_time(tmp_path, behaviour, after):
    """One command, then 20 steps: with cmd_timeout 10.5 ms, steps starting after t = 10.5 ms time out."""
    from std_msgs.msg import Float64
    with start(tmp_path, lockstep_steps=20, cmd_timeout=0.0105, timeout_behaviour=behaviour) as proc, \
            RosClient(ENV) as cli:
        js, diag = connect(cli, proc)
        send(cli, js, TORQUE, Float64(data=1.25), 20)
        # step k starts at t = k ms: k = 0..10 use the command, k >= 11 are past the timeout
        assert [m.effort[0] for m in js] == [1.25] * 11 + [after] * 9
        level, text, v = latest_diagnostics(cli, diag, 20)
        assert v["timed_out"] == "True" and v["timeouts"] == "1"
        assert level == 1 and "no command for" in text
        send(cli, js, TORQUE, Float64(data=0.5), 40)  # a fresh command ends the timeout
        assert js[20].effort[0] == 0.5
        assert proc.stop() == 0


@pytest.mark.slow
def test_non_finite_state_faults_reports_error_and_reset_recovers(tmp_path):
    """fu2018 with a vanishing moved mass and no screw/roller inertia yields NaN on its first step."""
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger
    broken = {"physics.mass.moved_mass_kg": 1e-300, "physics.mass.screw_inertia_kgm2": 0.0,
              "physics.mass.roller_mass_kg": 0.0, "physics.mass.roller_inertia_kgm2": 0.0}
    with start(tmp_path, model="fu2018", **broken) as proc, RosClient(ENV) as cli:
        js, diag = connect(cli, proc)
        cli.publish(TORQUE, Float64(data=1.0))
        n = len(diag)
        cli.spin_until(lambda: any(diagnostics_of(m)[0] == 2 for m in diag[n:]), 10.0, "an ERROR diagnostic")
        level, text, v = next(diagnostics_of(m) for m in diag[n:] if diagnostics_of(m)[0] == 2)
        assert "non-finite state" in text and v["steps"] == "0"
        cli.publish(TORQUE, Float64(data=1.0))  # faulted: no stepping, no crash
        cli.spin_for(0.2)
        assert js == [] and proc.proc.poll() is None
        res = cli.set_parameters({"physics.mass.moved_mass_kg": 50.0, "physics.mass.screw_inertia_kgm2": 2e-4,
                                  "physics.mass.roller_mass_kg": 0.05, "physics.mass.roller_inertia_kgm2": 6e-7})
        assert res.successful, res.reason
        assert cli.call("/prsm_actuator/reset", Trigger).success
        send(cli, js, TORQUE, Float64(data=1.0), 1)
        assert math.isfinite(js[0].position[0]) and js[0].header.stamp.nanosec == 1_000_000
        level, text, v = latest_diagnostics(cli, diag, 1)
        assert level == 0 and v["fault"] == ""
        assert proc.stop() == 0
