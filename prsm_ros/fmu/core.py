"""The FMU's slave, whatever the FMI version: a `prsm_sim.Session` behind FMI's set, get, doStep and state.

`SlaveCore` is what `slave_fmi2.py` (pythonfmu, FMI 2.0) and `slave_fmi3.py` (pythonfmu3, FMI 3.0)
delegate to; they only translate statuses and variable types. It reads the build's configuration
(`config.CONFIG_NAME` in the FMU's resources: parameters, model, drive mode, actuator, step, the
prsm version), builds the session, and compiles the model's first step at instantiation.

The FMI contract as kept here:
- doStep(t, h) with h a whole multiple k of the model step runs k `Session.step` calls with the
  inputs held (a zero-order hold, as the library's own loop); any other h is refused, and so is a k
  above the library's run limit (`prsm_ros.limits.MAX_RUN_STEPS`), which would hold the importer
  for hours. A doStep before initialisation ends, after terminate, or at a time other than where
  the last step ended (backwards, or skipping ahead) is refused.
- A NaN or infinite input, or a parameter value the library refuses, is not taken: the setter logs
  the variable, the value and why, and the next doStep fails with the same message (the instance's
  state unchanged) until a valid value is set. pythonfmu maps a Python exception to a fatal status,
  so a setter cannot itself return an error; the doStep is where the importer sees it.
- A model failure (`ModelError`) fails the step with its reason; the session keeps its last finite
  state and refuses to step until the instance is reset.
- The FMU state is the whole `Session.get_state()` plus the inputs and the tunable parameters, as
  JSON-able data, so get/set/serialise continue a run bit for bit. A state that is refused (damaged
  bytes, another build or version, values the session refuses) changes nothing and fails the next
  doStep until a good state is set.
- No Python exception reaches the FMI wrappers: pythonfmu's and pythonfmu3's C++ wrappers answer one
  with a fatal status and release a reference to the slave's class and instance each time, so the
  third one frees the class and the next call into the instance crashes the importer (a segfault).
  Deserialising therefore never raises (`state_from_bytes`), and the slave's entry points turn
  every refusal into a logged error. Log messages are cut to `MAX_LOG_CHARS`, so no state blob or
  long value is ever printed.
"""

from __future__ import annotations

import ctypes
import json
import math
import os
import sys
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from collections.abc import Callable

import numpy as np

from prsm_sim import InputError, ModelError, ParamError, PrsmError, __version__
from prsm_sim.actuator import ACTUATOR_QUANTITIES, MEASURED_QUANTITIES
from prsm_ros.fmu.config import CONFIG_NAME, check_version, session_from_config
from prsm_ros.limits import MAX_RUN_STEPS

STATE_FORMAT = "prsm-fmu-state/1"
UNREADABLE = "unreadable"  # the key of what `state_from_bytes` returns for bytes that hold no state
MAX_LOG_CHARS = 400  # a log message longer than this is cut (a refused value or state is never printed whole)
# What a state's content can raise as it is checked and applied (wrong types, shapes, huge numbers, nesting)
_STATE_ERRORS = (PrsmError, AttributeError, KeyError, TypeError, ValueError, OverflowError, RecursionError)

# FMI unit names and their SI base-unit exponents (FMI's BaseUnit attributes)
UNITS: dict[str, dict[str, int]] = {
    "m": {"m": 1}, "m/s": {"m": 1, "s": -1}, "N": {"kg": 1, "m": 1, "s": -2}, "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1}, "N.m": {"kg": 1, "m": 2, "s": -2}, "A": {"A": 1}, "J": {"kg": 1, "m": 2, "s": -2},
    "1": {}, "1/s": {"s": -1}, "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1}, "s": {"s": 1},
}

INPUT_OF_INTERFACE = {
    "effort": ("screw_torque_nm", "N.m", "screw torque command (effort mode), right-handed about +z; "
               "saturated at max_effort_nm"),
    "velocity": ("screw_speed_command_rad_s", "rad/s", "screw speed command (velocity mode)"),
    "position": ("nut_position_command_m", "m", "nut position command (position mode)"),
}


@dataclass(frozen=True)
class Variable:
    """One FMU variable: `causality` is "input", "output" or "parameter" (tunable)."""

    name: str
    causality: str
    unit: str
    description: str


# Outputs every FMU has: name, unit, description, and how one step's Outputs give it.
_SCREW_OUTPUTS: tuple[tuple[str, str, str], ...] = (
    ("nut_position_m", "m", "nut position x_nut = (L/2π) θ_S (true)"),
    ("nut_velocity_m_s", "m/s", "nut velocity (true)"),
    ("nut_force_n", "N", "axial force the threads deliver to the nut (true)"),
    ("screw_angle_rad", "rad", "screw angle, right-handed about +z (true)"),
    ("screw_speed_rad_s", "rad/s", "screw speed (true)"),
    ("efficiency", "1", "mechanism efficiency over the step; NaN when no power reaches the load"),
    ("energy_residual_j", "J", "energy books' residual since the start (work in − out − Δstored − dissipated)"),
)
_PEAK_OUTPUTS = (
    ("peak_roller_load_n", "N", "largest screw- or nut-side normal force on any roller this step"),
    ("peak_tooth_load_n", "N", "largest normal force on any engaged tooth this step"),
)
_ACTUATOR_OUTPUTS = (
    ("motor_current_a", "A", "motor current"),
    ("motor_torque_nm", "N.m", "motor torque, screw side"),
    ("stop_force_n", "N", "end-stop contact force on the nut along +x_nut (negative at the upper stop)"),
)
_FLAG_OUTPUTS = (
    ("fault_active", "1", "1 while an injected actuator fault is active, else 0"),
    ("at_stop", "1", "1 while the nut presses on an end stop, else 0"),
    ("brake_engaged", "1", "1 while the holding brake is commanded engaged, else 0"),
)
_MEASURED_OUTPUTS = (  # (FMU name, unit, description, the quantity's name in MEASURED_QUANTITIES)
    ("measured_motor_angle_rad", "rad", "motor encoder angle (screw side) as measured", "motor_angle_rad"),
    ("measured_screw_angle_rad", "rad", "screw angle as measured", "screw_angle_rad"),
    ("measured_screw_speed_rad_s", "rad/s", "screw speed as measured", "screw_speed_rad_s"),
    ("measured_nut_position_m", "m", "nut position as measured", "nut_position_m"),
    ("measured_nut_velocity_m_s", "m/s", "nut velocity as measured", "nut_velocity_m_s"),
    ("measured_nut_force_n", "N", "nut force as measured by the load cell", "nut_force_n"),
)
_ACTUATOR_NAMES = tuple(n for n, _ in ACTUATOR_QUANTITIES)
_MEASURED_NAMES = tuple(n for n, _ in MEASURED_QUANTITIES)
# Tunable parameters with an actuator: FMU name → (group, field, unit, description); the drive's gains
# start at the values it was tuned to (DriveParams.tuned), so setting one changes only that one.
_DRIVE_TUNABLES = {
    "drive_speed_kp_nm_s_rad": ("drive", "speed_kp_nm_s_rad", "N.m.s/rad", "speed loop proportional gain"),
    "drive_speed_ki_nm_rad": ("drive", "speed_ki_nm_rad", "N.m/rad", "speed loop integral gain"),
    "drive_position_kp_1_s": ("drive", "position_kp_1_s", "1/s", "position loop gain"),
    "drive_speed_limit_rad_s": ("drive", "speed_limit_rad_s", "rad/s", "speed reference limit (screw)"),
}
_MOTOR_TUNABLES = {
    "motor_torque_limit_nm": ("motor", "torque_limit_nm", "N.m", "motor torque limit"),
    "motor_current_limit_a": ("motor", "current_limit_a", "A", "motor current limit"),
}


def brief(msg: str, limit: int = MAX_LOG_CHARS) -> str:
    """`msg` cut to `limit` characters, saying how much was left out."""
    return msg if len(msg) <= limit else f"{msg[:limit]}… ({len(msg) - limit} more characters not shown)"


def state_from_bytes(data: bytes) -> dict:
    """The FMU state serialised in `data` (UTF-8 JSON), or `{UNREADABLE: why}`; never raises.

    The slaves use it as pythonfmu's `_fmu_state_from_bytes`: an exception there would be fatal and
    corrupt the wrapper (see the module's notes); `SlaveCore.set_state` refuses the marker instead.
    """
    try:
        return json.loads(bytes(data).decode("utf-8"))
    except (ValueError, RecursionError, TypeError) as e:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        return {UNREADABLE: f"{len(data)} bytes that are not a serialised state ({type(e).__name__})"}


def _step_count(h: float, dt: float) -> int | None:
    """h as a whole number of model steps dt, or None when it is not one (to rounding)."""
    if not (h > 0.0 and math.isfinite(h)):
        return None
    k = round(h / dt)
    return k if k >= 1 and abs(h - k * dt) <= 1e-9 * h else None


class SlaveCore:
    """A `Session` as an FMI co-simulation slave.

    Parameters
    ----------
    resources : str
        The FMU's resources directory (holds `config.CONFIG_NAME`).
    log : callable(str, str)
        The FMU logger: `log(message, status)` with status "ok", "warning" or "error".
    """

    def __init__(self, resources: str, log: Callable[[str, str], None]) -> None:
        path = Path(resources) / CONFIG_NAME
        try:
            config = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as e:
            raise ParamError(f"{path}: cannot read the FMU's configuration ({e})") from None
        check_version(config)
        self.config = config
        self.log = lambda msg, status: log(brief(msg), status)
        with warnings.catch_warnings(record=True) as said:
            self.session = session_from_config(config)
            session_from_config(config).step()  # a throwaway copy compiles the first step here, not in a doStep
        self._log_warnings(said)
        s = self.session
        self.dt_s = s.dt_s
        self.interface = s.interface
        self.command_name = INPUT_OF_INTERFACE[self.interface][0]
        act = s.actuator
        # inputs: the active interface's command and the load, held over every step until set again
        self.inputs = {self.command_name: s.gate.value, "load_force_n": s.load_n}
        self.tunables: dict[str, float] = {"max_effort_nm": s.gate.max_effort_nm}
        self._tunable_meta = {"max_effort_nm": ("gate", "max_effort_nm", "N.m",
                                                "screw torque command limit (effort commands beyond it are saturated)")}
        if act is not None:
            drive = act.drive  # the tuned gains
            for name, (g, f, unit, desc) in _DRIVE_TUNABLES.items():
                self.tunables[name] = float(getattr(drive, f))
                self._tunable_meta[name] = (g, f, unit, desc)
            if act.actuator.motor is not None:
                for name, (g, f, unit, desc) in _MOTOR_TUNABLES.items():
                    self.tunables[name] = float(getattr(act.actuator.motor, f))
                    self._tunable_meta[name] = (g, f, unit, desc)
        # where each internal-load block sits in the flat vector (the layout is fixed for the FMU's life)
        at = s.layout.offsets()
        self._blocks = {b.name: (slice(at[b.name], at[b.name] + b.size), b.shape) for b in s.layout.blocks}
        self._has_peaks = "per_roller" in self._blocks and "per_tooth" in self._blocks
        if self._has_peaks:
            q = [n for n, _ in next(b for b in s.layout.blocks if b.name == "per_roller").quantities]
            self._normal_forces = [q.index("screw_normal_force_n"), q.index("nut_normal_force_n")]
        self.variables = self._variables(act is not None)
        self._refused: dict[str, str] = {}  # variable → why its last value was not taken
        self._row: dict[str, float] | None = None
        self._h = None  # the last communication step and its step count
        self._k = 0
        self.phase = "instantiated"  # → "initialising" → "stepping" → "terminated" (FMI's order of calls)
        self._origin_s: float | None = None  # importer time at session time 0, fixed by the first step taken

    # -- the FMI life cycle -------------------------------------------------------------------
    def enter_initialization(self) -> None:
        self.phase = "initialising"

    def exit_initialization(self) -> None:
        self.phase = "stepping"

    def terminate(self) -> None:
        self.phase = "terminated"

    # -- the variable list ------------------------------------------------------------------
    def _variables(self, with_actuator: bool) -> list[Variable]:
        cmd_name, cmd_unit, cmd_desc = INPUT_OF_INTERFACE[self.interface]
        out = [Variable(cmd_name, "input", cmd_unit, cmd_desc),
               Variable("load_force_n", "input", "N", "external axial load on the nut, positive resisting "
                                                     "positive nut motion")]
        out += [Variable(n, "output", u, d) for n, u, d in _SCREW_OUTPUTS]
        if self._has_peaks:
            out += [Variable(n, "output", u, d) for n, u, d in _PEAK_OUTPUTS]
        if with_actuator:
            out += [Variable(n, "output", u, d) for n, u, d in _ACTUATOR_OUTPUTS]
            out += [Variable(n, "output", u, d) for n, u, d, _ in _MEASURED_OUTPUTS]
            out += [Variable(n, "output", u, d) for n, u, d in _FLAG_OUTPUTS]
        out += [Variable(n, "parameter", m[2], m[3]) for n, m in self._tunable_meta.items()]
        return out

    # -- get / set ----------------------------------------------------------------------------
    def accessors(self, variable: Variable):
        """The (getter, setter) an FMI variable registers: setter None for an output."""
        name = variable.name
        getter = lambda: self.get(name)  # noqa: E731
        return getter, None if variable.causality == "output" else (lambda value: self.set(name, value))

    def get(self, name: str) -> float:
        """The variable's present value (outputs: of the last step, or at rest before the first)."""
        if name in self.inputs:
            return self.inputs[name]
        if name in self.tunables:
            return self.tunables[name]
        row = self._row
        if row is None:
            row = self._row = self._outputs()
        try:
            return row[name]
        except KeyError:  # the outputs read from the internal loads, built only when one is asked for
            row.update(self._internal_outputs())
            return row[name]

    def set(self, name: str, value: float) -> None:
        """Take an input or a tunable parameter; a value refused is logged and fails the next doStep."""
        try:
            if name in self.inputs:
                if not math.isfinite(value):
                    raise InputError(f"{name} = {value!r}: must be a finite number")
                self.inputs[name] = float(value)
            elif name in self.tunables:
                if value != self.tunables[name]:
                    self._tune(name, float(value))
            else:
                raise InputError(f"{name}: not an input or a tunable parameter of this FMU")
        except PrsmError as e:
            msg = str(e) if str(e).startswith(f"{name} = ") else f"{name} = {value!r} refused: {e}"
            self._refused[name] = msg
            self.log(msg, "error")
            return
        self._refused.pop(name, None)

    def _tune(self, name: str, value: float) -> None:
        """A new tunable parameter value, validated by the library (ParamError names it), applied between steps."""
        group, field, _, _ = self._tunable_meta[name]
        s = self.session
        if not math.isfinite(value):
            raise ParamError(f"{group}.{field} = {value!r}: must be a finite number")
        if group == "gate":
            s.configure_gate(value, s.gate.cmd_timeout_s, s.gate.timeout_behaviour)
        else:
            a = s.actuator_params
            # the drive's gains as tuned: explicit from now on, so the rebuilt drive keeps them
            drive = replace(a.drive, **{m[1]: self.tunables[n] for n, m in self._tunable_meta.items()
                                        if m[0] == "drive"})
            parts = {"drive": drive, "motor": a.motor}
            parts[group] = replace(parts[group], **{field: value})
            s.actuator_params = replace(a, **parts)
            with warnings.catch_warnings(record=True) as said:
                s.rebuild(s.params)
            self._log_warnings(said)
        self.tunables[name] = value
        self._row = None

    def _log_warnings(self, said: list[warnings.WarningMessage]) -> None:
        """What the library said without refusing while the session was built (a drive loop that cannot settle),
        through the FMU's logger, where the importer shows it: status "warning"."""
        for w in said:
            self.log(f"{w.category.__name__}: {w.message}", "warning")

    # -- stepping -----------------------------------------------------------------------------
    def do_step(self, current_time: float, step_size: float) -> str | None:
        """Advance the communication step; None, or why it failed (already logged)."""
        why = self._out_of_order(current_time)
        if why is not None:
            return self._fail(why + "; the step was not taken")
        if self._refused:
            return self._fail("; ".join(self._refused.values()) + "; the step was not taken")
        if step_size != self._h:
            k = _step_count(step_size, self.dt_s)
            if k is None:
                return self._fail(f"communication step {step_size!r} s: must be a whole multiple of the model "
                                  f"step dt_s = {self.dt_s!r} s")
            if k > MAX_RUN_STEPS:
                return self._fail(f"communication step {step_size!r} s: {k} model steps of {self.dt_s!r} s; at most "
                                  f"{MAX_RUN_STEPS} per doStep (the library's limit for one run)")
            self._h, self._k = step_size, k
        if self._origin_s is None:
            self._origin_s = current_time - self.session.time_s
        step, cmd, load = self.session.step, self.inputs[self.command_name], self.inputs["load_force_n"]
        self._row = None
        try:
            for _ in range(self._k):
                step(cmd, load)
        except ModelError as e:
            return self._fail(f"model failure at t = {self.session.time_s!r} s: {e}")
        except PrsmError as e:  # an input the session refuses (e.g. a position command off the threads)
            return self._fail(f"step refused at t = {self.session.time_s!r} s: {e}")
        return None

    def _out_of_order(self, current_time: float) -> str | None:
        """Why a doStep at `current_time` is out of FMI's order of calls, or None."""
        if self.phase != "stepping":
            return (f"doStep {'after terminate' if self.phase == 'terminated' else 'before initialisation ended'}: "
                    "steps are taken between exitInitializationMode and terminate")
        if not math.isfinite(current_time):
            return f"doStep at t = {current_time!r} s: the communication point must be a finite time"
        if self._origin_s is not None:
            at = self._origin_s + self.session.time_s
            if abs(current_time - at) > 0.5 * self.dt_s:  # to rounding of the importer's sum of steps
                return (f"doStep at t = {current_time!r} s: this instance is at t = {at!r} s "
                        f"({'back in time' if current_time < at else 'a gap'}); a step starts where the last one "
                        "ended, or at a saved state's time after setting it")
        return None

    def _fail(self, msg: str) -> str:
        self.log(msg, "error")
        return msg

    def _outputs(self) -> dict[str, float]:
        """The screw's outputs of the last step (or at rest), computed once per step when first read."""
        s = self.session
        out = s.last
        return {n: float(getattr(out, n)) for n, _, _ in _SCREW_OUTPUTS}

    def _internal_outputs(self) -> dict[str, float]:
        """The outputs read from the last step's internal loads (peaks, actuator, sensors, flags)."""
        s = self.session
        row: dict[str, float] = {}
        internal, blocks = s.last.internal, self._blocks

        def view(name: str) -> np.ndarray:
            at, shape = blocks[name]
            return internal[at].reshape(shape)
        if self._has_peaks:
            row["peak_roller_load_n"] = float(np.abs(view("per_roller")[:, self._normal_forces]).max())
            row["peak_tooth_load_n"] = float(np.abs(view("per_tooth")).max())
        if s.actuator is not None:
            a = dict(zip(_ACTUATOR_NAMES, view("actuator").tolist()))
            m = dict(zip(_MEASURED_NAMES, view("measured").tolist()))
            for n, _, _, q in _MEASURED_OUTPUTS:
                row[n] = m[q]
            row["motor_current_a"] = a["motor_current_a"]
            row["motor_torque_nm"] = a["motor_torque_nm"]
            row["stop_force_n"] = a["stop_force_n"]
            row["fault_active"] = 1.0 if a["faults_active"] > 0 else 0.0
            row["at_stop"] = 1.0 if a["stop_penetration_m"] > 0 else 0.0
            row["brake_engaged"] = 1.0 if s.simulator.state.brake_engaged else 0.0
        return row

    # -- state --------------------------------------------------------------------------------
    def get_state(self) -> dict:
        """Everything that decides the next steps, as JSON-able data."""
        return {"format": STATE_FORMAT, "prsm_version": __version__, "session": self.session.get_state(),
                "inputs": dict(self.inputs), "tunables": dict(self.tunables)}

    def set_state(self, state: dict) -> bool:
        """Continue from a state of `get_state` (this process or another): True when taken; refused →
        False, nothing changed, logged, and the next doStep fails until a good state is set."""
        before = self.get_state()
        try:
            self._apply_state(state)
        except _STATE_ERRORS as e:  # whatever the bytes held: nothing of it stays
            self._apply_state(before)
            msg = f"FMU state refused: {e}"
            self._refused["FMU state"] = msg
            self.log(msg, "error")
            return False
        self._refused.pop("FMU state", None)
        self._row = None
        return True

    def _apply_state(self, state: dict) -> None:
        """Check and apply a state of `get_state`; raises what the content gives rise to."""
        if isinstance(state, dict) and UNREADABLE in state:
            raise InputError(f"FMU state: {state[UNREADABLE]}")
        if not isinstance(state, dict) or state.get("format") != STATE_FORMAT:
            raise InputError(f"FMU state: not a prsm FMU state ({STATE_FORMAT})")
        if state.get("prsm_version") != __version__:
            raise InputError(f"FMU state saved by prsm {state.get('prsm_version')!r}: this is prsm "
                             f"{__version__!r}; a state continues only on the version that saved it")
        if set(state["inputs"]) != set(self.inputs) or set(state["tunables"]) != set(self.tunables):
            raise InputError("FMU state: its variables are not this FMU's (another build)")
        for name, value in state["tunables"].items():
            if value != self.tunables[name]:
                self._tune(name, float(value))
        self.session.set_state(state["session"])
        inputs = {k: float(v) for k, v in state["inputs"].items()}
        bad = [k for k, v in inputs.items() if not math.isfinite(v)]
        if bad:
            raise InputError(f"FMU state: input {bad[0]} = {inputs[bad[0]]!r}: must be a finite number")
        self.inputs = inputs


def life_cycle():
    """The slave's enterInitializationMode, exitInitializationMode and terminate, passed to its core
    (which then refuses a doStep out of FMI's order)."""
    def enter_initialization_mode(slave) -> None:
        slave.core.enter_initialization()

    def exit_initialization_mode(slave) -> None:
        slave.core.exit_initialization()

    def terminate(slave) -> None:
        slave.core.terminate()
    return enter_initialization_mode, exit_initialization_mode, terminate


def attach(slave, statuses: dict, experiment) -> SlaveCore:
    """The `SlaveCore` of a pythonfmu or pythonfmu3 slave, logging through it (`statuses` maps "ok",
    "warning", "error" to its status enum), with the slave's description and default experiment
    (`experiment`: its DefaultExperiment class) set from the FMU's configuration."""
    core = SlaveCore(slave.resources, lambda msg, status: slave.log(msg, statuses[status]))
    release_static_interpreter_handle(slave.resources)
    slave.author = "prsm"
    slave.version = core.config["prsm_version"]  # the model description's version: the prsm that built it
    slave.description = describe(core.config)
    slave.default_experiment = experiment(start_time=0.0, step_size=core.dt_s)
    return core


def release_static_interpreter_handle(resources: str) -> None:
    """Drop the reference the FMU binary's static keeps to its interpreter handle, where the importer is a
    Python command line on Linux; each instance keeps its own.

    pythonfmu's and pythonfmu3's exported binaries hold that handle (a shared pointer) in a static and also
    reset it from a library destructor (`finalizePythonInterpreter`, run by `onLibraryUnload`). At the
    importer's exit the static's own destructor runs first (C++ exit handlers, then the libraries' fini
    functions), so the reset reads, and may release again, the block the first freed: valgrind shows an
    invalid read in `finalizePythonInterpreter` of a block freed by the exit handlers, and now and then
    glibc aborts the importer at exit ("corrupted double-linked list", exit status -6) after a run that
    passed. With the static already empty neither exit path has anything to free.

    Only where `sys.orig_argv` is set (a `python` command started the interpreter): where the binary
    started it itself (a host that is not Python), the handle's end finalises the interpreter, which has
    to wait for the library's unload. `RTLD_NOLOAD` only finds the FMU's binary already loaded in this
    process (the one calling this); it never loads anything.
    """
    if not sys.platform.startswith("linux") or not getattr(sys, "orig_argv", None):
        return
    # FMI 2.0 puts the binary in binaries/linux64, FMI 3.0 in binaries/<arch>-linux
    for binary in sorted((Path(resources).parent / "binaries").glob("*/*.so")):
        try:
            library = ctypes.CDLL(str(binary), mode=os.RTLD_NOLOAD)
        except OSError:  # not loaded here
            continue
        release = getattr(library, "finalizePythonInterpreter", None)
        if release is not None:
            release()


def describe(config: dict) -> str:
    """One line for the model description: what plant this FMU is."""
    s = config["session"]
    what = "actuator" if config["actuator"] is not None else "bare screw (no actuator)"
    return (f"prsm {config['prsm_version']} planetary roller screw, parameters {config['params']['name']!r}, "
            f"model {config['model']}, step {config['dt_s']!r} s, {what}, {s['interface']} command")
