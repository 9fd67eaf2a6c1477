"""`prsm-demo`: the simulated actuator and a position controller, two processes talking over DDS.

    prsm-demo                      # 4 s realtime run, s30 preset, jones2016 model, bag recorded
    prsm-demo --time-mode lockstep --model fu2018 --duration 2 --record run.mcap
    prsm-demo --no-record --rerun spawn
    prsm-demo --command-interface velocity     # the node's drive closes the speed loop
    prsm-demo --gains tune_out/gains.yaml      # gains tuned by prsm-sweep tune

It starts `prsm-node` and `python -m prsm_ros.cli.demo_controller` as separate OS processes, lets the
controller track a smooth nut-position profile through the torque topic for `--duration` seconds
of simulation time, stops the node with SIGINT, and prints the tracking summary (RMS and maximum
error, final position, steps, real-time factor) and where the bag is. The node starts paused and
the controller resumes it once it listens, so the run starts at t = 0 whatever the start-up takes.
In realtime mode both processes run SCHED_FIFO `--realtime-priority` where the OS allows (root or
an rtprio limit; otherwise normal priority, as the summary says). `--time-mode fast` is refused:
the node would step as fast as it can without waiting for the controller, so no loop closes.

Isolation: a ROS_DOMAIN_ID you set is used as it is (so `ros2 topic echo` in another shell sees the
run); otherwise the demo picks one from its process id and prints it. Discovery stays on this
machine (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) unless you set a range yourself.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
from datetime import datetime, timezone
from pathlib import Path

from prsm_ros.json_out import dumps
from prsm_ros.ros_env import isolated_env, ros_args, start_module
from prsm_ros.interrupts import interrupt_handled

# How long the controller waits for the node to come up. A first start on a fresh install compiles the
# numba kernels (tens of seconds on a busy two-core machine); the wait ends early if the node process dies.
NODE_START_CEILING_S = 600.0
TIME_MODES = ("realtime", "lockstep")  # fast: the node does not wait for the controller (refused in main)


def build_parser() -> argparse.ArgumentParser:
    from prsm_sim import MODELS, PRESETS, __version__
    p = argparse.ArgumentParser(prog="prsm-demo", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="\n\n".join(__doc__.split("\n\n")[1:]))
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    p.add_argument("--duration", type=float, default=4.0, help="simulation seconds to run (default 4)")
    p.add_argument("--preset", default="s30", choices=sorted(PRESETS))
    p.add_argument("--model", default="jones2016", choices=list(MODELS))
    p.add_argument("--time-mode", default="realtime", metavar="{realtime,lockstep}",
                   help="realtime (default): the node steps at 1 kHz on the wall clock; lockstep: every command "
                        "advances one step (deterministic)")
    p.add_argument("--realtime-priority", type=int, default=10,
                   help="realtime: SCHED_FIFO priority (1..99) of the node's step thread and of the controller "
                        "where the OS allows; 0 keeps both at normal priority (default 10)")
    p.add_argument("--load", type=float, default=500.0, help="external nut load force in N (default 500)")
    p.add_argument("--command-interface", default="effort", choices=("effort", "velocity", "position"),
                   help="what the controller commands: screw torque (effort, default), screw speed (velocity: "
                        "the node's drive closes the speed loop) or nut position (position: the drive closes both)")
    p.add_argument("--record", metavar="FILE.mcap", help="bag path (default ./prsm_demo_<UTC time>.mcap)")
    p.add_argument("--no-record", action="store_true", help="do not record a bag")
    p.add_argument("--rerun", default="off", choices=("off", "save", "spawn", "connect"),
                   help="Rerun output of the node (default off)")
    p.add_argument("--rerun-target", default="", help="save: .rrd path; spawn: port; connect: address")
    p.add_argument("--gains", metavar="FILE", help="controller gains file, as prsm-sweep tune writes it (DIR/gains.yaml)")
    p.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: yours, else one from the pid)")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object (and nothing else "
                   "on stdout)")
    return p


def _refusal(args) -> str | None:
    """Why the options cannot run, in one line, or None."""
    if not (0 < args.duration <= 3600):
        return f"--duration {args.duration:g}: must be in (0, 3600] s"
    if args.time_mode not in TIME_MODES:
        why = (": the node steps as fast as it can without waiting for the controller, so the loop cannot close"
               if args.time_mode == "fast" else "")
        return f"--time-mode {args.time_mode}{why}; allowed: {', '.join(TIME_MODES)}"
    if not 0 <= args.realtime_priority <= 99:
        return f"--realtime-priority {args.realtime_priority}: must be in 0..99 (0: normal)"
    return None


def _prepare(args) -> tuple[str | None, dict | None, dict]:
    """(why the options cannot run or None, the --gains file's gains, the ROS environment of the run)."""
    why = _refusal(args)
    gains, env = None, {}
    if why is None and args.gains:
        from prsm_ros.sweep.gains import load_gains
        from prsm_sim.errors import InputError
        try:
            gains = load_gains(args.gains)
        except InputError as e:
            why = f"--gains {e}"
    if why is None:
        try:
            env = isolated_env(args.domain_id)
        except ValueError as e:
            why = f"--domain-id: {e}"
    return why, gains, env


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    why, gains, env = _prepare(args)
    if why is not None:
        print(f"prsm-demo: error: {why}", file=sys.stderr)
        return 2
    record = None if args.no_record else Path(
        args.record or f"prsm_demo_{datetime.now(timezone.utc).strftime('%Y%m%d_%H%M%S')}.mcap").resolve()
    print(f"prsm-demo: ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']} "
          f"ROS_AUTOMATIC_DISCOVERY_RANGE={env['ROS_AUTOMATIC_DISCOVERY_RANGE']}; "
          f"{args.model} / {args.preset}, {args.time_mode}, {args.duration:g} s, load {args.load:g} N, "
          f"{args.command_interface} commands"
          + (f"; gains {', '.join(f'{k} {v:g}' for k, v in gains.items())} from {args.gains}" if gains else ""),
          file=sys.stderr if args.json else sys.stdout, flush=True)
    out, node_rc, ctl_rc, node_text, interrupted = _run(args, env, record)
    if interrupted:
        kept = f"the bag so far is in {record} (the node closed it)" if record and record.exists() else "nothing kept"
        print(f"prsm-demo: interrupted: {kept}", file=sys.stderr)
        return 130
    lines = [line for line in out.decode(errors="replace").splitlines() if line.startswith("{")]
    if node_rc != 0 or not lines:
        print(f"prsm-demo: the run failed (node exit code {node_rc}, controller exit code {ctl_rc})",
              file=sys.stderr)
        print(node_text, file=sys.stderr)
        return 1
    s = json.loads(lines[-1])
    dt_s = 1e-3
    if args.json:
        print(dumps({**s, "steps": round(s["sim_time_s"] / dt_s), "bag": str(record) if record else None,
                     "time_mode": args.time_mode, "model": args.model, "preset": args.preset}))
    else:
        print(summary_text(s, dt_s, record))
    return 0 if s["completed"] else 1


def _run(args, env: dict, record: Path | None) -> tuple[bytes, int | None, int | None, str, bool]:
    """Start the node and the controller, wait for the controller, stop the node (SIGINT: it closes its bag).

    Returns the controller's output, both exit codes, the node's log and whether Ctrl-C ended the run.
    """
    node_params = {"preset": args.preset, "model": args.model, "time_mode": args.time_mode,
                   "load_force": args.load, "record": record is not None, "record_path": str(record or ""),
                   "rerun": args.rerun, "rerun_target": args.rerun_target, "command_interface": args.command_interface,
                   "start_paused": True, "realtime_priority": args.realtime_priority}
    realtime_priority = args.realtime_priority if args.time_mode == "realtime" else 0
    interrupted = False
    with tempfile.TemporaryDirectory(prefix="prsm_demo_") as tmp:
        node_log = Path(tmp) / "node.log"
        with open(node_log, "wb") as log:
            node = start_module("prsm_ros.cli.node", ros_args(node_params), env, stdout=log, stderr=subprocess.STDOUT)
            ctl = start_module("prsm_ros.cli.demo_controller",
                               ["--duration", repr(args.duration), "--preset", args.preset, "--load", repr(args.load),
                                "--connect-timeout", repr(NODE_START_CEILING_S),
                                "--wall-timeout", repr(60.0 + 20 * args.duration),
                                "--command-interface", args.command_interface,
                                "--realtime-priority", str(realtime_priority), "--progress"]
                               + (["--gains", str(Path(args.gains).resolve())] if args.gains else []),
                               env, stdout=subprocess.PIPE)
            try:
                out = wait_for_controller(ctl, node)
            except KeyboardInterrupt:
                interrupt_handled()
                ctl.kill()
                out, interrupted = b"", True
            finally:
                node_rc = _stop(node)
            ctl.wait()
        node_text = node_log.read_text(errors="replace")
    return out, node_rc, ctl.returncode, node_text, interrupted


def _stop(node: subprocess.Popen) -> int | None:
    """SIGINT to the node and its exit code once it has closed its bag; a second Ctrl-C does not cut that short."""
    if node.poll() is None:
        node.send_signal(signal.SIGINT)
    while True:
        try:
            return node.wait(timeout=30)
        except KeyboardInterrupt:
            interrupt_handled()
            continue
        except subprocess.TimeoutExpired:
            node.kill()
            return node.wait()


def wait_for_controller(ctl: subprocess.Popen, node: subprocess.Popen) -> bytes:
    """The controller's output once it exits; it is stopped at once if the node dies first."""
    while True:
        try:
            out, _ = ctl.communicate(timeout=0.25)
            return out
        except subprocess.TimeoutExpired:
            if node.poll() is not None:
                ctl.kill()
                out, _ = ctl.communicate()
                return out


def summary_text(s: dict, dt_s: float, record: Path | None) -> str:
    lines = [
        "tracking summary (nut position, controller process over DDS):",
        f"  RMS error        {s['rms_error_m'] * 1e3:10.4f} mm",
        f"  max error        {s['max_error_m'] * 1e3:10.4f} mm",
        f"  final position   {s['final_position_m'] * 1e3:10.4f} mm   (reference {s['final_reference_m'] * 1e3:.4f} mm)",
        f"  steps            {round(s['sim_time_s'] / dt_s):10d}     ({s['sim_time_s']:.3f} s simulated, "
        f"{s['states_received']} states received)",
        f"  real-time factor {s['real_time_factor']:10.3f}     ({s['wall_time_s']:.2f} s wall)",
        f"  scheduling       controller {s['scheduling']}",
    ]
    if "gains" in s:
        g = s["gains"]
        lines.append(f"  gains            bandwidth {g['bandwidth_hz']:g} Hz, damping {g['damping']:g}, "
                     f"integral ratio {g['integral_ratio']:g}, torque limit {g['max_torque_nm']:g} N·m")
    if not s["completed"]:
        lines.append("  (incomplete: the controller stopped before the end of the run)")
    if record is not None:
        lines.append(f"bag: {record}\n  inspect: prsm-bag info {record.name}\n  report:  prsm-bag report {record.name}"
                     f"   (plots and report.json in {record.stem}_report/)")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
