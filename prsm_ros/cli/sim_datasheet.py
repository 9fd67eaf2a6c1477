"""`prsm-sim datasheet` and `prsm-sim params --datasheet`: catalogue figures from a model, a plant from a catalogue row.

    prsm-sim datasheet --preset s30 [--model fu2018] [--set k=v …] [--load N] [--speed RAD_S] [--json]
    prsm-sim params --datasheet SHEET.yaml [--base PARAMS.yaml] [--model fu2018] [-o OUT.yaml] [--json]

The computation is `prsm_sim.datasheet` and `prsm_sim.calibration` (docs/model.md "The model's
datasheet", "From a datasheet"); this module maps the command line onto them.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from typing import Any

from prsm_sim import MODELS, Params
from prsm_sim.models.registry import model_class
from prsm_sim.calibration import Calibration, calibrate
from prsm_sim.datasheet import Datasheet, ModelSheet, model_datasheet

from prsm_ros.json_out import dumps
from prsm_ros.param_files import read_param_text, yaml_mapping, params_to_yaml, resolve_params

SHEET_FIGURES = (("efficiency_forward", "η forward", 1.0, ""), ("efficiency_backward", "η backward", 1.0, ""),
                 ("no_load_torque_nm", "no-load torque", 1.0, "N·m"),
                 ("static_load_rating_n", "static rating C0a", 1e-3, "kN"),
                 ("dynamic_load_rating_n", "dynamic rating Ca", 1e-3, "kN"),
                 ("axial_stiffness_n_per_um", "nut axial stiffness", 1.0, "N/µm"))


def sheet_text(params: Params, sheet: ModelSheet) -> str:
    c = sheet.conditions
    lines = [f"{params.name} on {c['model']}: efficiencies at {c['load_n']:.6g} N and {c['speed_rad_s']:g} rad/s, "
             f"no-load torque at {c['no_load_speed_rad_s']:g} rad/s"]
    d = sheet.to_dict()
    for key, label, scale, unit in SHEET_FIGURES:
        lines.append(f"  {label:22s} {d[key] * scale:12.4f} {unit}")
    return "\n".join(lines)


def cmd_datasheet(args, params_of) -> None:
    p = params_of(args)
    sheet = model_datasheet(p, args.model, load_n=args.load, speed_rad_s=args.speed, dt_s=args.dt)
    print(dumps({"preset": p.name, **sheet.to_dict()}) if args.json else sheet_text(p, sheet))


def load_datasheet(path: str) -> Datasheet:
    """A datasheet YAML file (the keys of `prsm_sim.datasheet.Datasheet`), errors naming the file."""
    from prsm_sim import ParamError
    data = yaml_mapping(read_param_text(path, "datasheet"), path, "datasheet keys")
    try:
        return Datasheet.from_dict(data)
    except ParamError as e:
        raise ParamError(f"{path}: {e}") from None


def calibration_text(cal: Calibration) -> str:
    lines = [f"datasheet → parameter set {cal.params.name!r} for model {cal.model}", "assumed:"]
    lines += [f"  {a}" for a in cal.assumptions]
    lines.append("fitted:")
    lines += [f"  {f.key} = {f.value:.6g}  ({f.figure}: sheet {f.target:.6g}, model {f.achieved:.6g})" for f in cal.fitted]
    lines += [f"  note: {n}" for n in cal.notes]
    lines.append("the result beside the sheet:")
    lines += [f"  {r['figure']:22s} sheet {r['sheet']:12.6g}  model {r['model']:12.6g}  ratio {r['ratio']:.4f}"
              for r in cal.comparison()]
    return "\n".join(lines)


def _write_atomically(path: str, text: str) -> None:
    """Write `text` to `path` whole or not at all (a temporary file beside it, then renamed)."""
    folder = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(prefix=".params-", suffix=".yaml", dir=folder)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def cmd_params_datasheet(args) -> None:
    sheet = load_datasheet(args.datasheet)
    base = resolve_params(args.preset or ("s30" if not args.base else None), args.base, None)
    cal = calibrate(sheet, base, args.model, progress=lambda m: print(f"prsm-sim: {m} …", file=sys.stderr))
    text = params_to_yaml(cal.params)
    report: dict[str, Any] = {"model": cal.model, "assumed": cal.assumptions,
                              "fitted": [f.__dict__ for f in cal.fitted], "notes": cal.notes,
                              "comparison": cal.comparison(), "model_sheet": cal.model_sheet.to_dict()}
    if args.output:
        try:
            _write_atomically(args.output, text)
        except OSError as e:
            from prsm_sim import ParamError
            raise ParamError(f"cannot write {args.output}: {e.strerror or e}") from None
        report["output"] = args.output
    if args.json:
        print(dumps({**report, "params": cal.params.to_dict()}))
        return
    if args.output:
        print(calibration_text(cal) + f"\nwrote {args.output}")
    else:
        print(calibration_text(cal), file=sys.stderr)
        print(text, end="")


def register(sub, common: argparse.ArgumentParser, cmd_params, params_of) -> None:
    """Add `params` (with its --datasheet form) and `datasheet` to prsm-sim's subcommands."""
    pa = sub.add_parser("params", parents=[common], help="print every parameter as YAML, or build them from a "
                                                           "catalogue datasheet (--datasheet)")
    pa.add_argument("--datasheet", metavar="SHEET.yaml", help="a catalogue row (nominal_diameter_m, lead_m, starts, …): "
                                                                "build and calibrate a parameter set for it")
    pa.add_argument("--base", metavar="PARAMS.yaml", help="with --datasheet: friction, material and factors from this "
                                                            "parameter file (default the s30 preset)")
    pa.add_argument("--model", choices=[m for m in MODELS if not model_class(m).takes_efficiencies], default="fu2018",
                    help="with --datasheet: the model the friction is calibrated for")
    pa.add_argument("-o", "--output", metavar="OUT.yaml", help="with --datasheet: write the parameter file here")
    pa.set_defaults(func=lambda a: cmd_params_datasheet(a) if a.datasheet else _plain_params(a, cmd_params))
    ds = sub.add_parser("datasheet", parents=[common], help="what a catalogue lists, computed by the model")
    ds.add_argument("--model", choices=list(MODELS), default="fu2018")
    ds.add_argument("--load", type=float, help="load of the efficiencies and the stiffness, N (default 10 %% of Ca)")
    ds.add_argument("--speed", type=float, default=100.0, help="screw speed of the efficiencies, rad/s")
    ds.add_argument("--dt", type=float, default=1e-3, help="simulation step, s")
    ds.set_defaults(func=lambda a: cmd_datasheet(a, params_of))
    va = sub.add_parser("validate", help="write docs/validation.md: a catalogue line beside the model fitted on one size")
    va.add_argument("-o", "--output", help="the page to write (default docs/validation.md of the source tree)")
    va.set_defaults(func=_validate)


def _validate(args) -> None:
    from prsm_ros.cli import validation
    rc = validation.main(["-o", args.output] if args.output else [])
    if rc:  # it printed its one line (2) or its interruption (130)
        raise SystemExit(rc)


def _plain_params(args, cmd_params) -> None:
    from prsm_sim import ParamError
    for flag, given in (("--base", args.base), ("-o", args.output)):
        if given:
            raise ParamError(f"{flag} applies with --datasheet only")
    cmd_params(args)

