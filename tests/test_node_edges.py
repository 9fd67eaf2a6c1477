"""Nothing a participant sends can stop the node: every service and settable parameter at its edges,
over DDS, against a real `prsm-node` process.

- `initial_nut_position` is checked at runtime as at start-up (on the threads): `1.0` m on the s30
  screw (travel ±0.135 m: (0.3 − 0.03) m / 2) is refused, and `~/reset` afterwards answers and the node steps on.
- Every settable parameter (node and `physics.*`) set to its bounds, past them, NaN, ±inf, the
  wrong type; every service called in between; a parameter named "": the node answers each, never
  exits, and steps afterwards (joint_states arrive again).
- Lockstep work is bounded: with `lockstep_steps` at its maximum, commands beyond the backlog are
  refused (`lockstep_backlog` on ~/events) and the steps waiting never exceed the stated cap.
- `params_file` takes the place of `preset` (its values are the physics.* defaults, `-p physics.*`
  applies on top); an unreadable or invalid file is one line and exit 2.
- Malformed ROS arguments are one line and exit 2, not an RCLError traceback.
- Two nodes with the same name: each says so on stderr and ~/events (`duplicate_node_name`).

Oracles: the s30 preset's thread travel (screw 0.3 m − nut 0.03 m), the parameter ranges the node
declares (`parameters.node_parameters`), `step_jobs.LOCKSTEP_BACKLOG_STEPS`.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import weakref

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from ros_procs import CEILING_FACTOR, NodeProcess, RosClient, diagnostics_of, ros_test_env  # noqa: E402

ENV = ros_test_env("test_node_edges")
NODE = "/prsm_actuator"


def start(tmp_path, name: str = "node", **params) -> NodeProcess:
    base = {"record": False, "diagnostics_rate": 20.0}
    return NodeProcess(ENV, {**base, **params}, workdir=tmp_path / name)


def alive(proc) -> None:
    assert proc.proc.poll() is None, f"node exited with {proc.proc.returncode}:\n{proc.stderr}"


def set_one(cli, name: str, value):
    """SetParameters (not atomic) with one value: the node's verdict."""
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter
    req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return call(cli, "set_parameters", SetParameters, req).results[0]


# per RosClient, held weakly: keyed by id(), a later test's client reusing a destroyed one's address got its
# destroyed service clients ("cannot use Destroyable because destruction was requested")
_CLIENTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def call(cli, name: str, srv, request=None, timeout: float = 10.0):
    """A service call through one client per service, kept for the test: a client made per call
    races the server matching its response reader (a busy node may answer into the void)."""
    clients = _CLIENTS.setdefault(cli, {})
    client = clients.get(name)
    if client is None:
        client = clients[name] = cli.node.create_client(srv, f"{NODE}/{name}")
        cli.spin_until(client.service_is_ready, timeout, f"service ~/{name}")
    future = client.call_async(request if request is not None else srv.Request())
    cli.spin_until(future.done, timeout, f"the response of ~/{name}")
    return future.result()


def call_every_service(cli) -> None:
    """Each service once, in an order that leaves the node running; every call is answered."""
    from std_srvs.srv import SetBool, Trigger
    for name, srv, req in (("pause", SetBool, SetBool.Request(data=True)), ("step", Trigger, None),
                           ("brake", SetBool, SetBool.Request(data=True)), ("brake", SetBool, SetBool.Request(data=False)),
                           ("clear_faults", Trigger, None), ("release_control", Trigger, None), ("reset", Trigger, None),
                           ("pause", SetBool, SetBool.Request(data=False))):
        res = call(cli, name, srv, req)
        assert isinstance(res.message, str)


@pytest.mark.slow
def test_initial_nut_position_off_the_threads_is_refused_and_reset_still_works(tmp_path):
    """The issue's two commands: `param set initial_nut_position 1.0` then `reset`."""
    from std_srvs.srv import Trigger
    with start(tmp_path, time_mode="lockstep") as proc, RosClient(ENV) as cli:
        cli.wait_for_node(proc)
        res = set_one(cli, "initial_nut_position", 1.0)
        assert not res.successful and "must lie on the threads" in res.reason and "0.135" in res.reason, res.reason
        assert cli.get_parameters(["initial_nut_position"]) == {"initial_nut_position": 0.0}
        res = call(cli, "reset", Trigger)
        assert res.success, res.message
        assert set_one(cli, "initial_nut_position", 0.1).successful  # on the threads: taken
        assert call(cli, "reset", Trigger).success
        alive(proc)
        assert proc.stop() == 0


def _edge_values(p) -> list:
    """Values at and past a node parameter's limits, and of the wrong kind."""
    if isinstance(p.default, str):
        return [*(p.choices or ()), "bogus", "", 3, True]
    hi = p.hi if p.hi is not None else 1e6
    lo = p.lo if p.lo is not None else -1e6
    values = [lo, hi, hi * 10 + 1, lo - 1, math.nan, math.inf, -math.inf, "text", True]
    return [int(v) if isinstance(p.default, int) and isinstance(v, float) and math.isfinite(v) else v
            for v in values]


def _physics_values(default) -> list:
    if isinstance(default, str):
        return ["bogus", "", 1.0]
    if isinstance(default, bool):
        return [not default, 3]
    return [0, -1, 1e300, math.nan, math.inf, "text"] + ([10 ** 9] if isinstance(default, int) else [])


@pytest.mark.slow  # a node process and many requests (10-20 s)
def test_every_service_and_settable_parameter_at_its_edges_leaves_the_node_stepping(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray

    from prsm_ros.node.parameters import node_parameters
    settable = [p for p in node_parameters() if not p.read_only]
    with start(tmp_path, model="jones2016", joint_states_rate=100.0) as proc, RosClient(ENV) as cli:
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        cli.wait_for_node(proc)
        refused = accepted = 0
        for p in settable:
            for v in _edge_values(p):
                res = set_one(cli, p.name, v)
                refused, accepted = refused + (not res.successful), accepted + res.successful
                alive(proc)
            call_every_service(cli)
            assert set_one(cli, p.name, p.default).successful, p.name
            alive(proc)
        physics = {k: v for k, v in cli.get_parameters(_physics_names(cli)).items()}
        for name, default in physics.items():
            for v in _physics_values(default):
                set_one(cli, name, v)
                alive(proc)
            call_every_service(cli)
            res = set_one(cli, name, default)
            assert res.successful, (name, res.reason)
        res = set_one(cli, "", 1.0)  # a parameter named "" is no parameter of the node
        assert not res.successful
        assert "" not in cli.get_parameters([""]) or cli.get_parameters([""])[""] is None
        assert refused > 0 and accepted > 0
        call_every_service(cli)
        def steps() -> int:
            counts = [int(v["steps"]) for _, _, v in map(diagnostics_of, diag) if "steps" in v]
            return counts[-1] if counts else -1
        n = steps()
        cli.spin_until(lambda: steps() > n + 100, 20.0, "steps after the sweep (the step thread lives)")
        alive(proc)
        assert proc.stop() == 0


def _physics_names(cli) -> list[str]:
    from rcl_interfaces.srv import ListParameters
    res = cli.call(f"{NODE}/list_parameters", ListParameters, ListParameters.Request(prefixes=["physics"], depth=0))
    return sorted(res.result.names)


@pytest.mark.slow  # a node process and many requests (10-20 s)
def test_lockstep_backlog_is_bounded_with_a_refusal(tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64, String

    from prsm_ros.node.step_jobs import LOCKSTEP_BACKLOG_STEPS
    with start(tmp_path, time_mode="lockstep", lockstep_steps=1_000_000, model="ideal", cmd_timeout=0.0) as proc, \
            RosClient(ENV) as cli:
        events = cli.subscribe(f"{NODE}/events", String)
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        cli.publisher(f"{NODE}/screw_torque", Float64)
        cli.wait_for_node(proc)
        for _ in range(6):
            cli.publish(f"{NODE}/screw_torque", Float64(data=0.0))
        cli.spin_until(lambda: any(json.loads(m.data)["code"] == "lockstep_backlog" for m in events), 20.0,
                       "the lockstep_backlog refusal")
        mine = [d for d in (diagnostics_of(m) for m in diag) if "step_jobs_steps_waiting" in d[2]]
        cli.spin_until(lambda: len([m for m in diag if "step_jobs_steps_waiting" in diagnostics_of(m)[2]]) > len(mine),
                       20.0, "a diagnostics report")
        waiting = [int(diagnostics_of(m)[2]["step_jobs_steps_waiting"]) for m in diag
                   if "step_jobs_steps_waiting" in diagnostics_of(m)[2]]
        assert max(waiting) <= LOCKSTEP_BACKLOG_STEPS
        refused = [int(diagnostics_of(m)[2]["lockstep_commands_refused_backlog"]) for m in diag
                   if "lockstep_commands_refused_backlog" in diagnostics_of(m)[2]]
        assert max(refused) >= 1
        alive(proc)
        assert proc.stop() == 0


@pytest.mark.slow  # a node process and many requests (10-20 s)
def test_params_file_takes_the_place_of_preset_and_physics_apply_on_top(tmp_path):
    from prsm_sim import preset

    from prsm_ros.param_files import params_to_yaml
    p = preset("s30").with_overrides({"mass.moved_mass_kg": 7.5, "friction.mu_pin": 0.02})
    path = tmp_path / "plant.yaml"
    path.write_text(params_to_yaml(p))
    with start(tmp_path, params_file=str(path), time_mode="lockstep", **{"physics.friction.mu_pin": 0.03}) as proc, \
            RosClient(ENV) as cli:
        cli.wait_for_node(proc)
        got = cli.get_parameters(["physics.mass.moved_mass_kg", "physics.friction.mu_pin", "params_file"])
        assert got == {"physics.mass.moved_mass_kg": 7.5, "physics.friction.mu_pin": 0.03, "params_file": str(path)}
        res = set_one(cli, "params_file", "other.yaml")
        assert not res.successful  # read-only: a new file is a new run
        assert proc.stop() == 0
    bad = tmp_path / "bad.yaml"
    bad.write_text("geometry: {pitch_m: -1}\n")
    for target, words in ((bad, "params_file"), (tmp_path / "missing.yaml", "params_file")):
        res = _run_node(["-p", f"params_file:={target}", "-p", "record:=false"])
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 2 and len(lines) == 1 and words in lines[0] and str(target) in lines[0], res.stderr


def _run_node(ros: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "prsm_ros.node", "--ros-args", *ros], env=ENV, capture_output=True,
                          text=True, timeout=60 * CEILING_FACTOR)


SLOW = pytest.mark.slow  # a process each; tests/test_node_bounds_units.py checks every case without one


@pytest.mark.parametrize("ros, words", [
    (["-p", "record_path:="], "no value after :="),
    pytest.param(["-p", "record:=false", "-p"], "expected NAME:=VALUE", marks=SLOW),
    pytest.param(["-r", "__ns:=bad//ns"], "not a valid namespace", marks=SLOW),
    pytest.param(["-p", ":=3"], "expected NAME:=VALUE", marks=SLOW),
], ids=["empty-value", "trailing-p", "bad-namespace", "empty-name"])
def test_malformed_ros_arguments_are_one_line_and_exit_2(ros, words):
    res = _run_node(ros)
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2 and len(lines) == 1 and lines[0].startswith("prsm-node: error:") and words in lines[0], \
        res.stderr
    assert "Traceback" not in res.stderr and "RCLError" not in res.stderr


@pytest.mark.slow  # a node process and many requests (10-20 s)
def test_two_nodes_with_one_name_say_so(tmp_path):
    from std_msgs.msg import String
    with start(tmp_path, "a", time_mode="lockstep") as a, RosClient(ENV) as cli:
        events = cli.subscribe(f"{NODE}/events", String)
        cli.wait_for_node(a)
        with start(tmp_path, "b", time_mode="lockstep") as b:
            cli.spin_until(lambda: any(json.loads(m.data)["code"] == "duplicate_node_name" for m in events), 30.0,
                           "a duplicate_node_name event")
            cli.spin_until(lambda: "2 nodes named /prsm_actuator" in a.stderr + b.stderr, 30.0, "the error line")
            alive(a)
            alive(b)
            assert b.stop() == 0
        assert a.stop() == 0
