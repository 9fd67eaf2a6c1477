"""`prsm-ctl` drives a running `prsm-node`: every verb, against a real node process over DDS.

The verbs run in this process through `prsm_ros.cli.ctl.main` (each call its own rclpy context, as
a separate `prsm-ctl` process would have), except where the exit status and the one-line error of
the real command matter (node not found, `state --follow` ended by Ctrl-C): there the command
runs as a process. What each verb did is checked on the node itself (its parameters, its
services' answers, its topics), not on prsm-ctl's own words.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)
import yaml

from prsm_ros.cli import ctl
from ros_procs import CEILING_FACTOR, NodeProcess, RosClient, ros_test_env

# the slow tier (.ci/run runs it after the README's test command): many node or Ray start-ups
pytestmark = pytest.mark.slow

ENV = ros_test_env("test_ctl")
PARAMS = {"model": "ideal", "preset": "s30", "start_paused": True, "record": False, "cmd_timeout": 0.0,
          "diagnostics_rate": 10.0,  # `state` waits for one report
          # a command from a prsm-ctl process makes that process the owner; a short lapse lets the next one in
          "ownership_timeout": 0.05,
          "actuator": "{motor: {}, brake: {holding_torque_nm: 8.0}}"}
TIMEOUT = str(10 * CEILING_FACTOR)


@pytest.fixture(scope="module")
def node(tmp_path_factory):
    saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    os.environ.update({k: ENV[k] for k in saved})
    with NodeProcess(ENV, PARAMS, workdir=tmp_path_factory.mktemp("ctl")) as proc, RosClient(ENV) as cli:
        cli.wait_for_node(proc)
        yield proc, cli
        assert proc.stop() == 0, proc.stderr
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v


def run(capsys, *argv: str) -> tuple[int, list, str]:
    """(exit status, the JSON records printed, stderr) of one prsm-ctl call."""
    rc = ctl.main(["--json", "--timeout", TIMEOUT, *argv])
    out, err = capsys.readouterr()
    return rc, [json.loads(line) for line in out.splitlines() if line.strip()], err


def until_state(capsys, key: str, value: str) -> None:
    """`prsm-ctl state` until the node reports `key` = `value` (a topic command is acknowledged by DDS
    before the node has acted on it; /diagnostics come once a second)."""
    end = time.monotonic() + 30 * CEILING_FACTOR
    while run(capsys, "state")[1][0].get(key) != value:
        assert time.monotonic() < end, f"the node never reported {key} = {value}"


def test_pause_step_resume_reset(node, capsys):
    proc, cli = node
    rc, rec, _ = run(capsys, "state")
    assert rc == 0 and rec[0]["paused"] == "True" and rec[0]["time_s"] == 0.0
    rc, rec, err = run(capsys, "step", "5")
    assert rc == 0, err
    assert rec[0]["message"].startswith("stepped 5 of 5 steps to t = 0.005000 s")
    assert cli.get_parameters(["step_count"]) == {"step_count": 1}  # N applies to that call only
    # likely more than a second of work: then the node answers "accepted" at once and prsm-ctl waits
    # for its step_done event; either way the answer is the steps done
    rc, rec, err = run(capsys, "step", "30000")
    assert rc == 0 and "30000 of 30000 steps" in rec[0]["message"], (rec, err)
    rc, rec, _ = run(capsys, "resume")
    assert rc == 0 and rec[0]["message"].startswith("running")
    rc, _, err = run(capsys, "step", "1")
    assert rc == 2 and "refused: not paused" in err and err.count("\n") == 1
    rc, rec, _ = run(capsys, "state")
    assert rc == 0 and rec[0]["paused"] == "False" and rec[0]["time_s"] > 30.005
    assert set(rec[0]) >= {"screw_joint", "nut_joint", "command_interface"}
    rc, rec, _ = run(capsys, "pause")
    assert rc == 0 and rec[0]["message"].startswith("paused")
    rc, rec, _ = run(capsys, "reset")
    assert rc == 0 and rec[0]["message"] == "reset to t = 0, nut at 0 m"
    rc, rec, _ = run(capsys, "state")
    assert rec[0]["time_s"] == 0.0


def test_param_get_set_list_dump(node, capsys):
    proc, cli = node
    rc, rec, _ = run(capsys, "param", "set", "load_force", "500")
    assert rc == 0
    assert cli.get_parameters(["load_force"]) == {"load_force": 500.0}
    rc, rec, _ = run(capsys, "param", "get", "load_force", "max_effort")
    assert rec == [{"name": "load_force", "value": 500.0}, {"name": "max_effort", "value": 50.0}]
    rc, _, err = run(capsys, "param", "get", "lod_force")
    assert rc == 2 and "did you mean load_force" in err and err.count("\n") == 1
    rc, _, err = run(capsys, "param", "set", "load_force", "nan")
    assert rc == 2 and "load_force" in err and "refused" in err
    assert cli.get_parameters(["load_force"]) == {"load_force": 500.0}
    rc, rec, _ = run(capsys, "param", "list", "physics.mass.")
    assert "physics.mass.moved_mass_kg" in rec[0]["names"] and all(n.startswith("physics.mass.") for n in rec[0]["names"])
    rc = ctl.main(["param", "dump"])
    dump = yaml.safe_load(capsys.readouterr().out)
    assert dump["prsm_actuator"]["ros__parameters"]["load_force"] == 500.0
    assert run(capsys, "param", "set", "load_force", "0.0")[0] == 0


def test_interface_command_release(node, capsys):
    from sensor_msgs.msg import TimeReference
    proc, cli = node
    echo = cli.subscribe("/prsm_actuator/command_echo", TimeReference)
    assert run(capsys, "resume")[0] == 0
    rc, _, _ = run(capsys, "interface", "velocity")
    assert rc == 0 and cli.get_parameters(["command_interface"]) == {"command_interface": "velocity"}
    rc, _, err = run(capsys, "command", "torque", "0.1")
    assert rc == 2 and "command_interface is velocity" in err and "prsm-ctl interface effort" in err
    rc, rec, err = run(capsys, "command", "velocity", "2.0")
    assert rc == 0, err
    assert rec[0]["topic"] == "/prsm_actuator/velocity_command" and rec[0]["applied_at_s"] > 0
    cli.spin_until(lambda: any(m.source.endswith("velocity_command") for m in echo), 10.0, "the command's echo")
    rc, rec, _ = run(capsys, "state")
    assert rec[0]["command"] == "2.0"
    rc, _, err = run(capsys, "command", "velocity", "inf")
    assert rc == 2 and "must be finite" in err
    rc, rec, _ = run(capsys, "release")
    assert rc == 0
    assert run(capsys, "interface", "effort")[0] == 0
    assert run(capsys, "pause")[0] == 0


def test_brake_fault_events(node, capsys):
    from std_msgs.msg import String
    proc, cli = node
    events = cli.subscribe("/prsm_actuator/events", String)
    assert run(capsys, "resume")[0] == 0
    rc, rec, err = run(capsys, "brake", "on")
    assert rc == 0, err
    until_state(capsys, "brake_engaged", "True")  # the node's own word, on /diagnostics
    rc, rec, _ = run(capsys, "brake", "off")
    assert rc == 0
    until_state(capsys, "brake_engaged", "False")
    rc, rec, err = run(capsys, "fault", "inject", "jam", "duration_s=0.05", "value=3")
    assert rc == 0, err
    cli.spin_until(lambda: any('"fault_clear"' in m.data for m in events), 10.0, "the jam's start and clear")
    rc, rec, _ = run(capsys, "events")
    codes = [(e["code"], e["details"].get("kind")) for e in rec]
    assert ("fault_start", "jam") in codes and ("fault_clear", "jam") in codes
    rc, _, err = run(capsys, "fault", "inject", "jamm")
    assert rc == 2 and "jamm" in err
    rc, rec, _ = run(capsys, "fault", "clear")
    assert rc == 0 and "runtime fault(s) ended" in rec[0]["message"]
    assert run(capsys, "pause")[0] == 0


def test_the_command_state_follow_and_a_missing_node(node, tmp_path):
    base = [sys.executable, "-m", "prsm_ros.cli.ctl"]
    env = {**ENV, "PYTHONPATH": os.pathsep.join(sys.path)}
    r = subprocess.run(base + ["--node", "/nobody", "--timeout", "1", "state"], env=env, capture_output=True,
                       text=True, timeout=60 * CEILING_FACTOR)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and "node /nobody not found on ROS_DOMAIN_ID" in r.stderr
    assert run_cli(base + ["resume"], env) == 0
    follow = subprocess.Popen(base + ["state", "--follow", "--rate", "50"], env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        lines = [follow.stdout.readline() for _ in range(3)]  # blocks until the node's states arrive
        assert all(line.startswith("t = ") and "screw_joint" in line for line in lines), lines
        follow.send_signal(signal.SIGINT)
        assert follow.wait(timeout=20 * CEILING_FACTOR) == 130
    finally:
        if follow.poll() is None:
            follow.kill()
            follow.wait()
    assert run_cli(base + ["pause"], env) == 0


def run_cli(cmd: list[str], env: dict) -> int:
    return subprocess.run(cmd + ["--timeout", TIMEOUT], env=env, capture_output=True, timeout=120 * CEILING_FACTOR).returncode


def test_wait_for_controller_hands_the_plant_to_the_first_command(tmp_path, capsys):
    """Realtime with load, as a user's controller joins late: nothing steps until its first command."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, String
    params = {"model": "ideal", "preset": "s30", "record": False, "load_force": 500.0, "wait_for_controller": True}
    saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    env = ros_test_env("test_ctl_wait")
    os.environ.update({k: env[k] for k in saved})
    try:
        with NodeProcess(env, params, workdir=tmp_path / "run") as proc, RosClient(env) as cli:
            js = cli.subscribe("/joint_states", JointState)
            events = cli.subscribe("/prsm_actuator/events", String)
            cli.publisher("/prsm_actuator/screw_torque", Float64)
            cli.wait_for_node(proc)
            assert ctl.main(["--json", "--timeout", TIMEOUT, "state"]) == 0
            rec = json.loads(capsys.readouterr().out)
            assert rec["paused"] == "True" and rec["time_s"] == 0.0 and js == []
            cli.publish("/prsm_actuator/screw_torque", Float64(data=0.4))
            cli.spin_until(lambda: js, 10.0, "the first state after the controller's command")
            t0 = js[0].header.stamp.sec + js[0].header.stamp.nanosec * 1e-9
            assert t0 == pytest.approx(1e-3)  # the first step after the hand-over, not seconds of free fall
            cli.spin_until(lambda: any('"controller_resumed"' in m.data for m in events), 10.0, "the hand-over event")
            assert proc.stop() == 0, proc.stderr
    finally:
        os.environ.update({k: v for k, v in saved.items() if v is not None})


def test_a_command_refused_by_the_owner_rule_says_so(tmp_path, capsys):
    """Another controller owns the actuator: prsm-ctl's command is refused with the node's reason
    (its refusal event names prsm-ctl's writer), and goes through once ownership is released."""
    from std_msgs.msg import Float64
    params = {"model": "ideal", "record": False, "cmd_timeout": 0.0, "ownership_timeout": 0.0}
    saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    env = ros_test_env("test_ctl_owner")
    os.environ.update({k: env[k] for k in saved})
    try:
        with NodeProcess(env, params, workdir=tmp_path / "run") as proc, RosClient(env) as cli:
            cli.publisher("/prsm_actuator/screw_torque", Float64)
            cli.wait_for_node(proc)
            cli.publish("/prsm_actuator/screw_torque", Float64(data=0.1))  # this client owns it from now on
            until_state(capsys, "command", "0.1")
            rc, _, err = run(capsys, "command", "torque", "0.3")
            assert rc == 2 and err.count("\n") == 1 and "refused by /prsm_actuator" in err and "owned by" in err, err
            assert run(capsys, "release")[0] == 0
            rc, rec, err = run(capsys, "command", "torque", "0.3")
            assert rc == 0 and rec[0]["applied_at_s"] > 0, err
            assert proc.stop() == 0, proc.stderr
    finally:
        os.environ.update({k: v for k, v in saved.items() if v is not None})
