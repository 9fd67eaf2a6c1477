"""prsm-fit excite: an identification signal as a CSV that `prsm-ctl play` sends to a node while it records.

    prsm-fit excite -o excite.csv [--kind multisine|chirp|prbs] [--signal torque|speed] [--duration 20]
                    [--rate 1000] [--amplitude A] [--band 0.5 20] [--preset P | --params F] [--actuator F]

The amplitude defaults to a fraction of what the actuator allows (its motor's peak torque through the
gear, or its speed limit; without an actuator the node's default effort limit) and is refused above
it. The node's holding controller (a PID on the nut position, `prsm-ctl play --hold`) runs beside
the signal, so the nut stays on its travel; the CSV carries the excitation alone, in the columns
`time_s` and `screw_torque_nm` or `screw_speed_rad_s`.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from prsm_sim.errors import PrsmError
from prsm_sim.identify.excite import KINDS, excitation
from prsm_sim.presets import PRESETS

from prsm_ros.interrupts import import_native, interrupt_handled

PROG = "prsm-fit excite"
DEFAULT_EFFORT_LIMIT_NM = 50.0  # the node's max_effort default: the bound without an actuator
SHARE_OF_LIMIT = 0.2  # the default amplitude, as a share of the limit


def limit_of(signal: str, actuator) -> float:
    """The largest amplitude the actuator allows for `signal` (N·m at the screw, or rad/s)."""
    if actuator is None:
        if signal == "speed":
            raise PrsmError("--signal speed needs --actuator FILE (a bare screw takes torque only)")
        return DEFAULT_EFFORT_LIMIT_NM
    m = actuator.motor  # the motor turns gear_ratio times per screw turn: torque × ratio, speed / ratio at the screw
    return float(m.peak_torque_nm * m.gear_ratio) if signal == "torque" else float(m.speed_limit_rad_s / m.gear_ratio)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--output", required=True, metavar="FILE.csv")
    ap.add_argument("--kind", choices=KINDS, default="multisine")
    ap.add_argument("--signal", choices=("torque", "speed"), default="torque")
    ap.add_argument("--duration", type=float, default=20.0, help="s (default 20)")
    ap.add_argument("--rate", type=float, default=1000.0, help="samples per s (default 1000)")
    ap.add_argument("--amplitude", type=float, help="peak, N·m or rad/s (default: a fifth of the actuator's limit)")
    ap.add_argument("--band", type=float, nargs=2, default=(0.5, 20.0), metavar=("LOW_HZ", "HIGH_HZ"))
    ap.add_argument("--seed", type=int, default=0, help="PRBS seed")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--preset", choices=list(PRESETS))
    g.add_argument("--params", metavar="FILE.yaml")
    ap.add_argument("--actuator", metavar="FILE.yaml", help="bounds the amplitude by its motor's limits")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    out = Path(args.output)
    try:
        import_native("scipy.signal")  # the chirp's module, which loads scipy's pybind11 solvers (`import_native`)
        from prsm_ros.param_files import load_actuator_file
        actuator = load_actuator_file(args.actuator) if args.actuator else None
        limit = limit_of(args.signal, actuator)
        amp = SHARE_OF_LIMIT * limit if args.amplitude is None else args.amplitude
        if not 0 < amp <= limit:
            raise PrsmError(f"--amplitude {amp:g}: must lie in (0, {limit:g}] "
                            f"({'N·m' if args.signal == 'torque' else 'rad/s'}, the actuator's limit)")
        if not out.absolute().parent.is_dir():
            raise PrsmError(f"-o {out}: its folder does not exist")
        t, x = excitation(args.kind, args.duration, 1.0 / args.rate if args.rate > 0 else -1.0, amp,
                          f_low_hz=args.band[0], f_high_hz=args.band[1], seed=args.seed)
        column = "screw_torque_nm" if args.signal == "torque" else "screw_speed_rad_s"
        tmp = out.with_name(out.name + ".tmp")
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(f"# prsm-fit excite: {args.kind} in {args.signal}, peak {amp:g}, band {args.band[0]:g}-"
                    f"{args.band[1]:g} Hz; play with prsm-ctl play {out.name}\n")
            f.write(f"time_s,{column}\n")
            f.writelines(f"{a:.6f},{b:.9g}\n" for a, b in zip(t, x))
        os.replace(tmp, out)
    except PrsmError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        interrupt_handled()
        print(f"\n{PROG}: interrupted; nothing written", file=sys.stderr)
        return 130
    print(f"wrote {out}: {len(t)} samples, {args.kind} {args.signal}, peak {amp:g}")
    return 0
