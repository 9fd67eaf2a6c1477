"""Node parameters (issue 4 item 1): start-up validation, ros__parameters files, runtime changes.

A bad value at start-up: exit code 2 and exactly one line on stderr naming the parameter and
what is allowed, no traceback. A bad value at runtime: the set is refused with that reason and
nothing changes (checked against the core run offline, as in test_node_lockstep).
"""

from __future__ import annotations

import math

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from prsm_sim import Simulator, preset  # noqa: E402
from prsm_ros.node.parameters import ConfigError, NodeConfig, params_template  # noqa: E402
from ros_procs import NodeProcess, RosClient, ros_test_env  # noqa: E402

ENV = ros_test_env("test_node_params")


BAD_STARTS = [
    ({"preset": "nope"}, "parameter preset = 'nope': must be one of jones2016, jones2016_literal, s30"),
    ({"model": "nope"}, "parameter model = 'nope': must be one of ideal, jones2016"),
    ({"physics.friction.mu_screw_roller": 2.0}, "physics.friction.mu_screw_roller = 2.0: must be < 1"),
    ({"physics.geometry.starts": 2.5}, "physics.geometry.starts = 2.5: must be a whole number"),
    ({"physics.friction.mu_typo": 0.1}, "unknown parameter physics.friction.mu_typo (-p); did you mean physics.friction."),
    ({"max_efort": 1.0}, "unknown parameter max_efort (-p); did you mean max_effort?"),
    ({"actuator.stops.max_positon_m": 0.1}, "unknown parameter actuator.stops.max_positon_m (-p); did you mean actuator.stops.max_position_m?"),
    ({"update_rate": 0}, "parameter update_rate = 0: must be a whole number in [1, 100000] (Hz)"),
    ({"cmd_timeout": -0.5}, "parameter cmd_timeout = -0.5: must be a finite number in [0, 1e+06] (s)"),
    ({"time_mode": 5}, "parameter time_mode = 5: must be one of realtime, fast, lockstep"),
    ({"record": True, "record_path": "/nonexistent/dir/run.mcap"}, "parameter record_path = '/nonexistent/dir/run.mcap'"),
    ({"step_thread_cpu": 1023}, "parameter step_thread_cpu = 1023: must be -1 "),
]


@pytest.fixture(scope="module")
def bad_starts(tmp_path_factory):
    """All the refused start-ups, launched at once (each is a separate node process)."""
    procs = [NodeProcess(ENV, {"record": False, **params}, workdir=tmp_path_factory.mktemp(f"bad{k}"))
             for k, (params, _) in enumerate(BAD_STARTS)]
    yield procs
    for p in procs:
        p.__exit__()


@pytest.mark.slow
@pytest.mark.parametrize("k", range(len(BAD_STARTS)), ids=[next(iter(p)) for p, _ in BAD_STARTS])
def test_invalid_parameter_stops_startup_with_one_clear_line(bad_starts, k):
    proc, expected = bad_starts[k], BAD_STARTS[k][1]
    assert proc.wait(60) == 2, proc.stderr  # all start at once: ros_procs stretches the ceiling
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("prsm-node: error: " + expected), proc.stderr
    assert list(proc.workdir.glob("*.mcap")) == []


def test_params_template_loads_back_into_a_valid_config():
    import yaml
    doc = yaml.safe_load(params_template("jones2016"))
    values = doc["prsm_actuator"]["ros__parameters"]
    cfg = NodeConfig.from_values(values)
    assert cfg.params == preset("jones2016") and cfg.preset == "jones2016"


def lockstep_states(cli, js, torques, start_count):
    from std_msgs.msg import Float64
    for k, tau in enumerate(torques):
        cli.publish("/prsm_actuator/screw_torque", Float64(data=tau))
        cli.spin_until(lambda: len(js) >= start_count + k + 1, 10.0, f"step {start_count + k + 1}")
    return js[start_count:]


def assert_same(msgs, outs):
    assert [(tuple(m.position), tuple(m.velocity), tuple(m.effort)) for m in msgs] == \
        [((o.screw_angle_rad, o.nut_position_m), (o.screw_speed_rad_s, o.nut_velocity_m_s),
          (o.screw_torque_nm, o.nut_force_n)) for o in outs]


@pytest.mark.slow
def test_params_file_and_runtime_changes(tmp_path):
    """Start from a ros__parameters file; a valid runtime change takes effect at once, invalid ones change nothing."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    pfile = tmp_path / "node.yaml"
    pfile.write_text(
        "prsm_actuator:\n  ros__parameters:\n    time_mode: lockstep\n    preset: jones2016\n"
        "    load_force: 250\n    cmd_timeout: 0\n    record: false\n"
        "    physics:\n      friction:\n        viscous_n_s_m: 40.0\n"
        "    qos_overrides:\n      /prsm_actuator/nut/wrench:\n        publisher:\n          durability: transient_local\n")
    with NodeProcess(ENV, workdir=tmp_path, extra_args=["--ros-args", "--params-file", str(pfile)]) as proc, \
            RosClient(ENV) as cli:
        js = cli.subscribe("/joint_states", JointState)
        cli.publisher("/prsm_actuator/screw_torque", Float64)
        cli.wait_for_node(proc)
        got = cli.get_parameters(["load_force", "physics.friction.viscous_n_s_m", "time_mode", "max_effort"])
        assert got == {"load_force": 250, "physics.friction.viscous_n_s_m": 40.0, "time_mode": "lockstep",
                       "max_effort": 50.0}
        from rclpy.qos import DurabilityPolicy
        info = cli.node.get_publishers_info_by_topic("/prsm_actuator/nut/wrench")
        assert [i.qos_profile.durability for i in info] == [DurabilityPolicy.TRANSIENT_LOCAL]  # QoS overridden

        p0 = preset("jones2016").with_overrides({"friction.viscous_n_s_m": 40.0})
        sim = Simulator(p0, "jones2016", 1e-3)
        want = [sim.step(1.0, 250.0) for _ in range(4)]
        assert_same(lockstep_states(cli, js, [1.0] * 4, 0), want)

        res = cli.set_parameters({"load_force": 500, "physics.friction.viscous_n_s_m": 10})
        assert res.successful, res.reason
        p1 = p0.with_overrides({"friction.viscous_n_s_m": 10.0})
        sim2 = Simulator(p1, "jones2016", 1e-3)
        sim2.state = sim.state  # the node keeps the state across a physics change
        want = [sim2.step(1.0, 500.0) for _ in range(4)]
        assert_same(lockstep_states(cli, js, [1.0] * 4, 4), want)

        for bad, reason in [({"max_effort": -1.0}, "max_effort out of range"),  # rclpy checks the declared range first
                            ({"physics.friction.viscous_n_s_m": -3.0}, "friction.viscous_n_s_m = -3.0: must be"),
                            ({"physics.geometry.n_rollers": 8}, "changes the internal-load layout"),
                            ({"timeout_behaviour": "explode"}, "must be one of zero, hold"),
                            ({"load_force": 1.0, "max_effort": "big"}, "parameter max_effort = 'big'"),
                            ({"update_rate": 500}, "read-only")]:
            res = cli.set_parameters(bad)
            assert not res.successful and reason in res.reason, (bad, res.reason)
        after = cli.get_parameters(["load_force", "max_effort", "physics.friction.viscous_n_s_m", "update_rate",
                                    "physics.geometry.n_rollers"])
        assert after == {"load_force": 500, "max_effort": 50.0, "physics.friction.viscous_n_s_m": 10,
                         "update_rate": 1000, "physics.geometry.n_rollers": 10}
        want = [sim2.step(1.0, 500.0) for _ in range(3)]  # nothing changed: same dynamics, same load
        assert_same(lockstep_states(cli, js, [1.0] * 3, 8), want)
        assert proc.stop() == 0


def test_namespace_and_topic_parameters_move_the_topics(tmp_path):
    """Topic names are relative: a namespace moves them all; topics.* renames one; /clock stays global."""
    with NodeProcess(ENV, {"record": False, "topics.joint_states": "measured_states"}, workdir=tmp_path,
                     extra_args=["--ros-args", "-r", "__ns:=/left"]) as proc, \
            RosClient(ENV, node_name="left/prsm_actuator") as cli:
        cli.wait_for_node(proc)
        expected = {"/left/prsm_actuator/screw_torque", "/left/prsm_actuator/joint_commands", "/left/measured_states",
                    "/left/prsm_actuator/nut/wrench", "/left/prsm_actuator/internal_loads/labels", "/clock",
                    "/diagnostics"}

        def names():
            return {n for n, _ in cli.node.get_topic_names_and_types()}
        cli.spin_until(lambda: expected <= names(), 10.0, f"topics {sorted(expected)}")  # discovery is gradual
        assert "/joint_states" not in names() and "/left/joint_states" not in names()
        assert proc.stop() == 0


def _start(tmp_path, *ros_args: str):
    import subprocess
    import sys
    from ros_procs import CEILING_FACTOR
    return subprocess.run([sys.executable, "-m", "prsm_ros.cli.node", "--urdf", "--ros-args", *ros_args],
                          env=ENV, cwd=tmp_path, capture_output=True, text=True, timeout=60 * CEILING_FACTOR)


@pytest.mark.slow
def test_params_files_broken_missing_wildcard_and_for_another_node(tmp_path):
    """One line and exit 2 for a file that cannot be read; warnings (not errors) for names in a `/**`
    section and for a file with no section for this node; rclpy's own parameters accepted."""
    (tmp_path / "broken.yaml").write_text("prsm_actuator:\n  ros__parameters: [\n", encoding="utf-8")
    (tmp_path / "multi.yaml").write_text(
        "/**:\n  ros__parameters:\n    use_sim_time: false\n    other_nodes_gain: 3.0\n"
        "prsm_actuator:\n  ros__parameters:\n    max_effort: 20.0\n", encoding="utf-8")
    (tmp_path / "other.yaml").write_text("controller:\n  ros__parameters:\n    gain: 1.0\n"
                                         "/robot/arm:\n  ros__parameters:\n    x: 1\n", encoding="utf-8")
    for args, says in ((["--params-file", "broken.yaml"], "--params-file broken.yaml: not valid YAML at line 3"),
                       (["--params-file", "missing.yaml"], "missing.yaml: cannot read parameters file (No such file")):
        r = _start(tmp_path, *args)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and says in r.stderr, r.stderr
    r = _start(tmp_path, "--params-file", "multi.yaml", "--params-file", "other.yaml", "-p", "use_sim_time:=false")
    assert r.returncode == 0, r.stderr
    assert "other.yaml: no section for /prsm_actuator (sections: controller, /robot/arm)" in r.stderr
    assert "parameter other_nodes_gain (multi.yaml, section /**) is not a parameter of this node; ignored" in r.stderr
    assert "use_sim_time" not in r.stderr and 'effort="20.0"' in r.stdout  # the node's own section applied


def test_a_misspelt_safety_parameter_in_the_nodes_section_is_refused(tmp_path):
    (tmp_path / "typo.yaml").write_text("prsm_actuator:\n  ros__parameters:\n    max_efort: 1.0\n", encoding="utf-8")
    r = _start(tmp_path, "--params-file", "typo.yaml")
    assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1
    assert r.stderr.strip() == ("prsm-node: error: unknown parameter max_efort (typo.yaml, section prsm_actuator); "
                                "did you mean max_effort?")


def test_fault_values_are_bounded_like_commands():
    for spec, says in (("kind=jam,value=1e300", "jam allows |value| <= 1e+06 N·m"),
                       ("kind=friction_surge,value=1e5", "friction_surge allows |value| <= 100"),
                       ("kind=jam,value=3,start_s=1e12", "fault.start_s = 1000000000000.0: must be <= 1e+09 s")):
        with pytest.raises(Exception, match="parameter faults: ") as e:
            NodeConfig.from_values({"faults": spec})
        assert says in str(e.value)


def test_nested_faults_are_checked_and_bounded_under_their_own_name():
    base = {"faults.j.kind": "jam", "faults.j.value": 30}
    cfg = NodeConfig.from_values({**base, "faults.j.start_s": "2", "faults.j.duration_s": "inf"})
    assert cfg.with_actuator and [(f.kind, f.start_s, f.duration_s, f.value) for f in cfg.actuator.faults] == \
        [("jam", 2.0, math.inf, 30.0)]
    for extra, says in (({"faults.j.value": 1e300},
                         "parameter faults.j: fault.value = 1e+300: jam allows |value| <= 1e+06 N·m"),
                        ({"faults.j.roller": 1}, "parameter faults.j: fault.roller = 1: model 'jones2016' treats all "
                                                 "rollers alike"),
                        ({"faults.j.kind": "jammed"}, "parameter faults.j: fault.kind = 'jammed': must be one of"),
                        ({"faults.j.start_s": "soon"}, "parameter faults.j.start_s = 'soon': must be a number")):
        with pytest.raises(ConfigError) as e:
            NodeConfig.from_values({**base, **extra})
        assert str(e.value).startswith(says), str(e.value)
    # a fault without a kind is refused, naming it
    with pytest.raises(ConfigError, match=r"^parameter faults.k: fault.kind = None: is required"):
        NodeConfig.from_values({"faults.k.value": 3.0})


@pytest.mark.parametrize("allowed, cpu, refusal", [
    ({0, 1, 2, 3}, 3, None),
    ({0, 1, 2, 3}, -1, None),
    ({0, 2}, 1, "parameter step_thread_cpu = 1: must be -1 or one of the CPUs this process may run on (0, 2)"),
    ({0}, 0, "parameter step_thread_cpu = 0: must be -1 here: this process may run on CPU 0 only, and the node's "
             "other threads need a CPU besides the step thread's"),
    ({5}, -1, None),
])
def test_the_step_threads_cpu_is_one_this_process_may_use_with_another_left(monkeypatch, allowed, cpu, refusal):
    """The OS's affinity mask stood in for (the node process test reads the real one: test_node_realtime)."""
    from prsm_ros.node import scheduling
    monkeypatch.setattr(scheduling, "allowed_cpus", lambda: frozenset(allowed))
    if refusal is None:
        assert NodeConfig.from_values({"step_thread_cpu": cpu}).step_thread_cpu == cpu
    else:
        with pytest.raises(ConfigError) as e:
            NodeConfig.from_values({"step_thread_cpu": cpu})
        assert str(e.value) == refusal
