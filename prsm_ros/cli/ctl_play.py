"""`prsm-ctl play FILE.csv`: play an excitation to a node (the simulator or a bench's driver) around a hold.

    prsm-ctl play excite.csv [--kp N·m/m] [--kd N·m·s/m] [--ki N·m/(m·s)] [--speed-kp rad/s/m]

The CSV (`prsm-fit excite` writes one) has `time_s` and either `screw_torque_nm` (the node's
`command_interface` must be effort) or `screw_speed_rad_s` (velocity). On every joint state the node
publishes, the command for the next step is the signal at that time since the first joint state (held
between samples) plus a holding controller on the nut position, so the nut stays on its travel around
where it started: a PID in torque, a proportional position loop in speed. A lockstep node steps on
each command, so the whole file is played step for step. The node records as it always does
(`record:=true`); the recording is what `prsm-fit` reads.
"""

from __future__ import annotations

import math
import time

import numpy as np

from prsm_ros.interface import NUT_JOINT

COLUMNS = {"screw_torque_nm": ("effort", "screw_torque"), "screw_speed_rad_s": ("velocity", "velocity_command")}


def register(sub, common) -> None:
    """Add the `play` verb to prsm-ctl's subcommands."""
    p = sub.add_parser("play", parents=[common], help="play an excitation CSV around a holding controller")
    p.add_argument("file", metavar="FILE.csv", help="time_s and screw_torque_nm or screw_speed_rad_s")
    p.add_argument("--kp", default="3000", help="hold: N·m per m of nut position error (torque)")
    p.add_argument("--kd", default="60", help="hold: N·m per m/s of nut speed (torque)")
    p.add_argument("--ki", default="0", help="hold: N·m per m·s of integrated error (torque)")
    p.add_argument("--speed-kp", default="2000", help="hold: screw rad/s per m of nut position error (speed)")


def _numbers(rows: list[list[str]], what: str, error: type[Exception]) -> np.ndarray:
    """`rows` of text as a 2-D array of finite numbers; `error` naming `what` otherwise."""
    try:
        data = np.array(rows, dtype=float)
    except ValueError:
        raise error(f"{what}: every value must be a number, every row as long as the header") from None
    if data.ndim != 2 or not np.isfinite(data).all():
        raise error(f"{what}: every value must be a finite number")
    return data


def read_signal(path: str, error: type[Exception]) -> tuple[str, np.ndarray, np.ndarray]:
    """(column, times, values) of an excitation CSV; `error` (prsm-ctl's one-line error) naming what is wrong."""
    from prsm_ros.limits import read_text_file
    text = read_text_file(path, what="excitation", error=error)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    col = next((c for c in COLUMNS if c in header), None)
    if "time_s" not in header or col is None:
        raise error(f"{path}: needs the columns time_s and screw_torque_nm or screw_speed_rad_s (has "
                    f"{', '.join(header) or 'none'})")
    data = _numbers([ln.split(",") for ln in lines[1:]], path, error)
    if len(data) < 2 or np.any(np.diff(data[:, header.index("time_s")]) <= 0):
        raise error(f"{path}: time_s must increase over at least two rows")
    return col, data[:, header.index("time_s")], data[:, header.index(col)]


def cmd_play(ctl, args, emit, error: type[Exception]) -> None:
    """Play the file (module docstring) and report how many commands went out over how long; `error` is
    prsm-ctl's one-line error (exit 2)."""
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64

    from prsm_ros.messages import TOPICS, with_depth
    col, ts, vs = read_signal(args.file, error)
    interface, key = COLUMNS[col]
    names = ("kp", "kd", "ki", "speed_kp")
    gains = dict(zip(names, _numbers([[getattr(args, k) for k in names]], "--kp/--kd/--ki/--speed-kp", error)[0]))
    active = ctl.get_params(["command_interface"])["command_interface"]
    if active != interface:
        raise error(f"play {args.file}: {col} needs command_interface {interface}, the node's is {active} "
                       f"(prsm-ctl interface {interface})")
    pub = ctl.node.create_publisher(Float64, ctl.topic(key), with_depth(TOPICS[key].qos, 10))
    ctl.spin_until(lambda: pub.get_subscription_count() > 0, f"nobody reads {ctl.topic(key)}")
    st = {"t0": None, "x0": 0.0, "integral": 0.0, "last": None, "sent": 0, "done": False}

    def on_state(js) -> None:
        if st["done"] or NUT_JOINT not in js.name:
            return
        i = list(js.name).index(NUT_JOINT)
        t = js.header.stamp.sec + js.header.stamp.nanosec * 1e-9
        x, v = js.position[i], js.velocity[i] if len(js.velocity) > i else 0.0
        if st["t0"] is None:
            st["t0"], st["x0"] = t, x
        e = t - st["t0"]
        if e > ts[-1]:
            st["done"] = True
            pub.publish(Float64(data=0.0))
            return
        if st["last"] is not None:
            st["integral"] += (st["x0"] - x) * (t - st["last"])
        st["last"] = t
        u = float(vs[max(0, int(np.searchsorted(ts, e, side="right")) - 1)])
        if interface == "effort":
            u += gains["kp"] * (st["x0"] - x) - gains["kd"] * v + gains["ki"] * st["integral"]
        else:
            u += gains["speed_kp"] * (st["x0"] - x)
        pub.publish(Float64(data=u if math.isfinite(u) else 0.0))
        st["sent"] += 1

    ctl.node.create_subscription(JointState, ctl.topic("joint_states"), on_state, with_depth(TOPICS["joint_states"].qos, 100))
    pub.publish(Float64(data=float(vs[0])))  # a lockstep node steps on a command: the first one starts the play
    start = time.monotonic()
    while not st["done"]:
        ctl.executor.spin_once(timeout_sec=0.05)
        if st["t0"] is None and time.monotonic() - start > ctl.timeout_s:
            raise error(f"no joint state from {ctl.target} within {ctl.timeout_s:g} s (paused? prsm-ctl resume)")
    emit({"file": args.file, "column": col, "commands": st["sent"], "duration_s": float(ts[-1])},
         f"played {args.file}: {st['sent']} commands over {ts[-1]:g} s ({col} around a hold at the start position)")
