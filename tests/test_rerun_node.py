"""A real prsm-node run in Rerun save mode (`rerun:=save`), driven over DDS by a client process.

Oracle: the node's own /joint_states as received over DDS — every received message must appear in
the .rrd at its stamp with the same nut position; and the recording holds every step (consecutive
1 ms sim times from the first step, nothing dropped), with the scene at 30 Hz.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)
import rerun  # noqa: F401

from ros_procs import NodeProcess, RosClient, ros_test_env  # noqa: E402
from test_rerun_support import has_blueprint, rrd_component, rrd_rows, rrd_verify  # noqa: E402

ENV = {**ros_test_env("test_rerun_node"), "RERUN": "on"}  # the helper turns Rerun off for other tests
# A namespace of our own as well: a node of another test process that happens to share the domain
# publishes on other topics, so every /joint_states message received here is this node's.
NS = f"/rerun_test_{os.getpid()}"


@pytest.mark.slow
def test_node_run_in_save_mode_records_every_step(tmp_path):
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    rrd = tmp_path / "node.rrd"
    params = {"model": "fu2018", "preset": "s30", "record": False, "rerun": "save", "rerun_target": str(rrd),
              "load_force": 500.0, "cmd_timeout": 0.0}
    with NodeProcess(ENV, params, workdir=tmp_path / "node", extra_args=["--ros-args", "-r", f"__ns:={NS}"]) as proc:
        client = RosClient(ENV, name="rerun_test_client", node_name=f"{NS[1:]}/prsm_actuator")
        try:
            states = client.subscribe(f"{NS}/joint_states", JointState, qos=QoSProfile(depth=10_000))
            client.publisher(f"{NS}/prsm_actuator/screw_torque", Float64)
            client.publisher(f"{NS}/prsm_actuator/nut_position_reference", JointState)
            client.wait_for_node(proc)
            client.publish(f"{NS}/prsm_actuator/screw_torque", Float64(data=1.0))
            client.spin_until(lambda: len(states) > 800, timeout=20, what="800 joint states")
            # a reference answering the latest state, as a controller stamps it: the live recording plots it
            answered = states[-1]
            reference = JointState(name=["screw_joint", "nut_joint"], position=[0.0, 0.0123])
            reference.header.stamp = answered.header.stamp
            client.publish(f"{NS}/prsm_actuator/nut_position_reference", reference)
            client.publish(f"{NS}/prsm_actuator/screw_torque", Float64(data=-1.0))
            client.spin_for(0.4)
        finally:
            client.close()
        assert proc.stop() == 0, proc.stderr

    res = rrd_verify(rrd)
    assert res.returncode == 0, res.stderr
    t_ns, nut = rrd_component(rrd, "/series/nut_position_mm", "Scalars:scalars")
    n = len(t_ns)
    assert n > 1000
    np.testing.assert_array_equal(t_ns, np.arange(1, n + 1) * 1_000_000)  # every step, none dropped
    by_time = dict(zip(t_ns.tolist(), np.array(nut).ravel().tolist(), strict=True))
    for m in states:
        stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        assert by_time[stamp] == m.position[1] * 1e3  # shown in mm
    rows = rrd_rows(rrd)
    assert rows[("/series/screw_torque_nm", "Scalars:scalars")] == n
    frames = len({(k + 1) * 30 // 1000 for k in range(n)})
    assert rows[("/world/nut", "Transform3D:translation")] == frames
    assert rows[("/loads/per_tooth/screw_normal_force_n", "Tensor:data")] == frames
    _, torque = rrd_component(rrd, "/series/screw_torque_nm", "Scalars:scalars")
    assert {1.0, -1.0} <= set(np.array(torque).ravel().tolist())  # both commands reached the recording
    t_ref, ref = rrd_component(rrd, "/series/inputs/nut_position_reference", "Scalars:scalars")
    stamp = answered.header.stamp.sec * 1_000_000_000 + answered.header.stamp.nanosec
    assert t_ref.tolist() == [stamp] and np.array(ref).ravel().tolist() == [pytest.approx(12.3)]  # in mm
    assert has_blueprint(rrd)
