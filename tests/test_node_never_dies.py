"""The node never dies on a valid request, over DDS.

- pause / resume / step / reset / brake / inject a fault / clear faults / commands in many orders
  (a seeded shuffle), with and without an actuator: every request is answered, the node keeps
  running and still steps afterwards, and the nut driven into a thread end raises
  `thread_end_reached` on `~/events`;
- a model failure (valid but extreme parameters set at run time: a vanishing moved mass with no
  inertia on the screw side has no finite acceleration) stops stepping, /diagnostics says ERROR
  naming it, `~/events` (and so the bag) holds one `model_failure` event, and `~/reset` brings the
  node back.

Lockstep with one step per command makes every step the consequence of one message, so the test
waits on states, never on time.
"""

from __future__ import annotations

import json
import math
import random

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from ros_procs import NodeProcess, RosClient, diagnostics_of, ros_test_env  # noqa: E402

ENV = ros_test_env("test_node_never_dies")
NODE = "/prsm_actuator"
TORQUE = f"{NODE}/screw_torque"
# a short screw: the nut's travel is ±0.1 mm, so 2 N·m reaches a thread end within a few steps
SHORT_SCREW = {"physics.geometry.screw_length_m": 0.0302}
ACTUATOR = "{motor: {}, brake: {holding_torque_nm: 5.0, engage_time_s: 0.002, release_time_s: 0.002}}"


def start(tmp_path, **params):
    base = {"time_mode": "lockstep", "lockstep_steps": 1, "cmd_timeout": 0.0, "max_effort": 2.0,
            "step_count": 3, "diagnostics_rate": 50.0, "record_path": str(tmp_path / "run.mcap")}
    return NodeProcess(ENV, {**base, **params}, workdir=tmp_path / "node")


def connect(cli, proc):
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Bool, Float64, String
    js = cli.subscribe("/joint_states", JointState)
    diag = cli.subscribe("/diagnostics", DiagnosticArray)
    events = cli.subscribe(f"{NODE}/events", String)
    for topic, cls in ((TORQUE, Float64), (f"{NODE}/inject_fault", String), (f"{NODE}/brake_command", Bool)):
        cli.publisher(topic, cls)
    cli.wait_for_node(proc)
    return js, diag, events


def codes(events) -> list[str]:
    return [json.loads(m.data)["code"] for m in events]


def alive(proc) -> None:
    assert proc.proc.poll() is None, f"node exited with {proc.proc.returncode}:\n{proc.stderr}"


def bag_events(path) -> list[dict]:
    from prsm_ros.bag.reader import open_bag
    return [json.loads(m.msg.data) for m in open_bag(path).messages([f"{NODE}/events"])]


@pytest.mark.slow
@pytest.mark.parametrize("actuator", ["", ACTUATOR], ids=["bare", "actuator"])
def test_requests_in_many_orders_never_kill_the_node_and_a_thread_end_is_an_event(tmp_path, actuator):
    from std_msgs.msg import Bool, Float64, String
    from std_srvs.srv import SetBool, Trigger
    params = {"model": "fu2018", **SHORT_SCREW, **({"actuator": actuator} if actuator else {})}
    with start(tmp_path, **params) as proc, RosClient(ENV) as cli:
        js, diag, events = connect(cli, proc)
        paused = False

        def command(torque: float) -> None:  # running: one step, waited for; paused: no step
            n = len(js)
            cli.publish(TORQUE, Float64(data=torque))
            if not paused:
                cli.spin_until(lambda: len(js) > n, 10.0, f"the step after command {torque}")

        def pause(on: bool) -> None:
            nonlocal paused
            res = cli.call(f"{NODE}/pause", SetBool, SetBool.Request(data=on))
            assert res.success and res.message.startswith("paused" if on else "running"), res.message
            paused = on

        def step() -> None:
            res = cli.call(f"{NODE}/step", Trigger)
            assert res.success == paused, res.message  # refused while running, 3 steps while paused

        def reset() -> None:
            assert cli.call(f"{NODE}/reset", Trigger).success

        def brake(on: bool) -> None:  # the owner's topic (the service is refused once a command owns
            # the actuator); the bare model has no brake: a refusal on ~/events, never a crash
            cli.publish(f"{NODE}/brake_command", Bool(data=on))

        def inject() -> None:  # a topic, not a service: a refusal (bare) is an event, never a crash
            cli.publish(f"{NODE}/inject_fault", String(data="kind=jam,duration_s=0.004,value=50"))

        def clear() -> None:
            assert cli.call(f"{NODE}/clear_faults", Trigger).success

        ops = [lambda: pause(True), lambda: pause(False), step, reset, lambda: brake(True), lambda: brake(False),
               inject, clear, lambda: command(1.5), lambda: command(-2.0), lambda: command(0.0)]
        rng = random.Random(24)
        for _ in range(60):
            rng.choice(ops)()
            alive(proc)
        # the sequence left no lasting damage: released, running, from the middle, it steps on
        brake(False)
        clear()
        pause(False)
        reset()
        n = len(events)
        for _ in range(300):
            command(2.0)
            if "thread_end_reached" in codes(events[n:]):
                break
        cli.spin_until(lambda: "thread_end_reached" in codes(events[n:]), 10.0, "a thread_end_reached event")
        assert all(math.isfinite(v) for m in js for v in m.position)
        assert not any(diagnostics_of(m)[0] == 2 for m in diag), "an ERROR diagnostic on valid requests"
        assert proc.stop() == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    reached = [e for e in bag_events(tmp_path / "run.mcap") if e["code"] == "thread_end_reached"]
    assert reached and reached[-1]["source"] == "plant" and abs(reached[-1]["details"]["force_n"]) > 0


@pytest.mark.slow
def test_model_failure_stops_stepping_reports_error_and_event_and_reset_recovers(tmp_path):
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool, Trigger
    from prsm_sim import preset
    mass = preset("s30").mass  # the node's preset: `good` restores its own values
    good = {f"physics.mass.{k}": getattr(mass, k) for k in ("moved_mass_kg", "screw_inertia_kgm2",
                                                             "roller_mass_kg", "roller_inertia_kgm2")}
    extreme = {"physics.mass.moved_mass_kg": 1e-300, "physics.mass.screw_inertia_kgm2": 0.0,
               "physics.mass.roller_mass_kg": 0.0, "physics.mass.roller_inertia_kgm2": 0.0}
    with start(tmp_path, model="fu2018", preset="s30") as proc, RosClient(ENV) as cli:
        js, diag, events = connect(cli, proc)
        for k in range(1, 4):
            cli.publish(TORQUE, Float64(data=1.0))
            cli.spin_until(lambda: len(js) >= k, 10.0, f"step {k}")
        res = cli.set_parameters(extreme)  # valid values: the failure shows only when the model steps
        assert res.successful, res.reason
        n = len(diag)
        cli.publish(TORQUE, Float64(data=1.0))
        cli.spin_until(lambda: any(diagnostics_of(m)[2]["fault"] for m in diag[n:]), 10.0, "a faulted diagnostic")
        level, text, v = next(diagnostics_of(m) for m in diag[n:] if diagnostics_of(m)[2]["fault"])
        assert level == 2 and text == v["fault"]
        assert "model fu2018 produced a non-finite state" in text and v["steps"] == "3", text
        cli.spin_until(lambda: "model_failure" in codes(events), 10.0, "the model_failure event")
        # faulted: commands, pause, step and resume are answered and step nothing; the node lives
        cli.publish(TORQUE, Float64(data=1.0))
        assert cli.call(f"{NODE}/pause", SetBool, SetBool.Request(data=True)).success
        res = cli.call(f"{NODE}/step", Trigger)
        assert not res.success and "faulted" in res.message
        assert cli.call(f"{NODE}/pause", SetBool, SetBool.Request(data=False)).success
        cli.publish(TORQUE, Float64(data=1.0))
        alive(proc)
        assert len(js) == 3 and codes(events).count("model_failure") == 1
        assert cli.set_parameters(good).successful
        assert cli.call(f"{NODE}/reset", Trigger).success
        n = len(diag)
        cli.publish(TORQUE, Float64(data=1.0))
        cli.spin_until(lambda: len(js) >= 4, 10.0, "a step after the reset")
        assert math.isfinite(js[-1].position[0]) and js[-1].header.stamp.nanosec == 1_000_000
        cli.spin_until(lambda: any(diagnostics_of(m)[2]["steps"] == "1" for m in diag[n:]), 10.0,
                       "diagnostics after the reset")
        level, text, v = next(diagnostics_of(m) for m in diag[n:] if diagnostics_of(m)[2]["steps"] == "1")
        assert level == 0 and v["fault"] == ""
        assert proc.stop() == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    failures = [e for e in bag_events(tmp_path / "run.mcap") if e["code"] == "model_failure"]
    assert len(failures) == 1
    assert failures[0]["severity"] == "error" and "non-finite state" in failures[0]["message"]
    assert failures[0]["details"]["model"] == "fu2018"
