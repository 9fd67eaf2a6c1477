"""What an FMU is built from, written into its resources as JSON and read back at instantiation.

The configuration fixes the plant at build time: the resolved physical parameters, the screw
model, the step, the actuator (or none), the drive mode, the command gate and the initial nut
position and load, and the prsm version that built it. Nothing in it is imported or executed: the
model is looked up in `prsm_sim.MODELS`, every value is validated by the library's own constructors.
"""

from __future__ import annotations

from typing import Any

from prsm_sim import ParamError, Params, Session, SessionConfig, __version__
from prsm_sim.actuator import ActuatorParams, actuator_params_from_dict, actuator_params_to_dict

CONFIG_NAME = "prsm_fmu.json"
CONFIG_FORMAT = "prsm-fmu-config/1"


def make_config(params: Params, model: str, dt_s: float, actuator: ActuatorParams | None, *, interface: str,
                nut_position_m: float = 0.0, load_n: float = 0.0, max_effort_nm: float = 50.0, fmi: int = 2,
                preset_name: str | None = None) -> dict[str, Any]:
    """The configuration of one FMU, checked by building its session once (ParamError/InputError when refused).

    No command watchdog: an FMU's inputs hold their value until set again (FMI), and every step
    hands the held command to the session, so a timeout could never fire.
    """
    config = {
        "format": CONFIG_FORMAT, "prsm_version": __version__, "fmi": int(fmi), "preset": preset_name,
        "params": params.to_dict(), "model": model, "dt_s": float(dt_s),
        "actuator": None if actuator is None else actuator_params_to_dict(actuator),
        "session": {"interface": interface, "nut_position_m": float(nut_position_m), "load_n": float(load_n),
                    "max_effort_nm": float(max_effort_nm)},
    }
    session_from_config(config)
    return config


def check_version(config: dict[str, Any]) -> None:
    """Refuse a configuration written by another prsm version, naming both."""
    if not isinstance(config, dict) or config.get("format") != CONFIG_FORMAT:
        raise ParamError(f"FMU configuration: not a prsm FMU configuration ({CONFIG_FORMAT})")
    built = config.get("prsm_version")
    if built != __version__:
        raise ParamError(f"this FMU was built by prsm {built}, but the Python that loads it has prsm {__version__}: "
                         f"rebuild the FMU with prsm-fmu build, or install prsm {built}")


def session_from_config(config: dict[str, Any]):
    """The `Session` the configuration describes (ParamError/InputError naming the field when refused)."""
    params = Params.from_dict(config["params"])
    s = config["session"]
    act = None if config["actuator"] is None else actuator_params_from_dict(config["actuator"])
    # starts in equilibrium at its load, as prsm-node does at its load_force: an FMU built with a
    # load sits still under it from the first step instead of ringing in from an unloaded chain
    return Session.from_config(SessionConfig(
        params=params, model=config["model"], dt_s=config["dt_s"], actuator=act, nut_position_m=s["nut_position_m"],
        load_n=s["load_n"], initial_load_n=s["load_n"], interface=s["interface"], max_effort_nm=s["max_effort_nm"]))
