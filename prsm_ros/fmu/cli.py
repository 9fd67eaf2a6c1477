"""`prsm-fmu`: the actuator as an FMI co-simulation FMU.

    prsm-fmu build --preset s30 --model fu2018 -o s30_fu2018.fmu                 # FMI 2.0, bare screw, effort
    prsm-fmu build --fmi 3 --preset s30 --model elastic --command-interface velocity \\
        --actuator "{motor: {}}" -o s30_elastic_velocity.fmu

Model, parameters, drive mode and actuator are fixed when the FMU is built; the FMU's default
step is the model step `--dt`. The FMU runs the installed prsm through pythonfmu (FMI 2.0) or
pythonfmu3 (FMI 3.0): the importing tool needs a Python with prsm installed and a shared
libpython (docs/fmu.md). Errors print one line and exit 2.
"""

from __future__ import annotations

import argparse
import sys

from prsm_sim import MODELS, PRESETS, PrsmError, __version__
from prsm_sim.actuator import COMMAND_INTERFACES

from prsm_ros.param_files import resolve_params
from prsm_ros.fmu.config import make_config


def _actuator(args, params):
    """The actuator the options ask for (the node's rule: `--actuator`, `--faults` or a non-effort
    interface fit one), or None for the bare screw model."""
    from prsm_ros.node.parameters import actuator_config

    if not (args.actuator.strip() or args.faults.strip()) and args.command_interface == "effort":
        return None
    return actuator_config({"actuator": args.actuator, "faults": args.faults, "model": args.model,
                            "command_interface": args.command_interface}, params)


def cmd_build(args) -> None:
    from prsm_ros.fmu.build import build_fmu

    params = resolve_params(args.preset, args.params)
    config = make_config(params, args.model, args.dt, _actuator(args, params), interface=args.command_interface,
                         nut_position_m=args.nut_position, load_n=args.load, max_effort_nm=args.max_effort,
                         fmi=args.fmi, preset_name=None if args.params else (args.preset or params.name))
    dest = args.output or f"prsm_{params.name}_{args.model}_{args.command_interface}_fmi{args.fmi}.fmu"
    path = build_fmu(config, dest)
    print(path)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="prsm-fmu", description=__doc__.splitlines()[0])
    ap.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="build a co-simulation FMU of the actuator")
    b.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (2: pythonfmu, 3: pythonfmu3)")
    src = b.add_mutually_exclusive_group()
    src.add_argument("--preset", choices=list(PRESETS), help="named parameter set (default jones2016)")
    src.add_argument("--params", metavar="FILE", help="parameter YAML file (prsm-sim params writes one)")
    b.add_argument("--model", choices=list(MODELS), default="jones2016", help="screw model (default jones2016)")
    b.add_argument("--dt", type=float, default=1e-3, help="model step, s: the FMU's default communication step "
                                                          "(default 1e-3)")
    b.add_argument("--command-interface", choices=COMMAND_INTERFACES, default="effort",
                   help="what the FMU's command input is: screw torque, screw speed or nut position")
    b.add_argument("--actuator", default="", metavar="YAML",
                   help="the actuator around the screw as a YAML mapping of groups motor, drive, sensors, stops, "
                        "brake, e.g. \"{motor: {}, stops: {max_position_m: 0.3}}\" (as prsm-node's actuator "
                        "parameter; default: none, or the ideal one for velocity/position)")
    b.add_argument("--faults", default="", metavar="SPECS",
                   help="faults from the start: 'kind=jam,start_s=1,duration_s=0.5,value=30; …'")
    b.add_argument("--max-effort", type=float, default=50.0, help="screw torque command limit, N·m (tunable)")
    b.add_argument("--load", type=float, default=0.0, help="initial nut load force, N (the load input's start)")
    b.add_argument("--nut-position", type=float, default=0.0, help="initial nut position, m")
    b.add_argument("-o", "--output", metavar="FILE.fmu", help="where to write the FMU")
    b.set_defaults(func=cmd_build)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        args.func(args)
    except (PrsmError, ValueError) as e:  # every refused option or parameter: one line, exit 2
        print(f"prsm-fmu: {e}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"prsm-fmu: {e} (pip install pythonfmu pythonfmu3, or 'prsm[fmu]')", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
