"""Node replay: an envelope case through prsm-node in lockstep, the same session actions, the same states.

    prsm-sim envelope --seed 31 --node
    prsm-sim envelope --case envelope-out/failures/seed-31.yaml --node

The case runs here first (`run_case(case, record=True)`), through `prsm_sim.Session`, which keeps
what was asked of the session in order (each step's command and load, brake requests, pause,
resume, reset) and the true state after each step. Then a `prsm-node` in lockstep (one step per
command) is started (`python -m prsm_ros.node`, this unit's own process) with the case's parameters on a ROS domain of its own, and the actions are
replayed into it: a command on the active interface's topic per step, `load_force` set when the
load changes, `~/brake`, `~/pause` and `~/reset` as services. The node's true state after each step
(`~/ground_truth/joint_states` with an actuator, `joint_states` without) must equal the recorded one
bit for bit: the node and the envelope step the same `Session`, so a failing case found offline is
seen, the same, in the node.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path
from typing import Any

from prsm_sim.envelope import TORQUE_LIMIT_NM, initial_load_n, run_case, session_interface
from prsm_sim.errors import PrsmError

NODE = "/prsm_actuator"
COMMAND_TOPIC = {"effort": "screw_torque", "velocity": "velocity_command", "position": "position_command"}
WAIT_S = 60.0  # ceiling on waiting for one answer of the node (a busy machine only makes it slower)


class ReplayError(PrsmError, RuntimeError):
    """The node exited, did not answer, or refused a replayed request."""


def node_parameters(case: dict) -> dict[str, Any]:
    """The prsm-node parameters that build the case's session: lockstep, one step per command."""
    params: dict[str, Any] = {
        "preset": case.get("preset", "s30"), "model": case["model"], "update_rate": int(round(1.0 / case["dt_s"])),
        "time_mode": "lockstep", "lockstep_steps": 1, "cmd_timeout": 0.0, "max_effort": TORQUE_LIMIT_NM,
        "command_interface": session_interface(case), "initial_nut_position": float(case["start_m"]),
        "load_force": initial_load_n(case) or 0.0, "record": False, "command_ownership": False,
        "publish_clock": False}
    for key, value in (case.get("overrides") or {}).items():
        params[f"physics.{key}"] = value
    if case["interface"] != "torque":
        drive: dict[str, Any] = {"mode": case["interface"]}
        if case.get("loop_rate_hz"):
            drive["loop_rate_hz"] = case["loop_rate_hz"]
        act: dict[str, Any] = {"motor": {}, "drive": drive}
        if case.get("stops"):
            act["stops"] = dict(case["stops"])
        if case.get("brake"):
            act["brake"] = {"holding_torque_nm": case["brake"]["holding_torque_nm"]}
        if case.get("faults"):
            act["faults"] = [dict(f) for f in case["faults"]]
        params["actuator"] = json.dumps(act)
    return params


def replay_on_node(case: dict, workdir: Path, env: dict[str, str] | None = None) -> dict:
    """Run `case` here, replay its actions into a lockstep prsm-node, compare the states.

    `env`: the node's environment (default: this one with localhost discovery, on the user's
    ROS_DOMAIN_ID or one of this process's own, `ros_env.isolated_env`). Returns {"steps", "compared", "ok", "mismatch"
    (None or where the node's state first differs), "violations" (the offline run's)}; the node's
    output is kept in `workdir`. ReplayError when the node exits, does not answer or refuses.
    """
    from prsm_ros.ros_env import isolated_env, ros_args, start_module

    rec = run_case(case, record=True)
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    env = env or isolated_env(RERUN="off")
    with open(workdir / "node.stdout", "wb") as out, open(workdir / "node.stderr", "wb") as err:
        proc = start_module("prsm_ros.node", ros_args(node_parameters(case)), env, cwd=workdir,
                            stdout=out, stderr=err)
    try:
        mismatch, compared = _replay(case, rec, env, proc, workdir)
    finally:
        if proc.poll() is None:
            proc.send_signal(2)  # SIGINT: the node's clean exit
            try:
                proc.wait(timeout=WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    return {"steps": rec.steps, "compared": compared, "ok": mismatch is None and compared == rec.steps,
            "mismatch": mismatch, "violations": rec.violations}


def _replay(case: dict, rec, env: dict[str, str], proc, workdir: Path) -> tuple[str | None, int]:
    import rclpy
    ctx = rclpy.Context()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    rclpy.init(context=ctx, domain_id=int(env["ROS_DOMAIN_ID"]),
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    replayer = _Replayer(ctx, case, env, proc, workdir)
    try:
        return replayer.run(rec)
    finally:
        replayer.close()
        rclpy.try_shutdown(context=ctx)


class _Replayer:
    """One rclpy node that sends a case's actions to the node under test and compares its states."""

    def __init__(self, ctx, case: dict, env: dict[str, str], proc, workdir: Path) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64

        from prsm_ros.messages import TOPICS, with_depth
        self.case, self.env, self.proc, self.workdir = case, env, proc, workdir
        self.node = rclpy.create_node("prsm_envelope_replay", context=ctx)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        state_key = "ground_truth" if case["interface"] != "torque" else "joint_states"
        self.states: list = []
        self.sub = self.node.create_subscription(JointState, TOPICS[state_key].resolved(), self.states.append,
                                                 with_depth(TOPICS[state_key].qos, 10000))
        spec = TOPICS[COMMAND_TOPIC[session_interface(case)]]
        self.pub = self.node.create_publisher(Float64, f"{NODE}/{spec.name.removeprefix('~/')}", with_depth(spec.qos, 10))
        self.load = initial_load_n(case) or 0.0

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()

    def spin_until(self, done, what: str) -> None:
        end = time.monotonic() + WAIT_S
        while not done():
            if self.proc.poll() is not None:
                raise ReplayError(f"prsm-node exited with {self.proc.returncode} waiting for {what} "
                                  f"(its output: {self.workdir})")
            if time.monotonic() > end:
                raise ReplayError(f"no {what} from prsm-node within {WAIT_S:g} s (its output: {self.workdir})")
            self.executor.spin_once(timeout_sec=0.01)

    def call(self, name: str, srv, request):
        client = self.node.create_client(srv, f"{NODE}/{name}")
        try:
            self.spin_until(client.service_is_ready, f"service ~/{name}")
            future = client.call_async(request)
            self.spin_until(future.done, f"the answer of ~/{name}")
            return future.result()
        finally:
            self.node.destroy_client(client)

    def set_load(self, f: float) -> None:
        if f == self.load:
            return
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.parameter import Parameter
        req = SetParametersAtomically.Request(parameters=[Parameter("load_force", value=float(f)).to_parameter_msg()])
        res = self.call("set_parameters_atomically", SetParametersAtomically, req).result
        if not res.successful:
            raise ReplayError(f"load_force = {f}: {res.reason}")
        self.load = f

    def run(self, rec) -> tuple[str | None, int]:
        """Every recorded action in order; (where the node's state first differs or None, states compared)."""
        from std_srvs.srv import SetBool, Trigger
        pub, sub = self.pub, self.sub
        # matched both ways: a state published before our reader matched is lost (volatile QoS)
        self.spin_until(lambda: pub.get_subscription_count() > 0 and sub.get_publisher_count() > 0,
                        "a match of the command and state topics")
        if pub.get_subscription_count() != 1:  # another node on this domain would answer too
            raise ReplayError(f"{pub.get_subscription_count()} nodes listen on {pub.topic_name}: another ROS graph "
                              f"shares ROS_DOMAIN_ID {self.env['ROS_DOMAIN_ID']}")
        compared = 0
        for action in rec.actions:
            kind = action[0]
            if kind == "step":
                mismatch = self.step(action, rec.states[compared], compared)
                compared += 1
                if mismatch is not None:
                    return mismatch, compared
            elif kind == "brake":
                self.call("brake", SetBool, SetBool.Request(data=bool(action[1])))
            elif kind in ("pause", "resume"):
                self.call("pause", SetBool, SetBool.Request(data=kind == "pause"))
            elif kind == "reset":  # the node resets to its load_force, the session to the case's start
                self.set_load(initial_load_n(self.case) or 0.0)
                self.call("reset", Trigger, Trigger.Request())
        return None, compared

    def step(self, action, want, compared: int) -> str | None:
        """One command and the state it answers; the mismatch in words, or None."""
        from std_msgs.msg import Float64
        _, command, f = action
        self.set_load(f)
        self.pub.publish(Float64(data=command))
        self.spin_until(lambda: len(self.states) > compared, f"the state of step {compared + 1}")
        m = self.states[compared]
        got = (m.position[0], m.velocity[0], m.position[1], m.velocity[1])
        if got == tuple(want):
            return None
        return (f"step {compared + 1} (t = {m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec:.6f} s): "
                f"node (angle, speed, x, v) = {got}, offline {tuple(want)}")
