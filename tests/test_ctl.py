"""`prsm-ctl` drives a running `prsm-node`: every verb, against a real node process over DDS.

Each verb runs as its own `prsm-ctl` process, as a user runs it (its exit status, its JSON lines
and its one-line errors). Not in this process: a second rclpy context created here after the
first is closed took 2.8–3.0 s to discover the node (Fast DDS, localhost discovery), a new
`prsm-ctl pause` process 1.0 s (median of ten). What each verb did is checked on the node itself
(its parameters, its services' answers, its topics), not on prsm-ctl's own words.
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
    with NodeProcess(ENV, PARAMS, workdir=tmp_path_factory.mktemp("ctl")) as proc, RosClient(ENV) as cli:
        cli.wait_for_node(proc)
        yield proc, cli
        assert proc.stop() == 0, proc.stderr


CTL = [sys.executable, "-m", "prsm_ros.cli.ctl"]


def ctl_env(env: dict) -> dict:
    """`env` for a prsm-ctl process that imports this checkout's packages."""
    return {**env, "PYTHONPATH": os.pathsep.join(sys.path)}


def run_text(env: dict, *argv: str) -> tuple[int, str, str]:
    """(exit status, stdout, stderr) of one `prsm-ctl` process on `env`'s domain."""
    r = subprocess.run([*CTL, "--timeout", TIMEOUT, *argv], env=ctl_env(env), capture_output=True, text=True,
                       timeout=120 * CEILING_FACTOR)
    return r.returncode, r.stdout, r.stderr


def run(env: dict, *argv: str) -> tuple[int, list, str]:
    """(exit status, the JSON records printed, stderr) of one `prsm-ctl --json` process."""
    rc, out, err = run_text(env, "--json", *argv)
    return rc, [json.loads(line) for line in out.splitlines() if line.strip()], err


def until_state(env: dict, key: str, value) -> None:
    """`prsm-ctl state` until the node reports `key` = `value` (a topic command is acknowledged by DDS
    before the node has acted on it; /diagnostics come once a second)."""
    end = time.monotonic() + 30 * CEILING_FACTOR
    while run(env, "state")[1][0].get(key) != value:
        assert time.monotonic() < end, f"the node never reported {key} = {value}"


def test_pause_step_resume_reset(node):
    proc, cli = node
    rc, rec, _ = run(ENV, "state")
    assert rc == 0 and rec[0]["paused"] is True and rec[0]["time_s"] == 0.0
    rc, rec, err = run(ENV, "step", "5")
    assert rc == 0, err
    assert rec[0]["message"].startswith("stepped 5 of 5 steps to t = 0.005000 s")
    rc, rec, _ = run(ENV, "state")  # paused: the state the node holds, though joint_states is silent
    assert rc == 0 and rec[0]["paused"] is True and rec[0]["time_s"] == pytest.approx(0.005)
    assert set(rec[0]["screw_joint"]) == {"position", "velocity", "effort"} and "nut_joint" in rec[0]
    assert cli.get_parameters(["step_count"]) == {"step_count": 1}  # N applies to that call only
    # likely more than a second of work: then the node answers "accepted" at once and prsm-ctl waits
    # for its step_done event; either way the answer is the steps done
    rc, rec, err = run(ENV, "step", "30000")
    assert rc == 0 and "30000 of 30000 steps" in rec[0]["message"], (rec, err)
    rc, rec, _ = run(ENV, "resume")
    assert rc == 0 and rec[0]["message"].startswith("running")
    rc, _, err = run(ENV, "step", "1")
    assert rc == 2 and "refused: not paused" in err and err.count("\n") == 1
    rc, rec, _ = run(ENV, "state")
    assert rc == 0 and rec[0]["paused"] is False and rec[0]["time_s"] > 30.005
    assert set(rec[0]) >= {"screw_joint", "nut_joint", "command_interface"}
    rc, rec, _ = run(ENV, "pause")
    assert rc == 0 and rec[0]["message"].startswith("paused")
    rc, rec, _ = run(ENV, "reset")
    assert rc == 0 and rec[0]["message"] == "reset to t = 0, nut at 0 m"
    rc, rec, _ = run(ENV, "state")
    assert rec[0]["time_s"] == 0.0


def test_param_get_set_list_dump(node):
    proc, cli = node
    rc, rec, _ = run(ENV, "param", "set", "load_force", "500")
    assert rc == 0
    assert cli.get_parameters(["load_force"]) == {"load_force": 500.0}
    rc, rec, _ = run(ENV, "param", "get", "load_force", "max_effort")
    assert rec == [{"name": "load_force", "value": 500.0}, {"name": "max_effort", "value": 50.0}]
    rc, _, err = run(ENV, "param", "get", "lod_force")
    assert rc == 2 and "did you mean load_force" in err and err.count("\n") == 1
    rc, _, err = run(ENV, "param", "set", "load_force", "nan")
    assert rc == 2 and "load_force" in err and "refused" in err
    assert cli.get_parameters(["load_force"]) == {"load_force": 500.0}
    rc, rec, _ = run(ENV, "param", "list", "physics.mass.")
    assert "physics.mass.moved_mass_kg" in rec[0]["names"] and all(n.startswith("physics.mass.") for n in rec[0]["names"])
    rc, text, _ = run_text(ENV, "param", "dump")
    assert rc == 0
    dump = yaml.safe_load(text)
    assert dump["prsm_actuator"]["ros__parameters"]["load_force"] == 500.0
    assert run(ENV, "param", "set", "load_force", "0.0")[0] == 0


def test_interface_command_release(node):
    from sensor_msgs.msg import TimeReference
    proc, cli = node
    echo = cli.subscribe("/prsm_actuator/command_echo", TimeReference)
    assert run(ENV, "resume")[0] == 0
    rc, _, _ = run(ENV, "interface", "velocity")
    assert rc == 0 and cli.get_parameters(["command_interface"]) == {"command_interface": "velocity"}
    rc, _, err = run(ENV, "command", "torque", "0.1")
    assert rc == 2 and "command_interface is velocity" in err and "prsm-ctl interface effort" in err
    rc, rec, err = run(ENV, "command", "velocity", "2.0")
    assert rc == 0, err
    assert rec[0]["topic"] == "/prsm_actuator/velocity_command" and rec[0]["applied_at_s"] > 0
    cli.spin_until(lambda: any(m.source.endswith("velocity_command") for m in echo), 10.0, "the command's echo")
    rc, rec, _ = run(ENV, "state")
    assert rec[0]["command"] == 2.0
    rc, _, err = run(ENV, "command", "velocity", "inf")
    assert rc == 2 and "must be finite" in err
    rc, rec, _ = run(ENV, "release")
    assert rc == 0
    assert run(ENV, "interface", "effort")[0] == 0
    assert run(ENV, "pause")[0] == 0


def test_brake_fault_events(node):
    from std_msgs.msg import String
    proc, cli = node
    events = cli.subscribe("/prsm_actuator/events", String)
    assert run(ENV, "resume")[0] == 0
    rc, rec, err = run(ENV, "brake", "on")
    assert rc == 0, err
    until_state(ENV, "brake_engaged", True)  # the node's own word, on /diagnostics
    rc, rec, _ = run(ENV, "brake", "off")
    assert rc == 0
    until_state(ENV, "brake_engaged", False)
    rc, rec, err = run(ENV, "fault", "inject", "jam", "duration_s=0.05", "value=3")
    assert rc == 0, err
    cli.spin_until(lambda: any('"fault_clear"' in m.data for m in events), 10.0, "the jam's start and clear")
    rc, rec, _ = run(ENV, "events")
    codes = [(e["code"], e["details"].get("kind")) for e in rec]
    assert ("fault_start", "jam") in codes and ("fault_clear", "jam") in codes
    rc, _, err = run(ENV, "fault", "inject", "jamm")
    assert rc == 2 and "jamm" in err
    rc, rec, _ = run(ENV, "fault", "clear")
    assert rc == 0 and "runtime fault(s) ended" in rec[0]["message"]
    assert run(ENV, "pause")[0] == 0


def test_the_command_state_follow_and_a_missing_node(node, tmp_path):
    rc, out, err = run_text(ENV, "--node", "/nobody", "--timeout", "1", "state")
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and "node /nobody not found on ROS_DOMAIN_ID" in err
    assert run(ENV, "resume")[0] == 0
    follow = subprocess.Popen([*CTL, "state", "--follow", "--rate", "50"], env=ctl_env(ENV), stdout=subprocess.PIPE,
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
    assert run(ENV, "pause")[0] == 0


def test_wait_for_controller_hands_the_plant_to_the_first_command(tmp_path):
    """Realtime with load, as a user's controller joins late: nothing steps until its first command."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, String
    params = {"model": "ideal", "preset": "s30", "record": False, "load_force": 500.0, "wait_for_controller": True}
    env = ros_test_env("test_ctl_wait")
    with NodeProcess(env, params, workdir=tmp_path / "run") as proc, RosClient(env) as cli:
        js = cli.subscribe("/joint_states", JointState)
        events = cli.subscribe("/prsm_actuator/events", String)
        cli.publisher("/prsm_actuator/screw_torque", Float64)
        cli.wait_for_node(proc)
        rc, recs, err = run(env, "state")
        assert rc == 0, err
        rec = recs[0]
        assert rec["paused"] is True and rec["time_s"] == 0.0 and js == []
        cli.publish("/prsm_actuator/screw_torque", Float64(data=0.4))
        cli.spin_until(lambda: js, 10.0, "the first state after the controller's command")
        t0 = js[0].header.stamp.sec + js[0].header.stamp.nanosec * 1e-9
        assert t0 == pytest.approx(1e-3)  # the first step after the hand-over, not seconds of free fall
        cli.spin_until(lambda: any('"controller_resumed"' in m.data for m in events), 10.0, "the hand-over event")
        assert proc.stop() == 0, proc.stderr


def test_a_command_refused_by_the_owner_rule_says_so(tmp_path):
    """Another controller owns the actuator: prsm-ctl's command is refused with the node's reason
    (its refusal event names prsm-ctl's writer), and goes through once ownership is released."""
    from std_msgs.msg import Float64
    params = {"model": "ideal", "record": False, "cmd_timeout": 0.0, "ownership_timeout": 0.0}
    env = ros_test_env("test_ctl_owner")
    with NodeProcess(env, params, workdir=tmp_path / "run") as proc, RosClient(env) as cli:
        cli.publisher("/prsm_actuator/screw_torque", Float64)
        cli.wait_for_node(proc)
        cli.publish("/prsm_actuator/screw_torque", Float64(data=0.1))  # this client owns it from now on
        until_state(env, "command", 0.1)
        rc, _, err = run(env, "command", "torque", "0.3")
        assert rc == 2 and err.count("\n") == 1 and "refused by /prsm_actuator" in err and "owned by" in err, err
        # owned inputs too: the node's refusal is prsm-ctl's exit 2, never "sent"
        rc, _, err = run(env, "fault", "inject", "jam", "duration_s=0.05", "value=3")
        assert rc == 2 and err.count("\n") == 1 and "refused by /prsm_actuator" in err, err
        rc, _, err = run(env, "brake", "on")
        assert rc == 2 and err.count("\n") == 1 and "refused by /prsm_actuator" in err, err
        assert run(env, "release")[0] == 0
        rc, rec, err = run(env, "command", "torque", "0.3")
        assert rc == 0 and rec[0]["applied_at_s"] > 0, err
        assert run(env, "release")[0] == 0  # that prsm-ctl process owned it (ownership_timeout 0)
        rc, rec, err = run(env, "command", "torque", "-1e-1")  # a number in any spelling
        assert rc == 0 and rec[0]["value"] == -0.1, err
        assert proc.stop() == 0, proc.stderr
