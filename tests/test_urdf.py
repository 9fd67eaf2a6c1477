"""The actuator's URDF (`prsm-node --urdf`, `robot_description`) and the README's command lines as a shell runs them.

Oracles: the node's own messages (joint names and coordinates of `joint_states`, the wrench's
frame), read by an independent URDF library (yourdfpy) from the description the node publishes;
the README's sign convention (a positive nut position is the body's −z for right-hand threads,
x_nut = (L/2π) θ_S); the stop given as a nested parameter on the command line, seen in the URDF
limit and by `prsm-ctl param get`. The shell tests run real `bash -c` command lines, so the
quoting a user types is what is tested, not a Python dict.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)
import yourdfpy  # likewise

from prsm_sim import preset  # noqa: E402
from ros_procs import CEILING_FACTOR, NodeProcess, RosClient, ros_test_env  # noqa: E402

ENV = ros_test_env("test_urdf")
NODE = [sys.executable, "-m", "prsm_ros.cli.node"]
SHELL_ENV = {**ENV, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}


def load(text: str):
    return yourdfpy.URDF.load(io.BytesIO(text.encode()), load_meshes=False)


def urdf_of(*ros_args: str) -> str:
    r = subprocess.run(NODE + ["--urdf", "--ros-args", *ros_args], env=ENV, capture_output=True, text=True,
                       timeout=60 * CEILING_FACTOR)
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.mark.slow
def test_urdf_against_the_node_messages_and_a_nested_stop(tmp_path, capsys):
    from std_msgs.msg import Float64
    from prsm_ros.cli import ctl

    params = {"model": "ideal", "preset": "s30", "time_mode": "lockstep", "record": False, "cmd_timeout": 0.0,
              "actuator.motor.fitted": True, "actuator.stops.max_position_m": 0.1}
    with lockstep_node(tmp_path, params, "/prsm_actuator/screw_torque", [Float64(data=2.0)] * 3) as (proc, desc, js,
                                                                                                       wrench):
        # prsm-ctl sees the nested stop given with -p
        saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
        os.environ.update({k: ENV[k] for k in saved})
        try:
            assert ctl.main(["--timeout", str(10 * CEILING_FACTOR), "param", "get",
                             "actuator.stops.max_position_m"]) == 0
        finally:
            os.environ.update({k: v for k, v in saved.items() if v is not None})
        assert capsys.readouterr().out.strip() == "0.1"

    text = desc[-1].data
    assert text == urdf_of(*(a for k, v in params.items() for a in ("-p", f"{k}:={_ros(v)}")))
    u = load(text)
    assert set(u.joint_names) == set(js[-1].name) == {"screw_joint", "nut_joint"}
    screw, nut = u.joint_map["screw_joint"], u.joint_map["nut_joint"]
    assert screw.type == "continuous" and list(screw.axis) == [0, 0, 1]
    assert nut.type == "prismatic" and list(nut.axis) == [0, 0, -1]
    # the stop from -p, and the thread end on the side without a stop
    geo = preset("s30").geometry
    travel = getattr(geo, "travel_m", geo.screw_length_m)
    assert (nut.limit.lower, nut.limit.upper) == (pytest.approx(-0.5 * travel), 0.1)
    assert wrench[-1].header.frame_id == nut.child == "nut_link" and u.base_link == screw.parent == nut.parent
    # the description's frames follow the node's coordinates: nut at z = −x_nut, x_nut = (L/2π) θ_S
    last = js[-1]
    theta, x_nut = last.position[list(last.name).index("screw_joint")], last.position[list(last.name).index("nut_joint")]
    assert x_nut > 0 and x_nut == pytest.approx(geo.lead_per_rad_m * theta, rel=1e-12)
    u.update_cfg({"screw_joint": theta, "nut_joint": x_nut})
    nut_z = u.get_transform("nut_link", u.base_link)[2, 3]
    screw_rot = u.get_transform("screw_link", u.base_link)[:2, :2]
    assert nut_z == pytest.approx(-x_nut, rel=1e-12)
    assert screw_rot[1, 0] == pytest.approx(math.sin(theta), abs=1e-12)  # right-handed about +z
    # ros2_control: the topic-based system on the node's topics, the active interface commanded
    assert "<plugin>joint_state_topic_hardware_interface/JointStateTopicSystem</plugin>" in text
    assert ">/prsm_actuator/joint_commands<" in text and ">/joint_states<" in text
    assert '<command_interface name="effort">' in text
    # masses from the parameters: the nut link moves the load mass and the rollers
    m = preset("s30").mass
    assert u.link_map["nut_link"].inertial.mass == pytest.approx(m.moved_mass_kg + geo.n_rollers * m.roller_mass_kg)


@contextlib.contextmanager
def lockstep_node(tmp_path, params: dict, topic: str, commands: list):
    """A lockstep node sent `commands` on `topic`, one state each: (process, descriptions, states, wrenches)."""
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    with NodeProcess(ENV, params, workdir=tmp_path / "run") as proc, RosClient(ENV) as cli:
        desc = cli.subscribe("/robot_description", String)
        js = cli.subscribe("/joint_states", JointState)
        wrench = cli.subscribe("/prsm_actuator/nut/wrench", WrenchStamped)
        cli.publisher(topic, type(commands[0]))
        cli.wait_for_node(proc)
        cli.spin_until(lambda: desc, 10.0, "robot_description (transient local)")
        for k, msg in enumerate(commands):
            cli.publish(topic, msg)
            cli.spin_until(lambda: len(js) > k and len(wrench) > k, 10.0, f"state {k + 1}")
        yield proc, desc, js, wrench
        assert proc.stop() == 0, proc.stderr


def _ros(v) -> str:
    return ("true" if v else "false") if isinstance(v, bool) else str(v)


def shell(cmd: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", "-c", cmd], env=SHELL_ENV, cwd=cwd, capture_output=True, text=True,
                          timeout=60 * CEILING_FACTOR)


ROS_DOC = Path(__file__).resolve().parent.parent / "docs" / "ros.md"


def doc_command_lines() -> list[str]:
    """The `prsm-node --urdf` lines of docs/ros.md, as written."""
    return [line.strip() for line in ROS_DOC.read_text(encoding="utf-8").splitlines()
            if line.startswith("prsm-node --urdf")]


def doc_params_file() -> str:
    import re
    return re.search(r"^```yaml\n(prsm_actuator:.*?)^```", ROS_DOC.read_text(encoding="utf-8"), re.S | re.M).group(1)


@pytest.mark.slow
@pytest.mark.parametrize("line", doc_command_lines() + ["prsm-node --urdf --ros-args --params-file actuator.yaml"],
                         ids=["nested -p", "quoted string form", "nested params file"])
def test_documented_actuator_command_lines_in_a_shell(tmp_path, line):
    (tmp_path / "actuator.yaml").write_text(doc_params_file(), encoding="utf-8")
    r = shell(line.replace("prsm-node", shlex.join(NODE), 1), tmp_path)
    assert r.returncode == 0, r.stderr
    nut = load(r.stdout).joint_map["nut_joint"]
    # the stop at 0.0, and the thread end (±0.135 m for s30) before the stop at 0.3 beyond it
    assert (nut.limit.lower, nut.limit.upper) == (0.0, pytest.approx(0.135))
    assert '<command_interface name="velocity">' in r.stdout  # the screw's speed is commanded
    # the motor is fitted: its rotor joins the screw's inertia about z
    screw = load(r.stdout).link_map["screw_link"].inertial.inertia
    assert screw[2, 2] > preset("s30").mass.screw_inertia_kgm2


def test_the_old_readme_form_is_refused_in_one_line(tmp_path):
    r = shell(f"{shlex.join(NODE)} --ros-args -p actuator:=\"{{motor: {{}}}}\"", tmp_path)
    assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1
    assert "rcl cannot read a YAML mapping" in r.stderr and "actuator.motor.fitted:=true" in r.stderr


@pytest.mark.slow
def test_joint_and_frame_names_from_parameters(tmp_path):
    """Renamed joints reach the node's joint_states, the wrench frame and the URDF alike."""
    from sensor_msgs.msg import JointState
    params = {"model": "ideal", "time_mode": "lockstep", "record": False, "joints.screw": "left_screw",
              "joints.nut": "left_nut", "frames.nut": "left_nut_link", "frames.base": "left_base"}
    command = JointState(name=["left_screw"], effort=[1.0])
    with lockstep_node(tmp_path, params, "/prsm_actuator/joint_commands", [command]) as (proc, desc, js, wrench):
        pass
    assert list(js[0].name) == ["left_screw", "left_nut"] and js[0].effort[0] == 1.0  # the command was taken
    u = load(desc[-1].data)
    assert set(u.joint_names) == {"left_screw", "left_nut"} and u.base_link == "left_base"
    assert wrench[0].header.frame_id == u.joint_map["left_nut"].child == "left_nut_link"


@pytest.mark.slow
def test_a_nested_fault_from_a_shell_command_line_jams_the_running_node(tmp_path):
    """`-p faults.<name>.<field>:=…` typed in a shell reaches the running node: the jam starts at
    t = 0 on ~/events with the values given (the string list's form adds a second fault)."""
    import json
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    line = (f"exec {shlex.join(NODE)} --ros-args -p model:=ideal -p time_mode:=lockstep -p record:=false "
            "-p faults.stuck.kind:=jam -p faults.stuck.start_s:=0.0 -p faults.stuck.value:=30 "
            "-p faults.stuck.duration_s:=.inf -p faults:=\"kind=friction_surge,value=2\"")
    (tmp_path / "run").mkdir()
    with open(tmp_path / "run" / "stderr", "wb") as err:
        proc = subprocess.Popen(["bash", "-c", line], env=SHELL_ENV, cwd=tmp_path / "run", stdout=subprocess.DEVNULL,
                                stderr=err)
    try:
        with RosClient(ENV) as cli:
            events = cli.subscribe("/prsm_actuator/events", String)
            cli.publisher("/prsm_actuator/joint_commands", JointState)
            cli.wait_for_node()
            cli.publish("/prsm_actuator/joint_commands", JointState(name=["screw_joint"], effort=[1.0]))
            starts = lambda: [d for d in map(json.loads, (m.data for m in events)) if d.get("code") == "fault_start"]
            cli.spin_until(lambda: len(starts()) >= 2, 10.0, "two fault_start events")
    finally:
        proc.send_signal(2)
        rc = proc.wait(timeout=20 * CEILING_FACTOR)
    assert rc == 0, (tmp_path / "run" / "stderr").read_text()
    jam = next(d for d in starts() if d["details"]["kind"] == "jam")
    assert jam["details"]["value"] == 30.0 and jam["details"]["duration_s"] is None and jam["time_s"] == 0.0
    assert {d["details"]["kind"] for d in starts()} == {"jam", "friction_surge"}


def test_nested_faults_in_a_params_file_combine_with_the_string_list(tmp_path):
    """Nested YAML under ros__parameters (dotted keys beside the `faults` string) as the node reads them."""
    import rclpy
    from rclpy.node import Node
    from prsm_ros.node.declare import declare_parameters
    path = tmp_path / "faults.yaml"
    path.write_text("prsm_actuator:\n  ros__parameters:\n"
                    "    faults: 'kind=sensor_bias,sensor=motor_encoder,value=0.1'\n"
                    "    faults.b:\n      kind: jam\n      start_s: 1.5\n      duration_s: 0.25\n      value: 40.0\n"
                    "    faults.a: {kind: lubrication_loss, value: 3}\n", encoding="utf-8")
    ctx = rclpy.Context()
    rclpy.init(args=["--ros-args", "--params-file", str(path)], context=ctx)
    try:
        node = Node("prsm_actuator", context=ctx, start_parameter_services=False, enable_rosout=False)
        cfg = declare_parameters(node)
        assert cfg.with_actuator
        got = [(f.kind, f.start_s, f.duration_s, f.value, f.sensor, f.roller) for f in cfg.actuator.faults]
        # the string list first, then the nested faults by name
        assert got == [("sensor_bias", 0.0, math.inf, 0.1, "motor_encoder", None),
                       ("lubrication_loss", 0.0, math.inf, 3.0, None, None),
                       ("jam", 1.5, 0.25, 40.0, None, None)]
        assert node.get_parameter("faults.b.value").value == 40.0
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def test_an_unknown_fault_field_is_refused_in_one_line(tmp_path):
    r = shell(f"{shlex.join(NODE)} --urdf --ros-args -p faults.j.kind:=jam -p faults.j.vlaue:=30", tmp_path)
    assert r.returncode == 2 and r.stdout == "" and r.stderr.count("\n") == 1
    assert "unknown parameter faults.j.vlaue" in r.stderr and "did you mean faults.j.value?" in r.stderr
