"""Joint commands as ros2_control's topic-based hardware interface writes them (no ROS needed).

Oracle: JointStateTopicSystem::write() (ros-controls/topic_based_hardware_interfaces,
joint_state_topic_hardware_interface): `name` = every joint of the <ros2_control> tag in order;
per joint, per declared command interface, its value is appended to that interface's array.
"""

from __future__ import annotations

import math

import pytest

from prsm_ros.node.joint_commands import decode_joint_command


def plugin_message(joints: list[tuple[str, list[str]]], commands: dict[tuple[str, str], float]):
    """Build (name, arrays) exactly as JointStateTopicSystem::write() packs them."""
    names, arrays = [], {"position": [], "velocity": [], "effort": []}
    for joint, interfaces in joints:
        names.append(joint)
        for itf in interfaces:
            arrays[itf].append(commands[(joint, itf)])
    return names, arrays


URDF = [("screw_joint", ["velocity", "effort"]), ("nut_joint", ["position"])]
VALUES = {("screw_joint", "velocity"): 12.5, ("screw_joint", "effort"): 0.75, ("nut_joint", "position"): 0.042}


@pytest.mark.parametrize("active,expected", [("velocity", 12.5), ("effort", 0.75), ("position", 0.042)])
def test_plugin_shaped_message_is_accepted_in_every_mode(active, expected):
    names, arrays = plugin_message(URDF, VALUES)
    assert decode_joint_command(names, arrays, active) == (expected, None)


def test_state_only_joint_listed_and_packed_velocity():
    """The issue's case: names [screw_joint, nut_joint] (nut state-only), velocity [ω]."""
    names, arrays = plugin_message([("screw_joint", ["velocity"]), ("nut_joint", [])], VALUES)
    assert arrays == {"position": [], "velocity": [12.5], "effort": []}
    assert decode_joint_command(names, arrays, "velocity") == (12.5, None)


def test_unpacked_layout_indexed_by_name():
    assert decode_joint_command(["nut_joint", "screw_joint"], {"effort": [math.nan, 1.5]}, "effort") == (1.5, None)


@pytest.mark.parametrize("names,arrays,active,says", [
    (["screw_joint", "nut_joint"], {"velocity": [3.0]}, "effort", "active command interface is 'effort'"),
    (["screw_joint"], {"position": [0.1]}, "position", "no 'nut_joint'"),
    (["screw_joint", "nut_joint", "x"], {"effort": [1.0, 2.0]}, "effort", "3 names but 2 effort values"),
    (["screw_joint", "screw_joint"], {"effort": [1.0]}, "effort", "repeat"),
    (["screw_joint"], {}, "velocity", "no velocity value"),
])
def test_refused_with_a_reason(names, arrays, active, says):
    value, reason = decode_joint_command(names, arrays, active)
    assert value is None and says in reason and "\n" not in reason


def test_gate_takes_the_active_interface_only_and_switches():
    """Oracle: the rules in command_gate's docstring (issue 14)."""
    from prsm_sim.command_gate import CommandGate
    g = CommandGate(5.0, cmd_timeout_s=0.01, interface="velocity")
    assert g.command(0.0) == 0.0
    assert "active command interface is 'velocity'" in g.offer_torque(1.0, 0.0)
    names, arrays = plugin_message(URDF, VALUES)
    assert g.offer("velocity", decode_joint_command(names, arrays, "velocity")[0], 0.0) is None
    assert g.command(0.005) == 12.5 and g.offer("velocity", 400.0, 0.005) is None and g.command(0.005) == 400.0
    assert g.command(0.05) == 0.0 and g.timed_out  # zero speed after the watchdog
    g.set_interface("position", 0.03)
    assert g.command(0.06) == 0.03  # starts from the present position; position never falls back to 0
    assert g.offer("position", 0.04, 0.06) is None and g.command(0.2) == 0.04 and g.timed_out
    # the torque sent in velocity mode is a well-formed command for the inactive interface, not a malformed one
    assert (g.counters.rejected_inactive_interface, g.counters.rejected_malformed, g.counters.accepted) == (1, 0, 3)
    assert "not a finite number" in g.offer("position", decode_joint_command(["nut_joint"], {"position": [math.inf]},
                                                                             "position")[0], 0.3)
    assert g.counters.rejected_non_finite == 1 and g.command(0.3) == 0.04
    with pytest.raises(Exception, match="command_interface = 'torque'"):
        g.set_interface("torque", 0.0)
    assert g.interface == "position"


@pytest.mark.parametrize("change,says", [
    ({"command_interface": "torque"}, "parameter command_interface = 'torque': must be one of effort, velocity, position"),
    ({"actuator": "{sensors: {linear_encoder_resolution_m: -1e-6}}"},
     "parameter actuator: sensors.linear_encoder_resolution_m = -1e-06: must be a finite number >= 0"),
    ({"faults": "kind=jam,value=5,roller=12"}, "parameter faults: fault.roller = 12: beyond n_rollers = 10"),
    ({"actuator": "{motr: {}}"}, "unknown actuator group 'motr'"),
])
def test_node_actuator_parameters_refused_in_one_line(change, says):
    """Oracle: the house rule for bad input (one line naming the parameter, value and what is allowed)."""
    from prsm_ros.node.parameters import ConfigError, NodeConfig, node_parameters
    values = {p.name: p.default for p in node_parameters()}
    with pytest.raises(ConfigError) as e:
        NodeConfig.from_values({**values, **change})
    assert says in str(e.value) and "\n" not in str(e.value)


def test_node_actuator_parameters_build_the_actuator():
    from prsm_ros.node.parameters import NodeConfig, node_parameters
    values = {p.name: p.default for p in node_parameters()}
    cfg = NodeConfig.from_values({**values, "command_interface": "position",
                                  "actuator": "{motor: {gear_ratio: 2}, stops: {max_position_m: 0.3}}",
                                  "faults": "kind=jam,start_s=1,value=5; kind=drive_fault,start_s=2,duration_s=0.1"})
    a = cfg.actuator
    assert a.motor.gear_ratio == 2.0 and a.stops.max_position_m == 0.3
    assert [f.kind for f in a.faults] == ["jam", "drive_fault"]
    # the session the node builds runs its drive in the node's command_interface
    from prsm_sim import Session
    assert Session(cfg.params, cfg.model, cfg.dt_s, a, interface="position").actuator.drive.mode == "position"
    assert NodeConfig.from_values(values).actuator.motor is None


def test_stepper_engages_the_brake_on_watchdog_and_reports_fault_events():
    """Oracle: the node's rules, without DDS — after cmd_timeout the brake engages (engage_on_watchdog);
    a fault injected now is reported by the next step; the bare model refuses a velocity interface."""
    from prsm_sim import Session, preset
    from prsm_sim.actuator import ActuatorParams, BrakeParams, Fault, MotorParams

    a = ActuatorParams(motor=MotorParams(), brake=BrakeParams(holding_torque_nm=5.0, engage_on_watchdog=True))
    st = Session(preset("s30"), "ideal", 1e-3, a, load_n=500.0, max_effort_nm=10.0, cmd_timeout_s=0.005)
    gate = st.gate
    st.offer("effort", 1.0)
    for _ in range(5):
        st.step()
    assert not st.simulator.state.brake_engaged
    for _ in range(3):
        st.step()
    assert gate.timed_out and st.simulator.state.brake_engaged
    assert st.inject(Fault("drive_fault", start_s=st.time_s, duration_s=0.002)) is None
    for _ in range(4):
        st.step()
    assert [(e.what, e.fault.kind) for e in st.take_events()] == [("start", "drive_fault"), ("clear", "drive_fault")]
    assert st.brake(False) is None and not st.simulator.state.brake_engaged
    assert st.set_interface("velocity") is None and gate.interface == "velocity"
    bare = Session(preset("s30"), "ideal", 1e-3, max_effort_nm=10.0)
    assert "runs the bare model" in bare.set_interface("velocity") and bare.gate.interface == "effort"
    assert "no actuator" in bare.inject(Fault("jam", value=1.0))
