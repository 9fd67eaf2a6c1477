"""The node's ROS parameters: declarations (type, unit, range, description) and validation, no ROS.

Every parameter is declared by `prsm_ros.node.ros_node` from `NODE_PARAMETERS` plus one `physics.<group>.<name>`
parameter per `Params.override_keys()` key, whose default is the chosen preset's value. Values come
from a standard `ros__parameters` YAML file (`--ros-args --params-file FILE`), `-p name:=value`, or
`ros2 param set` at runtime. `NodeConfig.from_values` turns the flat name → value mapping into one
validated record, or raises `ConfigError` with one line naming the parameter, the value and what is
allowed; the node uses it at start-up (non-zero exit) and for every runtime change (rejected with
the reason, nothing changed).

Units are SI (REP 103). Doubles also accept integers (`cmd_timeout: 1`), because YAML and
`ros2 param set` type "1" as an integer and refusing it helps no one.

The actuator around the screw is configured by ordinary nested parameters, one per field of
`prsm_sim.actuator` (`actuator.<group>.<field>`, e.g. `actuator.stops.max_position_m`,
`actuator.drive.speed_bandwidth_hz`), plus `actuator.<group>.fitted` (true: the group with its
defaults; for the motor, false removes it). NaN stands for "none" where the field's value may be
None (no stop on that side, gains tuned from the inertia, no load-cell filter). Only names given
at start-up (`-p`, a params file) apply; they override the same field of the `actuator` string
form (a YAML mapping, still accepted); a given name with a value other than its default, or a
`fitted: true`, runs the actuator.

Faults injected from the start are nested the same way, one group per fault under a name of the
user's choosing: `faults.<name>.<field>` with the fields of `prsm_sim.actuator.Fault` (kind,
start_s, duration_s, value, sensor, roller). rclpy needs every parameter declared, so these are
found among the names given at start-up and declared read-only; they add to the faults of the
`faults` string list and of the `actuator` mapping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Any

from prsm_sim.errors import PrsmError
from prsm_sim import MODELS, PRESETS, ParamError, Params, preset
from prsm_sim.actuator import COMMAND_INTERFACES, ActuatorParams
from prsm_sim.params import parse_float

from prsm_ros.param_files import (ACTUATOR_GROUPS, ACTUATOR_PREFIX, FAULT_FIELDS, FAULT_START_LIMIT_S,  # noqa: F401
                                  FAULT_VALUE_LIMITS, FAULTS_PREFIX, bound_fault, is_fault_field, nested_faults)

from prsm_sim.command_gate import TIMEOUT_BEHAVIOURS

TIME_MODES = ("realtime", "fast", "lockstep")
EXECUTORS = ("events", "single")  # prsm_ros.node.executors makes them
RERUN_MODES = ("off", "save", "spawn", "connect")
PHYSICS_PREFIX = "physics."
ACTUATOR_SKIPPED = {("drive", "mode")}
DEFAULT_PRESET = "s30"
DEFAULT_MODEL = "jones2016"


class ConfigError(PrsmError, ValueError):
    """A node parameter was refused; the message names it, its value and what is allowed."""


@dataclass(frozen=True)
class NodeParam:
    """One node parameter: name, default (its type is the parameter's type), unit, meaning, limits.

    `lo`/`hi` bound numbers (inclusive unless `lo_open`), `choices` bounds strings; `read_only`
    parameters are fixed at start-up (changing them means a new run).
    """

    name: str
    default: Any
    unit: str
    description: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] | None = None
    read_only: bool = False
    nan_is_none: bool = False  # a double whose NaN means "none" (actuator fields that may be None)

    @property
    def allowed(self) -> str:
        """The constraint in words, for descriptors and error messages."""
        if self.nan_is_none:
            return "a number, or NaN for none"
        if self.choices is not None:
            return f"one of {', '.join(self.choices)}"
        if isinstance(self.default, bool):
            return "true or false"
        kind = "a whole number" if isinstance(self.default, int) else "a finite number"
        if self.lo is not None and self.hi is not None:
            return f"{kind} in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}]"
        if self.lo is not None:
            return f"{kind} {'>' if self.lo_open else '>='} {self.lo:g}"
        return kind if not isinstance(self.default, str) else "a string"


def _topic_params() -> list[NodeParam]:
    from prsm_ros.messages import TOPICS  # rclpy message classes: imported only when the node needs them
    return [NodeParam(f"topics.{t.key}", t.name, "", f"name of the {t.msg_class.__name__} {t.direction}put topic "
                      "(relative names follow the node's namespace; ~/ is the node)", read_only=True)
            for t in TOPICS.values() if t.key not in ("clock", "diagnostics")]


NODE_PARAMETERS: tuple[NodeParam, ...] = (
    NodeParam("preset", DEFAULT_PRESET, "", "named parameter set; physics.* parameters default to its values",
              choices=tuple(PRESETS), read_only=True),
    NodeParam("params_file", "", "", "a parameter file (prsm_sim parameter groups as YAML, e.g. from prsm-sim "
              "params -o): takes the place of preset; physics.* parameters default to its values", read_only=True),
    NodeParam("model", DEFAULT_MODEL, "", "dynamics model", choices=tuple(MODELS), read_only=True),
    NodeParam("update_rate", 1000, "Hz", "simulation steps per second of simulation time (step = 1/update_rate)",
              lo=1, hi=100_000, read_only=True),
    NodeParam("time_mode", "realtime", "", "realtime: paced at update_rate × real_time_factor on absolute "
              "deadlines; fast: as fast as possible; lockstep: lockstep_steps steps per received command",
              choices=TIME_MODES, read_only=True),
    NodeParam("real_time_factor", 1.0, "1", "simulated seconds per wall second in realtime mode",
              lo=0.0, hi=100.0, lo_open=True),
    NodeParam("realtime_priority", 10, "", "realtime: SCHED_FIFO priority of the step thread when the OS allows "
              "it, the node's other threads one below (0: normal scheduling); reported on /diagnostics",
              lo=0, hi=99, read_only=True),
    NodeParam("pacing_spin", 0.0, "s", "realtime: poll the clock for this long before each deadline instead "
              "of trusting the sleep's wake-up latency (CPU for jitter; 0: sleep only)", lo=0.0, hi=1e-2, read_only=True),
    NodeParam("step_thread_cpu", -1, "", "realtime: the CPU the step thread runs on, the node's other threads "
              "(executor, middleware, recorder and its writer process, Rerun) kept on the other CPUs the process may "
              "use; a controller is best kept off it too (-1: the OS places every thread); reported on /diagnostics",
              lo=-1, hi=1023, read_only=True),
    NodeParam("executor", "events", "", "what runs the callbacks (services, parameters, timers, lockstep "
              "commands): events, rclpy's C++ EventsExecutor (single where rclpy lacks it); single, rclpy's "
              "SingleThreadedExecutor in Python", choices=EXECUTORS, read_only=True),
    NodeParam("lockstep_steps", 1, "steps", "steps advanced per received command in lockstep mode", lo=1, hi=1_000_000),
    NodeParam("step_count", 1, "steps", "steps advanced by one ~/step call (std_srvs/Trigger) while paused",
              lo=1, hi=10_000_000),
    NodeParam("start_paused", False, "", "start paused (resume with ~/pause false, or prsm-ctl resume)",
              read_only=True),
    NodeParam("wait_for_controller", False, "", "start paused; the first command accepted from a controller "
              "resumes the node (that controller owns it from then on)", read_only=True),
    NodeParam("joint_states_rate", 0.0, "Hz", "publish rate of joint_states and ~/nut/wrench (0: every step)",
              lo=0.0, hi=1e6),
    NodeParam("internal_loads_rate", 100.0, "Hz", "DDS publish rate of ~/internal_loads in realtime and fast "
              "mode, and its rate to live views (0: every step); lockstep publishes every step; the bag records "
              "it at record_internal_loads_rate", lo=0.0, hi=1e6),
    NodeParam("diagnostics_rate", 1.0, "Hz", "publish rate of /diagnostics (wall time)", lo=0.01, hi=100.0),
    NodeParam("cmd_timeout", 0.5, "s", "command watchdog in simulation time (0 disables)", lo=0.0, hi=1e6),
    NodeParam("timeout_behaviour", "zero", "", "after cmd_timeout: zero torque, or hold the last command",
              choices=TIMEOUT_BEHAVIOURS),
    NodeParam("command_interface", "effort", "", "what the drive is commanded in: effort (screw torque N·m, "
              "~/screw_torque), velocity (screw speed rad/s, ~/velocity_command), position (nut position m, "
              "~/position_command); ~/joint_commands carries the active one", choices=COMMAND_INTERFACES),
    NodeParam("actuator", "", "", "the actuator around the screw as a YAML mapping of groups motor, drive, sensors, "
              "stops, brake (prsm_sim.actuator; '' = ideal: no motor, ideal sensors, bit for bit the bare model), "
              "e.g. \"{motor: {}, sensors: {encoder_counts_per_rev: 4096}, stops: {max_position_m: 0.3}}\"",
              read_only=True),
    NodeParam("faults", "", "", "faults injected from the start: 'kind=jam,start_s=1,duration_s=0.5,value=30; …' "
              "(kinds: see docs/actuator.md); at runtime: ~/inject_fault", read_only=True),
    NodeParam("max_effort", 50.0, "N·m", "screw torque limit; larger commands are saturated and counted",
              lo=0.0, hi=1e6, lo_open=True),
    NodeParam("initial_nut_position", 0.0, "m", "nut position at start and after ~/reset", lo=-1e3, hi=1e3),
    NodeParam("load_force", 0.0, "N", "external axial load on the nut, positive resisting positive nut motion",
              lo=-1e8, hi=1e8),
    NodeParam("record", True, "", "record every published and received topic to MCAP", read_only=True),
    NodeParam("record_internal_loads_rate", 0.0, "Hz", "rate at which the bag records ~/internal_loads, in every "
              "time mode (0: every step, the default; every other topic is recorded every step). A lower rate "
              "makes a smaller bag and a cheaper recorder (the internal loads are most of a step's bytes: 7 KB "
              "of fu2018's 7.2), but the bag's peaks and energy integrals are then those of the kept steps",
              lo=0.0, hi=1e6, read_only=True),
    NodeParam("record_path", "", "", "MCAP file, never overwritten ('' → ./prsm_<namespace_node>_<UTC "
              "yyyymmdd_HHMMSS>[_n].mcap, unique)", read_only=True),
    NodeParam("publish_clock", True, "", "publish /clock (with several actuators in one graph exactly one "
              "node should: set false on the others)", read_only=True),
    NodeParam("ownership_timeout", 1.0, "s", "wall seconds of silence after which the controller owning the "
              "actuator loses it (0: only ~/release_control ends ownership)", lo=0.0, hi=1e6),
    NodeParam("command_ownership", True, "", "the first participant to send a valid command owns the "
              "actuator; commands from others are refused and counted", read_only=True),
    NodeParam("joints.screw", "screw_joint", "", "name of the screw's revolute joint (joint_states, "
              "~/joint_commands, the URDF's continuous joint)", read_only=True),
    NodeParam("joints.nut", "nut_joint", "", "name of the nut's prismatic joint (joint_states, ~/joint_commands, "
              "the URDF)", read_only=True),
    NodeParam("frames.base", "base_link", "", "the URDF's fixed root link (the housing)", read_only=True),
    NodeParam("frames.screw", "screw_link", "", "the URDF's screw link", read_only=True),
    NodeParam("frames.nut", "nut_link", "", "the URDF's nut link, the frame of ~/nut/wrench", read_only=True),
    NodeParam("rerun", "off", "", "Rerun output (environment RERUN=off forces off)", choices=RERUN_MODES,
              read_only=True),
    NodeParam("rerun_target", "", "", "save: .rrd path; spawn: port; connect: viewer address ('' → default)",
              read_only=True),
    NodeParam("foxglove_port", 0, "", "serve every topic live to Foxglove (WebSocket) on this port (0: off)",
              lo=0, hi=65535, read_only=True),
    NodeParam("foxglove_host", "127.0.0.1", "", "address the Foxglove server binds to (127.0.0.1: this machine "
              "only; 0.0.0.0 exposes every topic to the network, unauthenticated)", read_only=True),
)


def actuator_parameters() -> tuple[NodeParam, ...]:
    """`actuator.<group>.fitted` and `actuator.<group>.<field>` for every field of the actuator's groups."""
    out = []
    for group, cls in ACTUATOR_GROUPS.items():
        what = "fit the default motor (false: none)" if group == "motor" else f"the {group} group at its defaults"
        out.append(NodeParam(f"{ACTUATOR_PREFIX}{group}.fitted", False, "", f"actuator: {what}; runs the actuator",
                             read_only=True))
        for f in fields(cls):
            if (group, f.name) in ACTUATOR_SKIPPED:
                continue
            kind = str(f.type)
            default = f.default
            none_ok = "None" in kind
            if none_ok and default is None:
                default = math.nan
            elif kind.startswith("int"):
                default = int(default)
            elif kind.startswith("float"):
                default = float(default)
            unit = unit_of(f.name)
            words = f.name[:-len(_unit_suffix(f.name))] if unit else f.name
            out.append(NodeParam(f"{ACTUATOR_PREFIX}{group}.{f.name}", default, unit,
                                 f"actuator {group}: {words.replace('_', ' ')} (prsm_sim.actuator.{cls.__name__})"
                                 + (f"; NaN: {NAN_MEANS.get(f.name, 'none')}" if none_ok else ""),
                                 read_only=True, nan_is_none=none_ok))
    return tuple(out)


def node_parameters() -> tuple[NodeParam, ...]:
    """All non-physics parameters: the node's, the actuator's nested ones, topic names (defaults from messages.TOPICS)."""
    return NODE_PARAMETERS + actuator_parameters() + tuple(_topic_params())


def physics_parameters(params: Params) -> dict[str, Any]:
    """`physics.<group>.<name>` → the value in `params` (the preset), one per Params.override_keys()."""
    d = params.to_dict()
    return {PHYSICS_PREFIX + key: d[key.split(".")[0]][key.split(".")[1]] for key in Params.override_keys()}


# what NaN ("None" in prsm_sim.actuator) means for the actuator's optional fields
NAN_MEANS = {"coupling_stiffness_nm_rad": "rigid coupling", "speed_kp_nm_s_rad": "tuned from the inertia",
             "speed_ki_nm_rad": "tuned from the inertia", "position_kp_1_s": "tuned from the inertia",
             "loop_rate_hz": "once per simulation step", "linear_encoder_resolution_m": "no linear encoder",
             "load_cell_bandwidth_hz": "unfiltered", "min_position_m": "no stop on this side",
             "max_position_m": "no stop on this side"}


def _unit_suffix(key: str) -> str:
    return next((s for s, _ in _UNITS if key.endswith(s)), "")


def unit_of(key: str) -> str:
    """Unit from the field-name suffix (the project names units in field names)."""
    return next((u for s, u in _UNITS if key.endswith(s)), "")


_UNITS = (("_kg_m3", "kg/m³"), ("_m2_s", "m²/s"), ("_kgm2", "kg·m²"), ("_n_s_m", "N·s/m"),
          ("_nm_s_rad", "N·m·s/rad"), ("_nm_rad", "N·m/rad"), ("_nm_a", "N·m/A"), ("_n_m", "N/m"),
          ("_rad_s", "rad/s"), ("_m_s", "m/s"), ("_1_s", "1/s"), ("_per_rev", "counts/rev"),
          ("_steps", "steps"), ("_kg", "kg"), ("_deg", "deg"), ("_hz", "Hz"), ("_ohm", "Ω"),
          ("_nm", "N·m"), ("_w", "W"), ("_a", "A"), ("_h", "H"), ("_s", "s"), ("_n", "N"), ("_m", "m"))


physics_unit = unit_of


@dataclass(frozen=True)
class NodeConfig:
    """The node's validated configuration (see NODE_PARAMETERS for meanings and units)."""

    values: dict[str, Any]  # every parameter by name, coerced (doubles as float)
    params: Params  # the preset with every physics.* value applied, validated
    topics: dict[str, str] = field(default_factory=dict)  # topic key → name
    actuator: ActuatorParams = field(default_factory=ActuatorParams)  # `actuator` + `faults` + the interface
    actuator_given: frozenset[str] = frozenset()  # the actuator.* names given at start-up (they apply)
    base: Params | None = None  # what physics.* apply to: the params_file's parameters, else the preset

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name == "values":
            raise AttributeError(name)
        try:
            return self.values[name]
        except KeyError:
            raise AttributeError(name) from None

    @property
    def joint_names(self) -> tuple[str, str]:
        """(screw, nut) joint names."""
        return self.values["joints.screw"], self.values["joints.nut"]

    @property
    def dt_s(self) -> float:
        return 1.0 / self.values["update_rate"]

    @property
    def with_actuator(self) -> bool:
        """Run the actuator around the screw: asked for by `actuator`, `faults` or a non-effort interface.
        Otherwise the node runs the bare model, publishing exactly what it did before the actuator existed."""
        v = self.values
        nested = {p.name: p.default for p in actuator_parameters() if p.name in self.actuator_given}
        asked = any((n.endswith(".fitted") and v[n]) or not _same(v[n], d) for n, d in nested.items())
        faults = bool(v["faults"].strip()) or any(k.startswith(FAULTS_PREFIX) for k in v)
        return bool(v["actuator"].strip()) or faults or v["command_interface"] != "effort" or asked

    @classmethod
    def from_values(cls, values: dict[str, Any], given: frozenset[str] | set[str] | None = None,
                    base: Params | None = None) -> NodeConfig:
        """Validate a full name → value mapping (node and physics parameters); ConfigError on the first problem.

        `given`: the actuator.* names set at start-up; None takes those whose value differs from the default.
        `base`: the parameters the physics.* values apply to (None: read from `params_file`, else the preset).
        """
        out: dict[str, Any] = {p.name: check_value(p, values.get(p.name, p.default)) for p in node_parameters()}
        out.update((k, v) for k, v in values.items() if is_fault_field(k))  # the nested faults (read-only)
        base = base if base is not None else base_params(out)
        params = _physics(base, values, out["model"])
        _check_on_threads(out["initial_nut_position"], params)
        _check_names(out)
        _check_cpu(out["step_thread_cpu"])
        topics = {k[len("topics."):]: v for k, v in out.items() if k.startswith("topics.")}
        if given is None:
            given = {p.name for p in actuator_parameters() if not _same(out[p.name], p.default)}
        given = frozenset(n for n in given if n.startswith(ACTUATOR_PREFIX))
        return cls(values=out, params=params, topics=topics, actuator=actuator_config(out, params, given),
                   actuator_given=given, base=base)


def base_params(values: dict[str, Any]) -> Params:
    """The parameters physics.* apply to: the `params_file` when given (it takes the place of `preset`),
    else the preset. ConfigError naming the parameter for an unreadable or invalid file."""
    path = values.get("params_file", "")
    if not path:
        return preset(values["preset"])
    if values["preset"] != DEFAULT_PRESET:
        raise ConfigError(f"parameters preset = {values['preset']!r} and params_file = {path!r}: give one of them "
                          "(a parameter file may name its own base with `preset:`)")
    from prsm_ros.param_files import load_params_file
    try:
        return load_params_file(path)
    except (ParamError, OSError) as e:
        raise ConfigError(f"parameter params_file = {path!r}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None


def _physics(base: Params, values: dict[str, Any], model: str) -> Params:
    """`base` with the physics.* values of `values`, checked by the model (ConfigError naming the parameter)."""
    phys = {k[len(PHYSICS_PREFIX):]: v for k, v in values.items() if k.startswith(PHYSICS_PREFIX)}
    try:
        params = base.with_overrides(phys)
        MODELS[model].check_params(params)  # combinations a model refuses (fu2018: line_of_centres)
    except ParamError as e:
        raise ConfigError(f"{PHYSICS_PREFIX}{e}") from None
    return params


def _check_on_threads(x: float, params: Params) -> None:
    """initial_nut_position on the threads of `params` (the session refuses a start or a reset elsewhere)."""
    travel = params.geometry.travel_m
    if travel is not None and abs(x) > 0.5 * travel:
        raise ConfigError(f"parameter initial_nut_position = {x!r}: must lie on the threads, |x| <= {0.5 * travel:g} m "
                          "((physics.geometry.screw_length_m - nut_length_m)/2; physics.geometry.thread_ends "
                          "= false removes the ends)")


def _check_names(out: dict[str, Any]) -> None:
    """Joint and frame names: non-empty, no spaces, quotes or <>& (they go into the URDF), distinct."""
    for group in (("joints.screw", "joints.nut"), ("frames.base", "frames.screw", "frames.nut")):
        names = [out[n] for n in group]
        for n in group:
            if not out[n].strip() or any(c in out[n] for c in " \t\n\"'<>&"):
                raise ConfigError(f"parameter {n} = {out[n]!r}: must be a non-empty name without spaces, "
                                  "quotes or <>&")
        if len(set(names)) != len(names):
            raise ConfigError(f"parameters {', '.join(group)} = {names}: must differ")


def _check_cpu(cpu: int) -> None:
    """step_thread_cpu: -1, or a CPU this process may run on, leaving another for the node's other threads."""
    from prsm_ros.node.scheduling import allowed_cpus, cpu_list
    allowed = allowed_cpus()
    if cpu < 0 or not allowed:  # off, or an OS that does not say (the thread's pinning then says it was refused)
        return
    if len(allowed) < 2:
        raise ConfigError(f"parameter step_thread_cpu = {cpu}: must be -1 here: this process may run on "
                          f"{cpu_list(allowed)} only, and the node's other threads need a CPU besides the step thread's")
    if cpu not in allowed:
        raise ConfigError(f"parameter step_thread_cpu = {cpu}: must be -1 or one of the CPUs this process may run on "
                          f"({', '.join(map(str, sorted(allowed)))})")


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN (a NaN default means none)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


def actuator_config(values: dict[str, Any], params: Params, given: frozenset[str] = frozenset()) -> ActuatorParams:
    """`prsm_ros.param_files.actuator_config` (where parameter files are read), refusing in a ConfigError."""
    from prsm_ros.param_files import actuator_config as read_actuator
    try:
        return read_actuator(values, params, given)
    except ParamError as e:
        raise ConfigError(str(e)) from None


def fault_field_names(name: str) -> list[str]:
    """The valid names of the fault group `name` (under faults.) lies in: the known names for a typo's hint."""
    parts = name.split(".")
    if len(parts) < 2 or parts[0] + "." != FAULTS_PREFIX or not parts[1]:
        return []
    return [f"{FAULTS_PREFIX}{parts[1]}.{k}" for k in FAULT_FIELDS]


def check_value(p: NodeParam, value: Any) -> Any:
    """The value coerced to the parameter's type, or ConfigError naming the parameter and what is allowed."""
    if p.nan_is_none and _means_none(value):
        return math.nan
    d = p.default
    if isinstance(d, bool):
        if not isinstance(value, bool):
            raise _bad(p, value)
        return value
    if isinstance(d, str):
        return _check_text(p, value)
    return _check_number(p, value)


def _bad(p: NodeParam, value: Any, why: str = "") -> ConfigError:
    unit = f" ({p.unit})" if p.unit and p.unit != "1" else ""
    return ConfigError(f"parameter {p.name} = {value!r}: must be {why or p.allowed}{unit}")


def _means_none(value: Any) -> bool:
    """None, NaN, or a word for them (a field whose NaN means none)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return True
    return isinstance(value, str) and value.strip().lower() in ("nan", ".nan", "none", "null")


def _check_text(p: NodeParam, value: Any) -> str:
    if not isinstance(value, str):
        raise _bad(p, value, "a string" if p.choices is None else p.allowed)
    if p.choices is not None and value not in p.choices:
        raise _bad(p, value)
    if p.name.startswith("topics."):
        why = _topic_name_problem(value)
        if why:
            raise _bad(p, value, f"a valid ROS topic name ({why})")
    return value


def _check_number(p: NodeParam, value: Any) -> int | float:
    d = p.default
    if isinstance(value, str) and isinstance(d, float):  # YAML 1.1 reads "1e-5" as a string
        try:
            value = parse_float(value, p.name)
        except ParamError:
            raise _bad(p, value) from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (isinstance(d, int) and not isinstance(value, int)):
        raise _bad(p, value)
    if not math.isfinite(value):
        raise _bad(p, value)
    lo_ok = p.lo is None or (value > p.lo if p.lo_open else value >= p.lo)
    if not lo_ok or (p.hi is not None and value > p.hi):
        raise _bad(p, value)
    return value if isinstance(d, int) else float(value)


def _topic_name_problem(name: str) -> str | None:
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_topic_name import validate_topic_name
    try:
        validate_topic_name(name)
    except InvalidTopicNameException as e:
        return str(e).splitlines()[0].split(": ", 1)[-1]
    return None


def check_preset(name: Any) -> Params:
    """The preset's Params, or ConfigError naming the known ones (checked before physics.* are declared)."""
    if not isinstance(name, str) or name not in PRESETS:
        raise ConfigError(f"parameter preset = {name!r}: must be one of {', '.join(PRESETS)}")
    return preset(name)


def runtime_change(old: NodeConfig, changes: dict[str, Any]) -> NodeConfig:
    """The new config after a runtime change, or ConfigError with the reason (nothing changes then).

    Read-only parameters are refused by ROS before this runs. A physics change that would alter
    the internal-load layout (e.g. the number of rollers) is refused: the latched labels and the
    MCAP channels describe one layout per run.
    """
    from prsm_sim import build_model
    if "" in changes:
        raise ConfigError("a parameter named '' is not a parameter of this node")
    new = NodeConfig.from_values({**old.values, **physics_parameters(old.params), **changes}, old.actuator_given,
                                 base=old.base)
    if new.params != old.params:
        changed = ", ".join(f"{k} = {changes[k]!r}" for k in sorted(changes) if k.startswith(PHYSICS_PREFIX))
        before = build_model(old.params, old.model, old.dt_s).layout
        try:  # the model the session would rebuild: values each valid alone may still leave it singular
            after = build_model(new.params, new.model, new.dt_s).layout
        except PrsmError:
            raise
        except (ArithmeticError, ValueError) as e:
            raise ConfigError(f"{changed}: model {old.model} cannot be built with it "
                              f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})") from None
        if after != before:
            raise ConfigError(f"{changed}: changes the internal-load layout of model {old.model} "
                              f"({before.size} → {after.size} elements); set it at start-up instead")
    return new


def physics_type(params: Params, key: str) -> type:
    """int, str or float: the type of a physics.<group>.<name> parameter, from the dataclass field."""
    group, name = key[len(PHYSICS_PREFIX):].split(".")
    gcls = type(getattr(params, group))
    ann = str(next(f.type for f in fields(gcls) if f.name == name))
    return int if ann.startswith("int") else str if ann.startswith("str") else float


def params_template(preset_name: str = DEFAULT_PRESET, node_name: str = "prsm_actuator") -> str:
    """A complete `ros__parameters` YAML file with every parameter at its default, units in comments."""
    import yaml
    lines = ["# prsm-node parameters; use with: prsm-node --ros-args --params-file FILE", f"{node_name}:",
             "  ros__parameters:"]
    nested = []
    for p in node_parameters():
        if p.name == "preset":
            value = preset_name
        else:
            value = p.default
        unit = f" [{p.unit}]" if p.unit and p.unit != "1" else ""
        text = yaml.safe_dump({p.name: value}, default_flow_style=True).strip()[1:-1]
        line = f"{text}  # {p.description}{unit}; {p.allowed}"
        if p.name.startswith(ACTUATOR_PREFIX):
            nested.append(line)
        else:
            lines.append(f"    {line}")
    # commented out: a name given runs the actuator and overrides the `actuator` mapping (module doc)
    lines.append("    # the actuator (prsm_sim.actuator), one name per field: uncomment what you set; any of them "
                 "runs the actuator")
    lines += [f"    # {line}" for line in nested]
    lines.append(f"    # faults injected from the start, one group {FAULTS_PREFIX}<name>.<field> per fault (fields "
                 f"{', '.join(FAULT_FIELDS)}; read-only; they add to `faults`), e.g.:")
    lines.append("    # faults: {jam1: {kind: jam, start_s: 2.0, duration_s: 0.5, value: 30.0}}")
    for key, value in physics_parameters(check_preset(preset_name)).items():
        unit = physics_unit(key)
        text = yaml.safe_dump({key: value}, default_flow_style=True).strip()[1:-1]
        lines.append(f"    {text}" + (f"  # [{unit}]" if unit else ""))
    return "\n".join(lines) + "\n"


# -- where the start-up values come from ---------------------------------------------------------
# rclpy's own parameters: a node accepts them without declaring them itself
RCLPY_PARAMETERS = ("use_sim_time", "start_type_description_service")


@dataclass(frozen=True)
class ParamSources:
    """The parameter names of the command line, by where they come from.

    `own`: `-p` and sections naming this node exactly (a name there that the node does not have is
    an error); `wildcard`: sections matching it through `*` or `**` (other nodes' names are normal
    there); `unmatched_files`: params files with no section for this node → the sections they have.
    """

    own: dict[str, str] = field(default_factory=dict)  # name → where it was given
    wildcard: dict[str, str] = field(default_factory=dict)
    unmatched_files: dict[str, list[str]] = field(default_factory=dict)
    node: str = "/prsm_actuator"  # the node's full name the sections were matched against

    def warnings(self) -> list[str]:
        return [f"{f}: no section for {self.node} (sections: {', '.join(s) or 'none'}); its parameters do not apply"
                for f, s in self.unmatched_files.items()]


def _ros_args(args: list[str]) -> list[str]:
    """The arguments inside --ros-args … [--] blocks."""
    out, inside = [], False
    for a in args:
        if a == "--ros-args":
            inside = True
        elif a == "--":
            inside = False
        elif inside:
            out.append(a)
    return out


def _section_matches(key: str, fqn: str) -> str | None:
    """'own' when a params-file section names the node `fqn` exactly, 'wildcard' through * or **, else None."""
    import re
    k = key if key.startswith("/") else "/" + key
    if "*" not in k:
        return "own" if k == fqn else None
    rx = "".join(".*" if part == "**" else "[^/]*" if part == "*" else re.escape(part)
                 for part in re.split(r"(\*\*|\*)", k))
    # rcl: "/**/name" matches "/name" too (** stands for any number of namespace levels, zero included)
    rx = rx.replace("/.*/", "(/.*)?/")
    return "wildcard" if re.fullmatch(rx, fqn) else None


def _flatten(d: dict, prefix: str = "") -> list[str]:
    names = []
    for k, v in d.items():
        name = f"{prefix}{k}"
        names += _flatten(v, name + ".") if isinstance(v, dict) and v else [name]  # rcl keeps `x: {}` as x
    return names


def param_sources(args: list[str], node_name: str, namespace: str = "/") -> ParamSources:
    """Read the command line's `-p` and `--params-file` names (ConfigError for a missing, unreadable,
    oversized or non-YAML file, in one line naming it). Remaps of __node and __ns are followed."""
    ros = _ros_args(args)
    node_name, fqn = _remapped(ros, node_name, namespace)
    own: dict[str, str] = {}
    wild: dict[str, str] = {}
    unmatched: dict[str, list[str]] = {}
    for flag, value in zip(ros, ros[1:]):
        if flag in ("-p", "--param") and ":=" in value:
            name = _param_arg_name(value, node_name, fqn)
            if name is not None:
                own[name] = "-p"
        elif flag == "--params-file":
            _params_file_names(value, fqn, own, wild, unmatched)
    for name in own:
        wild.pop(name, None)
    return ParamSources(own, wild, unmatched, fqn)


def _remapped(ros: list[str], node_name: str, namespace: str) -> tuple[str, str]:
    """(node name, full name) after the command line's remaps of __node and __ns."""
    for flag, value in zip(ros, ros[1:]):
        if flag in ("-r", "--remap") and ":=" in value:
            lhs, rhs = value.split(":=", 1)
            target = lhs.rsplit(":", 1)[-1] if lhs.count(":") else lhs
            if target == "__node" and (lhs == "__node" or lhs.split(":")[0] == node_name):
                node_name = rhs
            elif target == "__ns" and (lhs == "__ns" or lhs.split(":")[0] == node_name):
                namespace = rhs
    return node_name, ("/" + namespace.strip("/") if namespace.strip("/") else "") + "/" + node_name


def _param_arg_name(value: str, node_name: str, fqn: str) -> str | None:
    """The name a `-p NAME:=VALUE` gives this node (None: it addresses another node)."""
    name = value.split(":=", 1)[0]
    if name.count(":") == 1:  # node:name:=value addresses one node
        target, name = name.split(":")
        if target not in (node_name, fqn):
            return None
    text = value.split(":=", 1)[1].strip()
    if text.startswith("{"):  # rcl reads -p values as YAML scalars or lists, never mappings
        raise ConfigError(f"-p {value}: rcl cannot read a YAML mapping after := (in a shell, "
                          f"-p {name}:=\"{{…}}\" reaches it without its quotes); give the nested names "
                          f"(-p {name}.motor.fitted:=true …) or quote the whole argument: "
                          f"-p '{name}:=\"{{…}}\"'")
    return name


def _params_file_names(path: str, fqn: str, own: dict, wild: dict, unmatched: dict) -> None:
    """The names a `--params-file` gives the node `fqn`, into `own` or `wild` by how its section matches."""
    # regular, bounded, UTF-8 (rcl's parser takes minutes on 9 MB), its depth, aliases and sections bounded
    from prsm_ros.limits import NODE_PARAMS_MAX_SECTIONS, load_yaml, read_text_file
    text = read_text_file(path, what="parameters file", error=ConfigError)
    doc = load_yaml(text, source=f"--params-file {path}", error=ConfigError, max_top_keys=NODE_PARAMS_MAX_SECTIONS)
    if not isinstance(doc, dict):
        raise ConfigError(f"--params-file {path}: expected a mapping of node names to {{ros__parameters: {{...}}}}")
    matched = False
    for key, section in doc.items():
        kind = _section_matches(str(key), fqn)
        if kind is None:
            continue
        params = section.get("ros__parameters") if isinstance(section, dict) else None
        if not isinstance(params, dict):
            raise ConfigError(f"--params-file {path}: section {key}: expected ros__parameters: {{...}}")
        matched = True
        for name in _flatten(params):
            (own if kind == "own" else wild)[name] = f"{path}, section {key}"
    if not matched:
        unmatched[path] = [str(k) for k in doc]


def nearest_hint(name: str, known: list[str]) -> str:
    """'; did you mean NAME?' for the closest known name, else where the names are listed."""
    import difflib
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    return f"; did you mean {close[0]}?" if close else "; prsm-node --help lists them"


def unknown_parameter(name: str, where: str, known: list[str]) -> str:
    """The one line that refuses a parameter this node does not have, with the nearest valid name."""
    return f"unknown parameter {name} ({where}){nearest_hint(name, known)}"


# ROS arguments that take the next argument as their value (rcl's --ros-args grammar)
ROS_VALUE_FLAGS = {"-p": "NAME:=VALUE", "--param": "NAME:=VALUE", "-r": "FROM:=TO", "--remap": "FROM:=TO",
                   "--params-file": "FILE", "--log-level": "LEVEL", "-e": "ENCLAVE", "--enclave": "ENCLAVE",
                   "--log-file-name": "NAME"}


def check_ros_args(args: list[str]) -> None:
    """ConfigError in one line for a malformed ROS argument (rcl would raise an RCLError at init):
    a flag without its value, `-p` without `:=` or with an empty name or value, a remap of the node's
    name or namespace to an invalid one."""
    ros = _ros_args(args)
    i = 0
    while i < len(ros):
        flag = ros[i]
        if flag not in ROS_VALUE_FLAGS:
            i += 1
            continue
        value = ros[i + 1] if i + 1 < len(ros) else None
        if value is None or value in ROS_VALUE_FLAGS:
            raise ConfigError(f"ROS argument {flag}: expected {ROS_VALUE_FLAGS[flag]} after it")
        if flag in ("-p", "--param"):
            _check_param_arg(value)
        elif flag in ("-r", "--remap"):
            _check_remap_arg(value)
        i += 2


def _check_param_arg(value: str) -> None:
    name, sep, text = value.partition(":=")
    if not sep or not name.strip():
        raise ConfigError(f"-p {value}: expected NAME:=VALUE")
    if not text.strip():
        raise ConfigError(f"-p {value}: no value after := (an empty string is -p '{name}:=\"\"')")


def _check_remap_arg(value: str) -> None:
    lhs, sep, rhs = value.partition(":=")
    if not sep or not lhs or not rhs:
        raise ConfigError(f"-r {value}: expected FROM:=TO")
    target = lhs.rsplit(":", 1)[-1]
    if target == "__ns":
        from rclpy.exceptions import InvalidNamespaceException
        from rclpy.validate_namespace import validate_namespace
        try:
            validate_namespace(rhs if rhs.startswith("/") else "/" + rhs)
        except InvalidNamespaceException as e:
            raise ConfigError(f"-r {value}: not a valid namespace ({str(e).splitlines()[0].split(': ', 1)[-1].rstrip(':')})") from None
    elif target == "__node":
        from rclpy.exceptions import InvalidNodeNameException
        from rclpy.validate_node_name import validate_node_name
        try:
            validate_node_name(rhs)
        except InvalidNodeNameException as e:
            raise ConfigError(f"-r {value}: not a valid node name ({str(e).splitlines()[0].split(': ', 1)[-1].rstrip(':')})") from None
