"""Regenerate the example recordings in `bags/` (golden data, one command):

    python -m prsm_ros.cli.make_bags [--out bags] [--model fu2018] [--offline-tracking]

Each bag is a full-rate (1 kHz) recording of a short run. The offline ones are written by
`offline_record.write_trajectory_mcap` (the same topics and messages as a node run) with a
`prsm_example` metadata record saying what the run is and how it was made:

- `step_response.mcap`: the Jones 2016 seed example (preset jones2016, 100 N) under a torque
  step of the torque that holds 1 rad/s in the jones2016 steady state; fu2018 with its
  screw–roller law set to viscous (the Jones limit), so the run settles as the seed describes.
- `sine_tracking.mcap`: closed-loop tracking of a raised-cosine (sinusoidal) nut-position profile
  by a real node and controller: `prsm-demo` in lockstep mode (`prsm-node` and
  `prsm_ros.cli.demo_controller` as two processes over DDS, s30, 2 kN, 2 s), so the run is
  deterministic; the bag is the node's own recording, reference on ~/nut_position_reference.
  `--offline-tracking` makes it instead with a PD loop stepped in Python (`pd_tracking`, labelled
  `offline closed loop`), for machines without DDS.
- `heavy_load.mcap`, `light_load.mcap`: the Fu 2018 load cases (preset s30, 20 kN and 100 N)
  driven speed-controlled to the preset's 100 rad/s (`prsm_sim.scenarios`).

The model is fu2018 when `prsm_sim.MODELS` has it, else jones2016. `bags/README.md` lists the
bags with their `prsm-bag report` figures.
"""

from __future__ import annotations

import argparse

import math
import sys
from pathlib import Path

import numpy as np

from prsm_sim import MODELS, ParamError, PrsmError, Simulator, preset
from prsm_sim.models.registry import model_class
from prsm_sim.physics.inertia import reflected_inertia
from prsm_sim.scenarios import default_spec, run_scenario
from prsm_sim.stepping.trajectory import trajectory_from_rows

from prsm_ros.json_out import dumps
from prsm_ros.mcap.offline import write_trajectory_mcap

DT_S = 1e-3
COMMAND = "python -m prsm_ros.cli.make_bags"


class RunFailed(PrsmError, RuntimeError):
    """A run that makes a bag (node and controller over DDS) failed; the message has its output."""


def default_model() -> str:
    return "fu2018" if "fu2018" in MODELS else "jones2016"


def pd_tracking(sim: Simulator, *, amplitude_m: float, frequency_hz: float, load_n: float, duration_s: float,
                bandwidth_hz: float = 30.0, damping: float = 0.7):
    """Closed-loop nut-position tracking of x_ref = A sin(2π f t) by a PD law on the screw angle.

    τ = J (ω_n² (θ_ref − θ) + 2ζω_n (ω_ref − ω)) + J α_ref + F p, with θ = x/p, p = L/2π, J the
    reflected inertia: a second-order error response of bandwidth ω_n, feed-forward of the
    reference acceleration and of the load torque. Returns (trajectory, reference per step).
    """
    p_lead = sim.params.geometry.lead_per_rad_m
    j = reflected_inertia(sim.params)
    wn = 2 * math.pi * bandwidth_hz
    w = 2 * math.pi * frequency_hz
    n = int(round(duration_s / sim.dt_s))
    rows, ref = [], np.empty(n)
    for k in range(n):
        t = sim.time_s
        x_ref, v_ref, a_ref = amplitude_m * math.sin(w * t), amplitude_m * w * math.cos(w * t), -amplitude_m * w * w * math.sin(w * t)
        s = sim.state
        e = x_ref / p_lead - s.screw_angle_rad
        de = v_ref / p_lead - s.screw_speed_rad_s
        tau = j * (wn * wn * e + 2 * damping * wn * de + a_ref / p_lead) + load_n * p_lead
        ref[k] = x_ref
        rows.append(sim.step(tau, load_n))
    return trajectory_from_rows(rows, sim.layout, sim.state), ref


BAGS = ("step_response", "sine_tracking", "heavy_load", "light_load")


def node_tracking_run(path: Path, model: str) -> Path:
    """The node's own bag of a lockstep `prsm-demo` run (node + controller processes over DDS)."""
    import subprocess
    path.unlink(missing_ok=True)  # regenerating golden data on purpose: the node itself never overwrites a bag
    cmd = [sys.executable, "-m", "prsm_ros.cli.demo", "--time-mode", "lockstep", "--model", model, "--preset", "s30",
           "--load", "2000", "--duration", "2", "--record", str(path)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if res.returncode != 0:
        raise RunFailed(f"the node + controller run failed ({' '.join(cmd[1:])}):\n{res.stderr.strip()}\n"
                           "make the bag offline instead with --offline-tracking")
    return path


def make(out_dir: Path, model: str, progress: bool = True, only: tuple[str, ...] = BAGS,
         offline_tracking: bool = False) -> list[Path]:
    """Write the example bags (all, or those named in `only`) into `out_dir`; returns their paths."""
    unknown = set(only) - set(BAGS)
    if unknown:
        raise ParamError(f"unknown example bag(s) {', '.join(sorted(unknown))}; known: {', '.join(BAGS)}")
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []

    def save(name: str, traj, params, preset_name: str, description: str, reference=None) -> None:
        meta = {"prsm_example": {"name": name, "description": description, "made_by": COMMAND,
                                 "source": "offline closed loop" if reference is not None else "offline run"}}
        path = write_trajectory_mcap(out_dir / f"{name}.mcap", traj, params, model, preset_name=preset_name,
                                     progress=progress, dt_s=DT_S, reference_m=reference, extra_metadata=meta)
        written.append(path)

    if "step_response" in only:
        p = preset("jones2016")
        jones_limit = model_class(model).has_friction_laws and not model_class(model).has_axial_chain
        if jones_limit:
            # Fu 2018's own validation: viscous screw–roller friction and every other friction off
            # (pins, nut–roller rolling, drag) is the Jones 2016 model
            p = p.with_overrides({"friction.screw_roller_law": "viscous", "friction.mu_pin": 0.0,
                                  "friction.mu_nut_roller_rolling": 0.0, "friction.lubricant_viscosity_m2_s": 0.0})
        spec = default_spec(p, "step")
        traj = run_scenario(Simulator(p, model, DT_S), spec, 1.0)
        save("step_response", traj, p, "jones2016",
             f"torque step of {spec.torque_nm:.5f} N·m at t = 0 from rest against {spec.load_n:g} N (Jones 2016 seed "
             "example)" + ("; fu2018 with friction.screw_roller_law = viscous and the other frictions off (Jones limit)" if jones_limit else ""))

    p = preset("s30")
    if "sine_tracking" in only and offline_tracking:
        traj, ref = pd_tracking(Simulator(p, model, DT_S), amplitude_m=2e-3, frequency_hz=1.0, load_n=2000.0,
                                duration_s=1.5)
        save("sine_tracking", traj, p, "s30",
             "offline closed loop: PD nut-position control (30 Hz, ζ 0.7, velocity/acceleration/load feed-forward) "
             "tracking 2 mm × sin(2π·1 Hz·t) against 2 kN, stepped in Python at 1 kHz", reference=ref)
    elif "sine_tracking" in only:
        written.append(node_tracking_run(out_dir / "sine_tracking.mcap", model))

    for case in ("heavy", "light"):
        if f"{case}_load" not in only:
            continue
        spec = default_spec(p, case)
        traj = run_scenario(Simulator(p, model, DT_S), spec, 0.5)
        save(f"{case}_load", traj, p, "s30",
             f"Fu 2018 {case}-load case: {spec.load_n:g} N, PI speed control to {spec.speed_rad_s:g} rad/s "
             f"(0.1 s ramp, prsm_sim.scenarios '{case}')")
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Regenerate the example MCAP recordings in bags/.")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[2] / "bags"),
                    help="output folder (default: the repository's bags/)")
    ap.add_argument("--model", default=default_model(), choices=sorted(MODELS),
                    help=f"model (default {default_model()})")
    ap.add_argument("--offline-tracking", action="store_true",
                    help="make sine_tracking with an offline PD loop instead of a node + controller run over DDS")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    try:
        paths = make(Path(args.out), args.model, progress=not args.no_progress, offline_tracking=args.offline_tracking)
    except RunFailed as e:
        print(f"make_bags: error: {e}", file=sys.stderr)
        return 1
    from prsm_ros.bag.reader import open_bag
    from prsm_ros.bag.report import report
    for path in paths:
        r = report(open_bag(path), path.with_suffix(""), plots=False, progress=False)
        keys = {"efficiency": r["efficiency"]["forward"], "tracking_rms_m": (r["tracking"] or {}).get("rms_error_m"),
                "l10_revolutions": r["life"]["l10_revolutions"]}
        print(f"{path} ({path.stat().st_size / 1e6:.2f} MB): {dumps(keys)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
