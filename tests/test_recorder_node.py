"""A short real node run (prsm-node + a controller process over DDS) leaves an MCAP that passes
`rerun mcap check`, holds what was published and received, and `prsm-bag report` turns into
plots and metrics."""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from prsm_ros.cli.bag import main as bag_main
from prsm_ros.bag.reader import open_bag
from ros_domains import domain_id

BIN = Path(sys.executable).parent
RERUN = shutil.which("rerun") or str(BIN / "rerun")
ENV = {**os.environ, "RERUN": "off", "PYTHONUNBUFFERED": "1", "ROS_DOMAIN_ID": str(domain_id("test_recorder_node")),
       "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}

# A controller under test: waits for the node's joint states, then for ~1.5 s sends a PD torque
# on the nut position toward a 1 mm sine reference, and publishes the reference so it lands in the bag.
_CONTROLLER = """
    import json, math, time
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Header
    rclpy.init()
    node = rclpy.create_node("pd_controller")
    state = {"x": None, "v": 0.0, "sent": []}
    def on_js(m):
        state["x"], state["v"], state["stamp"] = m.position[1], m.velocity[1], m.header.stamp
    node.create_subscription(JointState, "/joint_states", on_js, 10)
    received = []  # the node's own count of commands received, from /diagnostics
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: received.append(
        int({kv.key: kv.value for kv in m.status[0].values}["commands_received"])), 10)
    tau_pub = node.create_publisher(Float64, "/prsm_actuator/screw_torque", 1)
    ref_pub = node.create_publisher(JointState, "/prsm_actuator/nut_position_reference", 10)
    # discovery matches each direction on its own: wait for the node's states AND for the node to
    # listen to both our topics, or the first commands go nowhere on a busy machine
    end = time.monotonic() + 60
    while (state["x"] is None or tau_pub.get_subscription_count() == 0 or ref_pub.get_subscription_count() == 0) \
            and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.5:
        rclpy.spin_once(node, timeout_sec=0.0)
        ref = 1e-3 * math.sin(2 * math.pi * (time.monotonic() - t0))
        # s30: J ≈ 2.4e-4 kg·m², lead 0.8 mm/rad → 10 Hz, ζ 0.7 in nut-position terms; the 200 N
        # load torque (F·L/2π) fed forward
        tau = 200.0 * 0.0008 + 1170.0 * (ref - state["x"]) - 26.0 * state["v"]
        ref_pub.publish(JointState(header=Header(stamp=state["stamp"]), name=["nut_joint"], position=[ref], velocity=[0.0], effort=[0.0]))
        tau_pub.publish(Float64(data=tau))
        state["sent"].append(tau)
        time.sleep(0.005)
    n = len(received)  # one report after the last command: the node's count includes what it took of ours
    end = time.monotonic() + 120
    while len(received) <= n + 1 and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps({"sent": state["sent"], "received": max(received, default=0)}), flush=True)
"""


@pytest.mark.slow
def test_node_run_records_an_mcap_that_checks_clean_and_reports(tmp_path, capsys):
    bag = tmp_path / "node_run.mcap"
    node = subprocess.Popen([str(BIN / "prsm-node"), "--ros-args", "-p", f"record_path:={bag}",
                             "-p", "load_force:=200.0", "-p", "cmd_timeout:=0.2"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=ENV)
    try:
        ctrl = subprocess.run([sys.executable, "-c", textwrap.dedent(_CONTROLLER)], capture_output=True, text=True,
                              env=ENV, timeout=360)
        assert ctrl.returncode == 0, ctrl.stderr
        # no wait here: the controller ended on the node's /diagnostics report after its last command,
        # so the node has taken every command it will take; SIGINT then closes the bag with all of them
        sent, received = json.loads(ctrl.stdout)["sent"], json.loads(ctrl.stdout)["received"]
    finally:
        node.send_signal(signal.SIGINT)
        try:
            out, _ = node.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            node.kill()
            out, _ = node.communicate()
    assert node.returncode == 0, out

    res = subprocess.run([RERUN, "mcap", "check", str(bag)], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    rows = [ln.split() for ln in res.stdout.splitlines() if ln.split() and ln.split()[0] in ("ok", "warn", "error")]
    assert rows and all(r[0] == "ok" and r[-1] == "—" for r in rows), res.stdout

    b = open_bag(bag)
    assert b.complete and b.profile == "ros2"
    assert b.run_metadata["model"] and "record_path" in b.run_metadata["node_parameters_yaml"]
    counts = {t: i.count for t, i in b.topics.items()}
    assert counts["/prsm_actuator/internal_loads/labels"] == 1
    assert counts["/joint_states"] == counts["/clock"] > 1000  # every step, realtime at 1 kHz
    # the commands in the bag are those the controller sent, in order (a subscription of depth 1
    # skips some when the node is busy, so the recorded list is an ordered subsequence), and every
    # command the node reported receiving on /diagnostics is in it (how many it skips depends on the
    # machine's load, what it records does not)
    recorded = [m.msg.data for m in b.messages(["/prsm_actuator/screw_torque"])]
    it = iter(sent)
    assert all(any(v == s for s in it) for v in recorded)
    assert len(recorded) >= received > 0, (len(recorded), received, len(sent))
    assert 0 < counts["/prsm_actuator/nut_position_reference"] <= len(sent)
    clock = [m.msg.clock.sec * 10**9 + m.msg.clock.nanosec for m in b.messages(["/clock"])]
    assert clock == sorted(clock) and [m.log_time_ns for m in b.messages(["/clock"])] == clock

    rc = bag_main(["report", str(bag), "-o", str(tmp_path / "report"), "--json"])
    r = json.loads(capsys.readouterr().out)
    assert rc == 0
    tr = r["tracking"]
    # the 1 mm sine the controller sent, as sampled (a busy machine samples it coarsely): the span of
    # the recorded references, read from the bag here, and never more than the sine's 2 mm
    refs = [m.msg.position[0] for m in b.messages(["/prsm_actuator/nut_position_reference"])]
    assert tr["reference_span_m"] == pytest.approx(max(refs) - min(refs), rel=1e-12) and 0 < tr["reference_span_m"] <= 2e-3
    assert 0 < tr["rms_error_m"] <= tr["max_error_m"]
    assert r["efficiency"]["forward"] is not None and 0 < r["efficiency"]["forward"] < 1
    assert r["life"]["l10_revolutions"] > 0 and r["peak_loads"]
    assert {Path(p).name for p in r["plots"]} >= {"motion.png", "loads.png", "power.png", "internal_loads.png"}
    for p in r["plots"]:
        assert Path(p).read_bytes()[:4] == b"\x89PNG"
