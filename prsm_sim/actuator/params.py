"""Frozen, validated parameter groups of the actuator around the screw.

The defaults are ideal: no motor (the command is the screw torque itself), a drive in
`effort` mode, ideal sensors, no end stops, no brake and no faults. An `Actuator` built from
`ActuatorParams()` steps exactly as the bare screw model does (bit for bit).

Coordinates: the drive's speed and position loops work in screw coordinates (screw rad/s,
nut m); the motor turns `gear_ratio` times per screw turn (ideal, lossless gear or belt).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

from prsm_sim.errors import ParamError
from prsm_sim.params import END_STOP_STIFFNESS_N_M
from prsm_sim.params import check_field as _check
from prsm_sim.params import check_non_negative as _non_negative
from prsm_sim.params import check_positive as _positive
from prsm_sim.params import is_finite_number as _finite

COMMAND_INTERFACES = ("effort", "velocity", "position")
FAULT_KINDS = ("friction_surge", "jam", "lubrication_loss", "sensor_stuck", "sensor_bias", "sensor_noise",
               "sensor_dropout", "torque_limit_drop", "drive_fault", "backlash")
SENSORS = ("motor_encoder", "linear_encoder", "load_cell")


def check_interface(name: object) -> str:
    """The command interface `name`, or a ParamError naming the allowed ones."""
    if name not in COMMAND_INTERFACES:
        raise ParamError(f"command_interface = {name!r}: must be one of {', '.join(COMMAND_INTERFACES)}")
    return str(name)


@dataclass(frozen=True)
class MotorParams:
    """A servo motor with an equivalent first-order current loop (the drive's inner loop).

    The current follows its reference as i' = ω_c (i_ref − i) with ω_c = 2π
    `current_bandwidth_hz`; the winding's `resistance_ohm` and `inductance_h` only enter the
    energy ledger (copper loss R i², magnetic energy ½ L i²) and the reported voltage
    u = R i + L di/dt + k_t ω_m (k_e = k_t in SI units). Torque k_t i, limited by
    `current_limit_a` and `torque_limit_nm` (whichever is lower). `gear_ratio`: motor turns per
    screw turn (lossless). `coupling_stiffness_nm_rad` = None couples motor and screw rigidly
    (the rotor inertia is then added to the screw's, exact for every model); a number makes a
    torsional spring (screw side, N·m/rad) with `coupling_damping_nm_s_rad` in parallel.
    """

    rotor_inertia_kgm2: float = 1.2e-4
    torque_constant_nm_a: float = 0.5
    resistance_ohm: float = 1.0
    inductance_h: float = 2e-3
    current_bandwidth_hz: float = 1000.0
    current_limit_a: float = 20.0
    torque_limit_nm: float = 10.0
    speed_limit_rad_s: float = 500.0
    gear_ratio: float = 1.0
    coupling_stiffness_nm_rad: float | None = None
    coupling_damping_nm_s_rad: float = 0.0

    def __post_init__(self) -> None:
        g = "motor"
        _positive(g, self, "rotor_inertia_kgm2", "torque_constant_nm_a", "current_bandwidth_hz", "current_limit_a",
                  "torque_limit_nm", "speed_limit_rad_s", "gear_ratio")
        _non_negative(g, self, "resistance_ohm", "inductance_h", "coupling_damping_nm_s_rad")
        if self.coupling_stiffness_nm_rad is not None:
            _positive(g, self, "coupling_stiffness_nm_rad")

    @property
    def peak_torque_nm(self) -> float:
        """Motor torque limit: min(torque limit, k_t × current limit)."""
        return min(self.torque_limit_nm, self.torque_constant_nm_a * self.current_limit_a)


@dataclass(frozen=True)
class DriveParams:
    """Servo drive: mode, loops, limits and loop rate.

    Velocity loop (screw coordinates): τ_ref = kp (ω_ref − ω_meas) + ki ∫(ω_ref − ω_meas) dt,
    ω from the motor encoder over the gear ratio; the integrator stops where the output meets
    the torque limit (anti-windup). Position loop (cascade): ω_ref = kp_pos (x_ref − x_meas) /
    (L/2π), x from the linear encoder if fitted, else the motor encoder × L/2π / gear ratio.
    Gains left None are tuned from the inertia J the drive sees (screw, nut, carrier and rotor)
    for `speed_bandwidth_hz` = f: kp = J·2πf (the speed loop's crossover at 2πf), ki = kp·2πf/4,
    kp_pos = 2πf/5 (the position loop a fifth of the speed loop's bandwidth).
    `loop_rate_hz` None runs the loops once per simulation step; a faster rate sub-steps the
    step (screw model at the sub-step), a slower one holds the output between updates.
    `speed_limit_rad_s` (screw) clamps the speed reference. `position_feedforward`: the position
    loop follows a reference shaped from the command (`drive.shape_reference`: at most the speed
    limit and half the torque limit's acceleration on the inertia it drives, braking to stop at
    the command) and adds its rate to the speed reference: no lag on a moving command, and a
    command step neither kicks the torque nor rises slower than the loop alone would.
    """

    mode: str = "effort"
    speed_bandwidth_hz: float = 30.0
    speed_kp_nm_s_rad: float | None = None
    speed_ki_nm_rad: float | None = None
    position_kp_1_s: float | None = None
    speed_limit_rad_s: float = 300.0
    loop_rate_hz: float | None = None
    position_feedforward: bool = True

    def __post_init__(self) -> None:
        g = "drive"
        _check(g, "position_feedforward", self.position_feedforward, isinstance(self.position_feedforward, bool),
               "must be true or false")
        try:
            check_interface(self.mode)
        except ParamError:
            raise ParamError(f"drive.mode = {self.mode!r}: must be one of {', '.join(COMMAND_INTERFACES)}") from None
        _non_negative(g, self, *(n for n in ("speed_kp_nm_s_rad", "speed_ki_nm_rad", "position_kp_1_s")
                                 if getattr(self, n) is not None))
        _positive(g, self, "speed_limit_rad_s", "speed_bandwidth_hz")
        if self.loop_rate_hz is not None:
            _positive(g, self, "loop_rate_hz")

    def tuned(self, inertia_kgm2: float) -> DriveParams:
        """These parameters with every gain left None tuned for `speed_bandwidth_hz` on `inertia_kgm2`."""
        w = 2.0 * math.pi * self.speed_bandwidth_hz
        kp = self.speed_kp_nm_s_rad if self.speed_kp_nm_s_rad is not None else inertia_kgm2 * w
        ki = self.speed_ki_nm_rad if self.speed_ki_nm_rad is not None else kp * w / 4.0
        kx = self.position_kp_1_s if self.position_kp_1_s is not None else w / 5.0
        return replace(self, speed_kp_nm_s_rad=kp, speed_ki_nm_rad=ki, position_kp_1_s=kx)


@dataclass(frozen=True)
class SensorParams:
    """Motor encoder, optional nut linear encoder and nut load cell (0 / None = ideal).

    - `encoder_counts_per_rev`: motor encoder counts per motor turn (0: no quantisation);
      speed is then the difference of quantised angles over the step.
    - `linear_encoder_resolution_m`: None = not fitted; 0 = fitted and ideal.
    - load cell: the amplifier's `load_cell_bias_n` and white Gaussian noise `load_cell_noise_n`
      (1σ in N of each sample at the simulation step rate f_s = 1/dt), then an anti-alias
      first-order low-pass `load_cell_bandwidth_hz` f_c (None: none) that filters both: the
      reading's σ is `load_cell_noise_n` · √((1 − a)/(1 + a)), a = exp(−2π f_c/f_s), about
      √(π f_c/f_s) of it for f_c ≪ f_s (unfiltered: independent of f_s).
    - `latency_steps`: every published measurement is this many simulation steps old (the
      drive reads its own encoders fresh at its loop rate; their quantisation and faults apply).
    - `dropout_probability`: per sample and sensor; a dropped sample repeats the last one.
    - `seed`: noise and dropout draw from a counter-based generator keyed by (seed, step), so
      a step stays a pure function of (state, inputs) and lockstep runs repeat bit for bit.
    """

    encoder_counts_per_rev: int = 0
    linear_encoder_resolution_m: float | None = None
    load_cell_noise_n: float = 0.0
    load_cell_bias_n: float = 0.0
    load_cell_bandwidth_hz: float | None = None
    latency_steps: int = 0
    dropout_probability: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        g = "sensors"
        for n in ("encoder_counts_per_rev", "latency_steps", "seed"):
            v = getattr(self, n)
            _check(g, n, v, isinstance(v, int) and not isinstance(v, bool) and v >= 0, "must be a whole number >= 0")
        if self.linear_encoder_resolution_m is not None:
            _non_negative(g, self, "linear_encoder_resolution_m")
        _non_negative(g, self, "load_cell_noise_n")
        _check(g, "load_cell_bias_n", self.load_cell_bias_n, _finite(self.load_cell_bias_n), "must be a finite number")
        if self.load_cell_bandwidth_hz is not None:
            _positive(g, self, "load_cell_bandwidth_hz")
        p = self.dropout_probability
        _check(g, "dropout_probability", p, _finite(p) and 0 <= p < 1, "must lie in [0, 1)")

    @property
    def ideal(self) -> bool:
        return self == SensorParams(seed=self.seed)


@dataclass(frozen=True)
class StopParams:
    """Stroke limits with stiff, damped hard stops on the nut (None: no stops).

    Contact force F = k δ + c δ' on penetration δ > 0, never pulling (F ≥ 0), treated
    implicitly over the step so a stiff stop stays stable at 1 ms.
    """

    min_position_m: float | None = None
    max_position_m: float | None = None
    stiffness_n_m: float = END_STOP_STIFFNESS_N_M
    damping_n_s_m: float = 2e5

    def __post_init__(self) -> None:
        g = "stops"
        for n in ("min_position_m", "max_position_m"):
            v = getattr(self, n)
            if v is not None:
                _check(g, n, v, _finite(v), "must be a finite number (m) or None")
        if self.min_position_m is not None and self.max_position_m is not None:
            _check(g, "max_position_m", self.max_position_m, self.max_position_m > self.min_position_m,
                   f"must exceed min_position_m ({self.min_position_m})")
        _positive(g, self, "stiffness_n_m")
        _non_negative(g, self, "damping_n_s_m")

    @property
    def fitted(self) -> bool:
        return self.min_position_m is not None or self.max_position_m is not None


@dataclass(frozen=True)
class BrakeParams:
    """Holding brake on the screw shaft: torque capacity ramps linearly over engage/release time.

    `holding_torque_nm` 0: no brake fitted (a brake command is then refused).
    `engage_on_watchdog`: the node engages it when its command watchdog times out.
    """

    holding_torque_nm: float = 0.0
    engage_time_s: float = 0.02
    release_time_s: float = 0.02
    engage_on_watchdog: bool = False

    def __post_init__(self) -> None:
        g = "brake"
        _non_negative(g, self, "holding_torque_nm", "engage_time_s", "release_time_s")
        _check(g, "engage_on_watchdog", self.engage_on_watchdog, isinstance(self.engage_on_watchdog, bool),
               "must be true or false")

    @property
    def fitted(self) -> bool:
        return self.holding_torque_nm > 0.0


@dataclass(frozen=True)
class Fault:
    """One injected fault: `kind` active over [start_s, start_s + duration_s) (inf: for good).

    `value` by kind: friction_surge / lubrication_loss — friction factor (> 0, e.g. 3);
    jam — stiction torque on the screw, N·m; sensor_bias — offset in the sensor's unit;
    sensor_noise — extra 1σ in the sensor's unit; sensor_dropout — probability in [0, 1);
    sensor_stuck — unused (the reading freezes at its value when the fault starts);
    torque_limit_drop — factor in [0, 1) on the torque limit; drive_fault — unused (torque off);
    backlash — growth rate of the axial clearance, m/s > 0 (model `elastic`, no preload: the
    clearance is elastic.axial_clearance_m + value × (t − start_s) while active; once cleared it
    closes back to the parameter's value as far as the flanks are apart, see actuator/faults.py).
    `sensor` names the sensor for the sensor faults; `roller` an index for the friction faults
    (None: all rollers).
    """

    kind: str
    start_s: float = 0.0
    duration_s: float = math.inf
    value: float = 0.0
    sensor: str | None = None
    roller: int | None = None

    def __post_init__(self) -> None:
        g = "fault"
        _check(g, "kind", self.kind, self.kind in FAULT_KINDS, f"must be one of {', '.join(FAULT_KINDS)}")
        _check(g, "start_s", self.start_s, _finite(self.start_s) and self.start_s >= 0, "must be a finite number >= 0 (s)")
        d = self.duration_s
        _check(g, "duration_s", d, isinstance(d, (int, float)) and not isinstance(d, bool) and d > 0 and not math.isnan(d),
               "must be a number > 0 (s; inf: until cleared)")
        _check(g, "value", self.value, _finite(self.value), "must be a finite number")
        k, v = self.kind, self.value
        if k in ("friction_surge", "lubrication_loss"):
            _check(g, "value", v, v > 0, f"{k}: a friction factor > 0 (e.g. 3)")
        elif k == "jam":
            _check(g, "value", v, v > 0, "jam: a stiction torque > 0 (N·m)")
        elif k == "torque_limit_drop":
            _check(g, "value", v, 0 <= v < 1, "torque_limit_drop: a factor in [0, 1) on the torque limit")
        elif k == "sensor_dropout":
            _check(g, "value", v, 0 <= v < 1, "sensor_dropout: a probability in [0, 1)")
        elif k == "backlash":
            _check(g, "value", v, v > 0, "backlash: a clearance growth rate > 0 (m/s)")
        if k.startswith("sensor_"):
            _check(g, "sensor", self.sensor, self.sensor in SENSORS, f"{k}: must name one of {', '.join(SENSORS)}")
        elif self.sensor is not None:
            raise ParamError(f"fault.sensor = {self.sensor!r}: only sensor faults name a sensor")
        if self.roller is not None:
            _check(g, "roller", self.roller, k in ("friction_surge", "jam", "lubrication_loss"),
                   "only friction faults (friction_surge, jam, lubrication_loss) name a roller")
            _check(g, "roller", self.roller, isinstance(self.roller, int) and not isinstance(self.roller, bool)
                   and self.roller >= 0, "must be a whole number >= 0 (roller index) or None (all rollers)")

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.end_s

    def describe(self) -> str:
        what = self.kind + (f"({self.sensor})" if self.sensor else "") + (f"[roller {self.roller}]" if self.roller is not None else "")
        return f"{what} value {self.value:g} from {self.start_s:g} s for {self.duration_s:g} s"


@dataclass(frozen=True)
class ActuatorParams:
    """Everything around the screw; the default is the ideal actuator (bit for bit the bare model)."""

    motor: MotorParams | None = None  # None: ideal torque source, the command is the screw torque
    drive: DriveParams = field(default_factory=DriveParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    stops: StopParams = field(default_factory=StopParams)
    brake: BrakeParams = field(default_factory=BrakeParams)
    faults: tuple[Fault, ...] = ()

    def __post_init__(self) -> None:
        for name, cls in (("drive", DriveParams), ("sensors", SensorParams), ("stops", StopParams),
                          ("brake", BrakeParams)):
            v = getattr(self, name)
            if not isinstance(v, cls):
                raise ParamError(f"{name}: expected a {cls.__name__}, got {type(v).__name__}")
        if self.motor is not None and not isinstance(self.motor, MotorParams):
            raise ParamError(f"motor: expected a MotorParams or None, got {type(self.motor).__name__}")
        object.__setattr__(self, "faults", tuple(self.faults))
        for f in self.faults:
            if not isinstance(f, Fault):
                raise ParamError(f"faults: expected Fault records, got {type(f).__name__}")


_SUBGROUPS: dict[str, type] = {"motor": MotorParams, "drive": DriveParams, "sensors": SensorParams,
                               "stops": StopParams, "brake": BrakeParams}
_INT_FIELDS = {("sensors", "encoder_counts_per_rev"), ("sensors", "latency_steps"), ("sensors", "seed")}
_STR_FIELDS = {("drive", "mode")}
_BOOL_FIELDS = {("brake", "engage_on_watchdog"), ("drive", "position_feedforward")}


def _coerce(group: str, key: str, value: Any) -> Any:
    """YAML/ROS values to the field's type; anything else refused by name (ParamError)."""
    if value is None:
        return None
    if (group, key) in _STR_FIELDS:
        _check(group, key, value, isinstance(value, str), "must be a string")
        return value
    if (group, key) in _BOOL_FIELDS:
        _check(group, key, value, isinstance(value, bool), "must be true or false")
        return value
    if isinstance(value, str):  # YAML 1.1 reads "1e-6" (no dot) as a string
        try:
            value = float(value)
        except ValueError:
            raise ParamError(f"{group}.{key} = {value!r}: must be a number") from None
    _check(group, key, value, isinstance(value, (int, float)) and not isinstance(value, bool), "must be a number")
    if (group, key) in _INT_FIELDS:
        _check(group, key, value, math.isfinite(value) and float(value) == int(value), "must be a whole number")
        return int(value)
    return float(value)


def actuator_params_from_dict(data: Any, *, base: ActuatorParams | None = None) -> ActuatorParams:
    """Build from a nested dict {motor: {...} | None, drive: {...}, ..., faults: [{...}]}; unknown keys refused.

    Groups missing from `data` come from `base` (default: the ideal actuator); `motor: {}`
    fits the default motor, `motor: null` removes it.
    """
    base = base if base is not None else ActuatorParams()
    if not isinstance(data, dict):
        raise ParamError(f"actuator: expected a mapping of groups ({', '.join(_SUBGROUPS)}, faults), "
                         f"got {type(data).__name__}")
    unknown = set(data) - set(_SUBGROUPS) - {"faults"}
    if unknown:
        raise ParamError(f"unknown actuator group {sorted(map(str, unknown))[0]!r}; "
                         f"allowed: {', '.join(_SUBGROUPS)}, faults")
    groups: dict[str, Any] = {}
    for gname, gcls in _SUBGROUPS.items():
        cur = getattr(base, gname)
        if gname not in data:
            groups[gname] = cur
            continue
        section = data[gname]
        if section is None:
            _check("actuator", gname, section, gname == "motor", "only the motor may be removed (null)")
            groups[gname] = None
            continue
        _check("actuator", gname, section, isinstance(section, dict), "must be a mapping")
        allowed = {f.name for f in fields(gcls)}
        bad = set(section) - allowed
        if bad:
            raise ParamError(f"unknown parameter {gname}.{sorted(map(str, bad))[0]}; "
                             f"allowed in {gname}: {', '.join(sorted(allowed))}")
        values = asdict(cur) if cur is not None else {}
        values.update({k: _coerce(gname, k, v) for k, v in section.items()})
        groups[gname] = gcls(**values)
    faults = base.faults
    if "faults" in data:
        items = data["faults"] or []
        _check("actuator", "faults", items, isinstance(items, (list, tuple)), "must be a list of faults")
        faults = tuple(fault_from_dict(f) for f in items)
    return ActuatorParams(faults=faults, **groups)


def actuator_params_to_dict(a: ActuatorParams) -> dict[str, Any]:
    """Plain nested dict; round-trips through `actuator_params_from_dict`."""
    out: dict[str, Any] = {g: (asdict(getattr(a, g)) if getattr(a, g) is not None else None) for g in _SUBGROUPS}
    out["faults"] = [asdict(f) for f in a.faults]
    return out


_FAULT_KEYS = ("kind", "start_s", "duration_s", "value", "sensor", "roller")


def fault_from_dict(data: Any) -> Fault:
    """A Fault from {kind, start_s, duration_s, value, sensor, roller}; unknown keys refused."""
    if isinstance(data, str):
        return parse_fault(data)
    _check("fault", "spec", data, isinstance(data, dict), "must be a mapping or a 'kind=…,start_s=…' string")
    bad = set(data) - set(_FAULT_KEYS)
    if bad:
        raise ParamError(f"unknown fault field {sorted(map(str, bad))[0]!r}; allowed: {', '.join(_FAULT_KEYS)}")
    _check("fault", "kind", data.get("kind"), "kind" in data, f"is required (one of {', '.join(FAULT_KINDS)})")
    vals: dict[str, Any] = {}
    for k, v in data.items():
        if k in ("kind", "sensor"):
            _check("fault", k, v, v is None or isinstance(v, str), "must be a string")
        elif k == "roller":
            _check("fault", k, v, v is None or (isinstance(v, (int, float)) and not isinstance(v, bool)
                                              and math.isfinite(v) and float(v) == int(v)), "must be a whole number")
            v = None if v is None else int(v)
        else:
            _check("fault", k, v, isinstance(v, (int, float)) and not isinstance(v, bool), "must be a number")
            v = float(v)
        vals[k] = v
    return Fault(**vals)


def parse_fault(text: str) -> Fault:
    """A Fault from 'kind=jam,start_s=1.0,duration_s=0.5,value=50' (ROS string parameters and services)."""
    _check("fault", "spec", text, isinstance(text, str) and text.strip() != "", "must be a non-empty string")
    d: dict[str, Any] = {}
    for part in text.split(","):
        key, sep, val = part.partition("=")
        key, val = key.strip(), val.strip()
        if not sep or not key:
            raise ParamError(f"fault spec {text!r}: expected key=value pairs separated by commas, "
                             f"e.g. kind=jam,start_s=1.0,duration_s=0.5,value=50")
        if key in ("kind", "sensor"):
            d[key] = val
        else:
            try:
                d[key] = float(val)
            except ValueError:
                raise ParamError(f"fault.{key} = {val!r}: must be a number") from None
    return fault_from_dict(d)


def parse_faults(text: str) -> tuple[Fault, ...]:
    """Faults from 'spec; spec; …' (each as `parse_fault`); '' gives none."""
    _check("faults", "spec", text, isinstance(text, str), "must be a string of 'kind=…,start_s=…' specs separated by ';'")
    return tuple(parse_fault(part) for part in text.split(";") if part.strip())
