"""Realtime and fast runs, the pause/step/reset services, and clean shutdown on SIGINT and SIGTERM.

The MCAP file each run leaves is read back with `rosbags` (an independent reader with its own
ROS 2 type store): it must be closed (summary present) and hold one /clock per step.
"""

from __future__ import annotations

import signal

import pytest

import rclpy  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)

from ros_procs import NodeProcess, RosClient, diagnostics_of, ros_test_env  # noqa: E402

# the slow tier (.ci/run runs it after the README's test command): many node or Ray start-ups
pytestmark = pytest.mark.slow

ENV = ros_test_env("test_node_lifecycle")


def clock_ns(msg) -> int:
    return msg.clock.sec * 10**9 + msg.clock.nanosec


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def read_bag(path):
    """topic → [(log_time_ns, message)] in file (write) order, decoded with rosbags' own type store.

    Also checks the file was closed (summary present) and that rosbags' reader opens it.
    """
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    store = get_typestore(Stores.ROS2_KILTED)
    with Reader(path) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        n_rosbags = sum(1 for _ in reader.messages())
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        r = make_reader(f)
        summary = r.get_summary()
        assert summary is not None and summary.statistics is not None, "MCAP has no summary: not closed"
        for _, channel, m in r.iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((m.log_time, store.deserialize_cdr(m.data, types[channel.topic])))
    assert sum(len(v) for v in out.values()) == n_rosbags
    return out


def test_realtime_run_services_and_sigint(tmp_path):
    """Realtime pacing, pause/step/reset and SIGINT, waiting on events (generous ceilings), so a
    busy machine only makes it slower. Pacing oracle: a realtime run never gets ahead of the wall
    clock. After ~/reset the schedule restarts no earlier than our call, so every /clock received
    after it satisfies sim_time <= wall time since the call (× real_time_factor 1) + one period;
    fast mode (no pacing) breaks this within milliseconds."""
    import time

    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_srvs.srv import SetBool, Trigger
    bag = tmp_path / "rt.mcap"
    params = {"time_mode": "realtime", "diagnostics_rate": 20.0, "record_path": str(bag), "step_count": 5}
    with NodeProcess(ENV, params, workdir=tmp_path) as proc, RosClient(ENV) as cli:
        clock = cli.subscribe("/clock", Clock)
        arrivals: list[tuple[float, int]] = []  # (our monotonic receive time, sim time ns) of every /clock
        cli.node.create_subscription(Clock, "/clock", lambda m: arrivals.append((time.monotonic(), clock_ns(m))), 10000)
        js = cli.subscribe("/joint_states", JointState)
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        cli.wait_for_node(proc)
        cli.spin_until(lambda: len(clock) > 50, 10.0, "clock")

        res = cli.call("/prsm_actuator/pause", SetBool, SetBool.Request(data=True))
        assert res.success and res.message.startswith("paused at t = "), res.message
        paused_at = round(float(res.message.split()[4]) * 1e9)  # the node's own word: last step's time
        cli.spin_until(lambda: clock_ns(clock[-1]) == paused_at, 10.0, "the last /clock before the pause")
        cli.spin_for(0.3)  # absence can only be watched for: nothing steps while paused
        assert clock_ns(clock[-1]) == paused_at and max(stamp_ns(m) for m in js) <= paused_at

        res = cli.call("/prsm_actuator/step", Trigger)
        assert res.success, res.message
        stepped = [paused_at + k * 1_000_000 for k in range(1, 6)]
        cli.spin_until(lambda: clock_ns(clock[-1]) == stepped[-1] and stamp_ns(js[-1]) == stepped[-1], 10.0,
                       "5 stepped states and /clock 5 ms on")
        assert [stamp_ns(m) for m in js if stamp_ns(m) > paused_at] == stepped  # published after every step

        n_js = len(js)
        n_reset = len(clock)
        t_reset = time.monotonic()
        assert cli.call("/prsm_actuator/reset", Trigger).success
        # reset while paused publishes the reset state at once (issue 15), though nothing steps
        cli.spin_until(lambda: len(js) > n_js, 5.0, "the reset state while paused")
        assert stamp_ns(js[n_js]) == 0 and clock_ns(clock[-1]) == 0
        assert cli.call("/prsm_actuator/pause", SetBool, SetBool.Request(data=False)).success
        res = cli.call("/prsm_actuator/step", Trigger)
        assert not res.success and "not paused" in res.message
        # wait on `arrivals` itself: its deep queue may still hold a backlog of pre-pause /clocks on a
        # busy machine after the shallow `clock` queue has caught up
        cli.spin_until(lambda: arrivals[-1][1] >= 300_000_000 and clock_ns(clock[-1]) >= 300_000_000, 20.0,
                       "0.3 s of simulation after the reset")
        # the reset state (t = 0, published at once while paused), then the first step: restarted from zero
        assert clock_ns(clock[n_reset]) == 0 and clock_ns(clock[n_reset + 1]) == 1_000_000
        # the stream is reliable and in order, so what follows its last t = 0 (the reset state) was
        # published after the reset; a receive time is never early, so `ahead` is never overstated
        last_zero = max(i for i, (_, ns) in enumerate(arrivals) if ns == 0)
        assert arrivals[last_zero][0] > t_reset
        ahead = max(ns * 1e-9 - (t - t_reset) for t, ns in arrivals[last_zero:])
        print(f"realtime: sim time ahead of the wall clock since the reset at most {ahead * 1e3:.3f} ms "
              "(negative: behind)")
        assert ahead <= 1e-3, ahead  # never ahead by more than one period: paced on wall time

        m = len(diag)
        cli.spin_until(lambda: len(diag) > m + 1, 10.0, "diagnostics")
        level, text, v = diagnostics_of(diag[-1])
        # OK, or WARN for nothing but overruns (a busy machine delays steps; the pacing check is above)
        assert (level, text) == (0, "running") or (level == 1 and text.endswith("step overruns since the last report")), \
            (level, text)
        assert float(v["achieved_real_time_factor"]) > 0  # running; prsm-bench measures the pacing itself
        # the count is the writer process's report after its flush: on a busy machine it may still be 0 in a
        # report sent before that process has run, so wait for the report that counts what it wrote
        cli.spin_until(lambda: int(diagnostics_of(diag[-1])[2]["record_written"]) > 0, 20.0,
                       "a diagnostics report counting recorded messages")
        assert diagnostics_of(diag[-1])[2]["record_error"] == ""
        assert proc.stop(signal.SIGINT) == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    topics = read_bag(bag)
    clocks = [clock_ns(m) for _, m in topics["/clock"]]
    # every step's internal loads are in the bag (DDS carries them decimated); the reset state adds
    # one /clock and one joint_states at t = 0, without internal loads
    assert len(clocks) == len(topics["/joint_states"]) == len(topics["/prsm_actuator/internal_loads"]) + 1
    # one /clock per step, each 1 ms after the previous, except back to 0 (the reset state) after the reset
    restarts = [k for k in range(1, len(clocks)) if clocks[k] != clocks[k - 1] + 1_000_000]
    assert len(restarts) == 1 and clocks[restarts[0]] == 0 and clocks[0] == 1_000_000
    assert [ts for ts, _ in topics["/clock"]] == clocks  # log time = simulation time
    assert len(topics["/prsm_actuator/internal_loads/labels"]) == 1 and "/diagnostics" in topics


def fast_run(tmp_path, name: str, params: dict, stop_signal) -> tuple[dict, list[int], dict]:
    """A fast-mode node recording to `name` until a /diagnostics report counts more than 1,000 steps (the third
    report at least), stopped by `stop_signal`: (the bag's topics as `read_bag` gives them, the /clock stamps
    checked one per step, the last report's values)."""
    from diagnostic_msgs.msg import DiagnosticArray
    bag = tmp_path / name
    params = {"time_mode": "fast", "diagnostics_rate": 10.0, "record_path": str(bag), **params}
    with NodeProcess(ENV, params, workdir=tmp_path) as proc, RosClient(ENV) as cli:
        diag = cli.subscribe("/diagnostics", DiagnosticArray)
        cli.wait_for_node(proc)
        cli.spin_until(lambda: len(diag) >= 3 and int(diagnostics_of(diag[-1])[2]["steps"]) > 1000, 60.0,
                       "a diagnostics report past 1,000 steps")
        report = diagnostics_of(diag[-1])[2]
        assert proc.stop(stop_signal) == 0, proc.stderr
    topics = read_bag(bag)
    clocks = [clock_ns(m) for _, m in topics["/clock"]]
    assert clocks == [1_000_000 * (k + 1) for k in range(len(clocks))] and len(clocks) > 1000
    return topics, clocks, report


def test_fast_mode_and_sigterm(tmp_path):
    topics, clocks, report = fast_run(tmp_path, "fast.mcap", {"model": "ideal", "joint_states_rate": 100.0,
                                                              "internal_loads_rate": 10.0}, signal.SIGTERM)
    assert float(report["achieved_real_time_factor"]) > 1.0
    # decimated: joint_states every 10th step; internal loads every 100th on DDS but every step in the bag
    assert len(topics["/joint_states"]) == len(clocks) // 10
    assert len(topics["/prsm_actuator/internal_loads"]) == len(clocks)


def test_a_bag_records_the_internal_loads_at_its_own_rate_and_reports(tmp_path, capsys):
    """record_internal_loads_rate 100 Hz at 1 kHz: the bag holds the internal loads of every 10th step (stamps on
    the 10 ms grid), every other topic every step, the rate in its node parameters, and `prsm-bag report`
    reads it (the efficiency from the recorded powers). Oracle: the rate's arithmetic."""
    import json

    import yaml

    from prsm_ros.bag.reader import open_bag
    from prsm_ros.cli.bag import main as bag_main
    topics, clocks, _ = fast_run(tmp_path, "decimated.mcap", {"model": "fu2018", "load_force": 2000.0,
                                                              "record_internal_loads_rate": 100.0}, signal.SIGINT)
    bag = tmp_path / "decimated.mcap"
    assert len(topics["/joint_states"]) == len(clocks)
    loads = [ts for ts, _ in topics["/prsm_actuator/internal_loads"]]
    assert loads == [c for c in clocks if c % 10_000_000 == 0]
    b = open_bag(bag)
    assert yaml.safe_load(b.run_metadata["node_parameters_yaml"])["record_internal_loads_rate"] == 100.0
    assert bag_main(["report", str(bag), "-o", str(tmp_path / "report"), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert "power_in_w" in r["efficiency"]["source"] and r["peak_loads"]
    assert (tmp_path / "report" / "internal_loads.png").read_bytes()[:4] == b"\x89PNG"


def test_rerun_save_writes_an_rrd_that_the_rerun_cli_verifies(tmp_path):
    """rerun = save: the node's .rrd holds every step's scalar series (checked with the `rerun` CLI)."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from test_rerun_support import rrd_rows, rrd_verify
    rrd = tmp_path / "node.rrd"
    env = {**ENV, "RERUN": ""}
    params = {"time_mode": "lockstep", "lockstep_steps": 10, "record": False, "rerun": "save",
              "rerun_target": str(rrd)}
    with NodeProcess(env, params, workdir=tmp_path) as proc, RosClient(env) as cli:
        js = cli.subscribe("/joint_states", JointState)
        cli.publisher("/prsm_actuator/screw_torque", Float64)
        cli.wait_for_node(proc)
        for k in range(20):
            cli.publish("/prsm_actuator/screw_torque", Float64(data=1.0))
            cli.spin_until(lambda: len(js) >= 10 * (k + 1), 10.0, "state")
        assert proc.stop(signal.SIGINT) == 0, proc.stderr
    res = rrd_verify(rrd)
    assert res.returncode == 0, res.stderr
    rows = rrd_rows(rrd)
    assert rows[("/series/nut_position_mm", "Scalars:scalars")] == 200, sorted(rows)[:20]
