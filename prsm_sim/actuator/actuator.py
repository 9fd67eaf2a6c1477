"""`Actuator`: drive, motor, coupling, screw model, end stops, brake, faults and sensors behind one step.

    act = Actuator(preset("s30"), 1e-3, "ideal", ActuatorParams(motor=MotorParams(), ...))
    state = act.initial_state(0.0)
    state, out = act.step(state, command, load_n)    # command in the active interface's unit

The same step contract as a bare model (`Model.step(state, input, load) → (state, Outputs)`):
the scalar outputs are the screw's true ones, and the actuator's own quantities and what the
sensors measure travel as two labelled internal-layout blocks (`actuator`, `measured`) after
the screw model's blocks, so node, recorder, bag report and Rerun need no per-part code.

Per step (h) the drive's loop runs n_sub = loop_rate × h times (the screw model is built at
h / n_sub), or once every 1 / (loop_rate × h) steps when slower. Per sub-step:
drive law on the encoder feedback → current loop → motor torque → (rigid: the rotor inertia
is part of the screw's; compliant: a torsional spring solved implicitly) → end-stop force and
dry friction (brake, jam) solved on the screw's linear response → screw model step. A sub-step
whose dry friction did work on the shaft (the screw turned round inside it: `brake.works_on_shaft`) or whose
stop gave out energy (the screw's response jumped across the stop's law: `stops.gives_out`), and
the step's last sub-step, should it end with the nut at rest off its stop's law (`stops.off_rest`), are
taken again in halves (models built at h / n_sub / 2**k). The energy ledger (source in = load work +
dissipated + stored) is kept in the state.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass, fields, replace
from typing import Any, cast

import numpy as np

from prsm_sim.actuator import faults as fl
from prsm_sim.actuator.brake import brake_level, held_torque, works_on_shaft
from prsm_sim.actuator.drive import drive_update, loop_schedule, shape_reference, tuned_drive
from prsm_sim.actuator.implicit import coupling_torque, linear_response, probe_inertia
from prsm_sim.actuator.motor import CurrentStep, current_reference, current_step, voltage
from prsm_sim.actuator.params import COMMAND_INTERFACES, ActuatorParams, Fault, check_interface
from prsm_sim.actuator.sensing import SensorSuite
from prsm_sim.actuator.sensors import MEASURED_QUANTITIES, TrueSample
from prsm_sim.actuator.stops import MAX_REST_HALVINGS, Limit, engaged, gives_out, limits_of, off_rest, \
    stop_penetration, stop_stored_j
from prsm_sim.actuator.stops import solve as solve_stop
from prsm_sim.errors import InputError
from prsm_sim.models.registry import build_model, model_class
from prsm_sim.stepping.ledger import efficiency
from prsm_sim.stepping.model import Model, check_step_inputs
from prsm_sim.stepping.packed import PackedOutputs
from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.stepping.records import InternalBlock, InternalLayout, Outputs, State
from prsm_sim.params import Params

ACTUATOR_QUANTITIES = (
    ("command", "m | rad/s | N·m (active interface)"),
    ("mode", "0 effort, 1 velocity, 2 position"),
    ("speed_reference_rad_s", "rad/s"),
    ("torque_reference_nm", "N·m"),
    ("torque_limited", "1"),
    ("motor_current_a", "A"),
    ("motor_torque_nm", "N·m"),
    ("motor_speed_rad_s", "rad/s"),
    ("motor_voltage_v", "V"),
    ("electrical_power_w", "W"),
    ("coupling_torque_nm", "N·m"),
    ("brake_level", "1"),
    ("brake_torque_nm", "N·m"),
    ("jam_torque_nm", "N·m"),
    ("stop_force_n", "N"),
    ("stop_penetration_m", "m"),
    ("stop_absorbed_j", "J"),
    ("thread_end", "1"),  # 1 while the nut presses on a thread end (the last of the threaded length)
    ("energy_in_j", "J"),
    ("load_work_j", "J"),
    ("dissipated_j", "J"),
    ("stored_j", "J"),
    ("faults_active", "1"),
)
_MODE_CODE = {m: float(i) for i, m in enumerate(COMMAND_INTERFACES)}
# the actuator block of one step, built by keyword: a new quantity is one entry in ACTUATOR_QUANTITIES
_ActuatorBlock = cast(Any, namedtuple)("_ActuatorBlock", [n for n, _ in ACTUATOR_QUANTITIES])
_MEASURED_AT = {n: i for i, (n, _) in enumerate(MEASURED_QUANTITIES)}
# the readings that stand for the true joint quantities of the same name in `Actuator.measured`
_JOINT_READINGS = ("screw_angle_rad", "screw_speed_rad_s", "nut_position_m", "nut_velocity_m_s", "nut_force_n")


@dataclass(frozen=True, slots=True, init=False)
class Ledger:
    """Energy accumulators of the actuator (J); the screw's own friction is in `State.dissipated_j`."""

    energy_in_j: float = 0.0  # electrical energy drawn (ideal torque source: its mechanical work)
    copper_j: float = 0.0
    coupling_j: float = 0.0  # dissipated in the coupling's damper
    stiction_j: float = 0.0  # dissipated by the brake and jams
    stop_work_j: float = 0.0  # work the nut did on the end stops
    load_work_j: float = 0.0  # work done against the external load
    backlash_j: float = 0.0  # elastic energy a widening clearance released from a loaded flank (growing backlash)

    def __init__(self, energy_in_j: float = 0.0, copper_j: float = 0.0, coupling_j: float = 0.0,
                 stiction_j: float = 0.0, stop_work_j: float = 0.0, load_work_j: float = 0.0,
                 backlash_j: float = 0.0) -> None:
        # the declared defaults (tests/test_stepping.py holds them together), each field through its slot's
        # setter (`_LEDGER_SET`): a ledger is made every sub-step
        s_in, s_cu, s_coup, s_st, s_stop, s_load, s_back = _LEDGER_SET
        s_in(self, energy_in_j)
        s_cu(self, copper_j)
        s_coup(self, coupling_j)
        s_st(self, stiction_j)
        s_stop(self, stop_work_j)
        s_load(self, load_work_j)
        s_back(self, backlash_j)

    def dissipated_j(self, screw_j: float, stop_stored_j: float) -> float:
        """Dissipated up to here (J): the screw model's friction `screw_j`, copper, coupling damping, brake and
        jams, backlash, and the stops' work less what they hold as ½ k δ² (`stop_stored_j`)."""
        return (screw_j + self.copper_j + self.coupling_j + self.stiction_j + self.stop_work_j - stop_stored_j
                + self.backlash_j)


_LEDGER_SET = tuple(getattr(Ledger, f.name).__set__ for f in fields(Ledger))  # the slots' setters, in field order


@dataclass(frozen=True, slots=True, init=False)
class ActuatorState:
    """The screw model's state plus the drive, motor, brake, sensor and fault memory (pure data).

    Motor angle and speed are in screw coordinates (motor / gear ratio); with a rigid coupling
    they equal the screw's. `faults` holds the faults injected at runtime; `history` the true
    samples the sensors' latency still has to deliver; `measured` the last published reading.
    """

    screw: State
    step: int = 0
    mode: str = "effort"
    motor_angle_rad: float = 0.0
    motor_speed_rad_s: float = 0.0
    current_a: float = 0.0
    integral_nm: float = 0.0
    torque_ref_nm: float = 0.0
    speed_ref_rad_s: float = 0.0
    limited: bool = False
    encoder_rad: float = 0.0  # last screw angle the drive read from the encoder
    brake_engaged: bool = False
    brake_level: float = 0.0
    faults: tuple[Fault, ...] = ()
    history: tuple[TrueSample, ...] = ()
    measured: tuple[float, ...] = ()
    load_cell_filtered_n: float = 0.0
    ledger: Ledger = Ledger()
    coupling_nm: float = 0.0  # the compliant coupling's torque over the last step (its next linearisation point)
    reference_m: float = math.nan  # the drive's shaped position reference (`shape_reference`; NaN: not started)
    reference_m_s: float = 0.0  # its rate, the position loop's feed-forward
    command_prev: float = math.nan  # the position command at the last loop update (its rate: the command's speed)

    def __init__(self, screw: State, step: int = 0, mode: str = "effort", motor_angle_rad: float = 0.0,
                 motor_speed_rad_s: float = 0.0, current_a: float = 0.0, integral_nm: float = 0.0,
                 torque_ref_nm: float = 0.0, speed_ref_rad_s: float = 0.0, limited: bool = False,
                 encoder_rad: float = 0.0, brake_engaged: bool = False, brake_level: float = 0.0,
                 faults: tuple[Fault, ...] = (), history: tuple[TrueSample, ...] = (), measured: tuple[float, ...] = (),
                 load_cell_filtered_n: float = 0.0, ledger: Ledger = Ledger(), coupling_nm: float = 0.0,
                 reference_m: float = math.nan, reference_m_s: float = 0.0, command_prev: float = math.nan) -> None:
        # the fields' defaults as declared above (tests/test_stepping.py holds them together); each
        # field set through its slot's own setter (`_STATE_SET`): a state is made every step
        (s_screw, s_step, s_mode, s_th, s_w, s_i, s_integ, s_tau, s_wref, s_lim, s_enc, s_brake, s_level, s_faults,
         s_hist, s_meas, s_filt, s_led, s_coup, s_ref, s_refv, s_cmd) = _STATE_SET
        s_screw(self, screw)
        s_step(self, step)
        s_mode(self, mode)
        s_th(self, motor_angle_rad)
        s_w(self, motor_speed_rad_s)
        s_i(self, current_a)
        s_integ(self, integral_nm)
        s_tau(self, torque_ref_nm)
        s_wref(self, speed_ref_rad_s)
        s_lim(self, limited)
        s_enc(self, encoder_rad)
        s_brake(self, brake_engaged)
        s_level(self, brake_level)
        s_faults(self, faults)
        s_hist(self, history)
        s_meas(self, measured)
        s_filt(self, load_cell_filtered_n)
        s_led(self, ledger)
        s_coup(self, coupling_nm)
        s_ref(self, reference_m)
        s_refv(self, reference_m_s)
        s_cmd(self, command_prev)

    @property
    def time_s(self) -> float:
        return self.screw.time_s


# the slots' setters of `ActuatorState`, in field order (a frozen record's fields are set past its own __setattr__)
_STATE_SET = tuple(getattr(ActuatorState, f.name).__set__ for f in fields(ActuatorState))


class _Work:
    """The working values of one step, handed from stage to stage (`Actuator._step_impl`): what the
    state carries (motor, drive, brake, ledger, screw) as the sub-steps advance it, and the last
    sub-step's solved torques and outputs the step reports."""

    __slots__ = ("screw", "led", "th_r", "w_r", "i_a", "integ", "tau_ref", "w_ref", "limited", "enc", "level",
                 "ref", "ref_v", "cmd_prev", "tau_c", "volt", "tau_st", "tau_in", "f_stop", "sums", "act", "model",
                 "tlim", "cs", "new", "out", "engaged", "halved", "work_halvings")

    def __init__(self, st: ActuatorState) -> None:
        self.screw, self.led = st.screw, st.ledger
        self.th_r, self.w_r, self.i_a = st.motor_angle_rad, st.motor_speed_rad_s, st.current_a
        self.integ, self.tau_ref, self.w_ref, self.limited = st.integral_nm, st.torque_ref_nm, st.speed_ref_rad_s, \
            st.limited
        self.enc, self.level, self.engaged = st.encoder_rad, st.brake_level, st.brake_engaged
        self.halved = False  # a sub-step was taken in pieces (`Actuator._sub_step`): the outputs are its mean
        # pieces halved for a brake or jam, or a stop, that did work on the shaft: one per level on the path to it
        self.work_halvings = 0
        self.ref, self.ref_v, self.cmd_prev = st.reference_m, st.reference_m_s, st.command_prev
        self.tau_c = st.coupling_nm
        self.volt = self.tau_st = self.tau_in = self.f_stop = 0.0
        self.sums = [0.0, 0.0, 0.0, 0.0]  # screw torque, power in, out, dissipated (n_sub > 1 or halved)
        self.act: fl.Active = fl.NONE
        self.tlim = math.inf

    # set by the stages before they are read: the screw model the faults call for (`_begin`), the
    # current loop's sub-step (`_motor`), the sub-step's new screw state and outputs (`_advance`)
    model: Model
    cs: CurrentStep
    new: State
    out: PackedOutputs  # the sub-step's record, kept packed (`_finish` builds the step's `Outputs`)


def _apply_clearance(w: _Work, faults: tuple[Fault, ...], t_s: float, lead_per_rad_m: float,
                     clearance_m: float) -> None:
    """The clearance the backlash faults add at `t_s` applied to the screw's state at the step's start (in `w`);
    `lead_per_rad_m`: L/2π; `clearance_m`: the parameter's axial clearance."""
    model, screw = w.model, w.screw
    extra = fl.extra_clearance_m(faults, t_s)
    if extra < screw.extra_clearance_m:
        # a cleared fault: the gap closes back only as far as the flanks are apart (2|δ| − c), never
        # into a loaded flank (that would be a force step of k Δc/2 out of nothing); it reaches the
        # parameter's clearance at the next pass through the gap
        delta = lead_per_rad_m * screw.screw_angle_rad - screw.nut_axial_m
        extra = max(extra, min(screw.extra_clearance_m, 2.0 * abs(delta) - clearance_m))
    if extra != screw.extra_clearance_m:
        # the clearance steps at the step's start: a wider gap at the same deflection unloads the
        # flank in contact, releasing its elastic energy (booked as dissipated: ≥ 0, since the gap
        # never closes onto a flank), so the ledger and the model's guard stay closed
        widened = replace(screw, extra_clearance_m=extra)  # type: ignore[call-arg]  # a part field of `State`
        w.led = replace(w.led, backlash_j=w.led.backlash_j + float(model.total_stored_energy_j(screw)
                                                                   - model.total_stored_energy_j(widened)))
        w.screw = widened


class Actuator(Model):
    """The actuator around a screw model (any of ideal, jones2016, fu2018, elastic), one step contract."""

    name = "actuator"
    packed = False  # its state is its own (`ActuatorState`): stepped by `_step_impl`
    command_name = "command"

    def __init__(self, params: Params, dt_s: float, model: str = "jones2016",
                 actuator: ActuatorParams | None = None, kernel: str = "compiled") -> None:
        super().__init__(params, dt_s)
        self.model_name = model
        self.kernel = kernel  # of the screw models it builds (`build_model`)
        # the nut on its own axial chain: loads, stops and sensors act at its own coordinate, backlash applies
        self.axial_chain = model_class(model).has_axial_chain
        self.actuator = a = actuator if actuator is not None else ActuatorParams()
        if not isinstance(a, ActuatorParams):
            raise InputError(f"actuator: expected ActuatorParams, got {type(a).__name__}")
        m = a.motor
        self.ratio = m.gear_ratio if m is not None else 1.0
        for f in a.faults:  # refused before anything is built or stepped
            fl.check_fault(f, params, model, m is not None)
        self.rigid = m is None or m.coupling_stiffness_nm_rad is None
        # a compliant coupling's stiffness (N·m/rad) and damping (N·m·s/rad); 0 when rigid
        self.k_coupling = 0.0 if m is None or m.coupling_stiffness_nm_rad is None else m.coupling_stiffness_nm_rad
        self.c_coupling = 0.0 if m is None else m.coupling_damping_nm_s_rad
        if m is not None and self.rigid:  # the rotor turns with the screw: its inertia, reflected, joins the screw's
            mass = replace(params.mass, screw_inertia_kgm2=params.resolved_mass.screw_inertia_kgm2
                           + m.rotor_inertia_kgm2 * m.gear_ratio**2)
            self.screw_params = replace(params, mass=mass)
        else:
            self.screw_params = params
        self.motor_inertia = 0.0 if m is None else m.rotor_inertia_kgm2 * m.gear_ratio**2  # screw side
        self.n_sub, self.hold_steps = loop_schedule(a.drive.loop_rate_hz, self.dt_s)
        self.h_sub = self.dt_s / self.n_sub
        self._h_loop = self.h_sub * self.hold_steps  # the drive loop's period
        self._holding_nm = a.brake.holding_torque_nm
        # end stops and thread ends, the innermost on each side (stops.py)
        self.limits = limits_of(a.stops, params.geometry.travel_m, params.geometry.nut_length_m) \
            if a.stops.fitted or params.geometry.thread_ends else ()
        self._models: dict[tuple[float, float, int], Model] = {}
        base = self._model(fl.NONE)
        self.p = self.geo.lead_per_rad_m
        self.sensing = SensorSuite(a.sensors, self.ratio, self.rigid, self.p, self.dt_s)
        self.J = probe_inertia(base, self.h_sub)
        # the drive's gains tuned on the inertia it drives (rigid: J; compliant: J + rotor), its loops' radius by mode
        self.J_drive = self.J + (0.0 if self.rigid else self.motor_inertia)  # the inertia the drive moves
        self.drive, self.drive_loop_radius = tuned_drive(a.drive, self.J_drive, self._h_loop, self.dt_s, a.sensors)
        self.M = mass_matrix(self.screw_params)
        self._kss, self._ksc, self._kcc = float(self.M[0, 0]), float(self.M[0, 1]), float(self.M[1, 1])
        self.block_at = base.layout.size  # where the actuator's block starts in the internal vector
        self.layout = InternalLayout(blocks=base.layout.blocks + (
            InternalBlock("actuator", ("quantity",), (len(ACTUATOR_QUANTITIES),), ACTUATOR_QUANTITIES),
            InternalBlock("measured", ("quantity",), (len(MEASURED_QUANTITIES),), MEASURED_QUANTITIES),
        ))

    # -- construction helpers ------------------------------------------------------------
    def _model(self, act: fl.Active, halvings: int = 0) -> Model:
        """The screw model the active faults call for, built at the sub-step h_sub / 2**halvings."""
        key = (act.friction_factor, act.lubrication_factor, halvings)
        mod = self._models.get(key)
        if mod is None:
            p = self.screw_params if key[:2] == (1.0, 1.0) else fl.scaled_params(self.screw_params, *key[:2])
            mod = self._models[key] = build_model(p, self.model_name, math.ldexp(self.h_sub, -halvings), self.kernel)
        return mod

    def _accel_limit(self, torque_limit_nm: float) -> float:
        """Screw acceleration (rad/s²) the position reference may ask for: half the torque limit on the inertia
        the drive moves (the other half for the load, friction and the error), unlimited without a motor."""
        return 0.5 * torque_limit_nm / self.J_drive

    # -- state ---------------------------------------------------------------------------
    # the actuator's state is a record of its own (`ActuatorState`, never packed): its methods take and give
    # that, not the screw model's `State`
    def initial_state(self, nut_position_m: float = 0.0,  # type: ignore[override]
                      load_n: float = 0.0) -> ActuatorState:
        """At rest with the nut at `nut_position_m`, in equilibrium under the nut load `load_n`: the screw
        model pre-deflected at it (`Model.initial_state`), the drive train carrying the frictionless
        holding torque (L/2π) F (the torque reference, the motor current and a compliant coupling's
        twist, as far as the motor's peak torque allows), the load cell reading it.

        The drive train is loaded in every mode, so the mode decides only who keeps it there: in
        velocity and position mode the drive's speed integrator starts at the holding torque (and
        `set_mode` carries it into either of them, so the interface chosen after this start holds it
        too); in effort mode the command is the torque, and the start stays in equilibrium while it
        is the holding torque (any other command moves the current towards it at the current loop's
        bandwidth)."""
        screw = self._model(fl.NONE).initial_state(nut_position_m, load_n)
        th = screw.screw_angle_rad
        mode = self.actuator.drive.mode
        m = self.actuator.motor
        hold = self.p * load_n
        if m is not None:  # as far as the drive can
            lim = self.ratio * m.peak_torque_nm
            hold = max(-lim, min(lim, hold))
        th_r = th if self.rigid or hold == 0.0 else th + hold / self.k_coupling
        i_a = 0.0 if m is None else hold / (self.ratio * m.torque_constant_nm_a)
        st = ActuatorState(screw=screw, mode=mode, motor_angle_rad=th_r, current_a=i_a,
                           integral_nm=hold if mode != "effort" else 0.0, torque_ref_nm=hold,
                           coupling_nm=0.0 if self.rigid else hold)
        sample = self._sample(th_r, 0.0, screw, float(load_n))
        enc = self.sensing.encoder_screw_angle(th_r * self.ratio, th)
        meas, filt = self.sensing.measure(0, (), 0.0, sample, sample, fl.NONE, first=True)
        return replace(st, encoder_rad=enc, history=(sample,), measured=meas, load_cell_filtered_n=filt)

    def all_faults(self, state: ActuatorState) -> tuple[Fault, ...]:
        return self.actuator.faults + state.faults

    def set_mode(self, state: ActuatorState, mode: str) -> ActuatorState:
        """Switch the command interface; the speed integrator restarts from the present torque (bumpless)."""
        check_interface(mode)
        return replace(state, mode=mode, integral_nm=state.torque_ref_nm if mode != "effort" else 0.0,
                       reference_m=math.nan, reference_m_s=0.0, command_prev=math.nan)

    def command_brake(self, state: ActuatorState, engage: bool) -> ActuatorState:
        """Engage or release the holding brake; refused (InputError, nothing changed) where unsupported."""
        if not isinstance(engage, bool):
            raise InputError(f"brake command = {engage!r}: must be true (engage) or false (release)")
        if not self.actuator.brake.fitted:
            raise InputError("brake command refused: no brake fitted (brake.holding_torque_nm = 0)")
        if not engage and fl.active(self.all_faults(state), state.time_s).drive_off:
            raise InputError("brake release refused: a drive fault is active (torque off), the load would run away; "
                             "clear the fault first")
        return replace(state, brake_engaged=engage)

    def inject(self, state: ActuatorState, fault: Fault) -> ActuatorState:
        """Add a fault at runtime (absolute simulation time); refused with one line where it cannot apply."""
        fl.check_fault(fault, self.params, self.model_name, self.actuator.motor is not None)
        return replace(state, faults=state.faults + (fault,))

    def clear_faults(self, state: ActuatorState) -> ActuatorState:
        """End every runtime fault now (the ones not yet started are dropped)."""
        t = state.time_s
        kept = tuple(replace(f, duration_s=t - f.start_s) for f in state.faults if f.start_s < t and f.end_s > t)
        kept += tuple(f for f in state.faults if f.end_s <= t)
        return replace(state, faults=kept)

    def events(self, before: ActuatorState, after: ActuatorState) -> list[fl.FaultEvent]:
        """Faults the step from `before` to `after` started or stopped using (relative to the step before it).

        A step starting at t applies the faults active at t, so a fault injected now with
        start_s = now is reported by the very next step.
        """
        t0, faults = before.time_s, self.all_faults(after)
        return fl.fault_events(faults, t0 - self.dt_s, t0) if faults else []

    # -- the step ------------------------------------------------------------------------
    def step(self, state: ActuatorState, command: float,  # type: ignore[override]
             load_n: float) -> tuple[ActuatorState, Outputs]:
        """One step with `command` (active interface: N·m, screw rad/s or nut m) and the nut load."""
        command, load_n = check_step_inputs(command, load_n, self.command_name)
        if not isinstance(state, ActuatorState):
            raise InputError(f"state: expected an ActuatorState (Actuator.initial_state), got {type(state).__name__}")
        return self._step_impl(state, command, load_n)

    def _step_impl(self, st: ActuatorState, command: float,  # type: ignore[override]
                   load_n: float) -> tuple[ActuatorState, Outputs]:
        """The step in its stages: faults and clearance (`_begin`), then per sub-step the drive loop
        (`_drive_loop`, when due) and the rest (`_sub_step`); then the sub-steps' averages, the sensors and
        the actuator block (`_finish`)."""
        w = self._begin(st)
        loop_due = st.step % self.hold_steps == 0
        for j in range(self.n_sub):
            if loop_due:
                self._drive_loop(w, st, command, st.step * self.n_sub + j)
            self._sub_step(w, load_n, 0, j == self.n_sub - 1)
        return self._finish(st, w, command)

    def _begin(self, st: ActuatorState) -> _Work:
        """The step's working values: the active faults, the screw model they call for, and a backlash
        fault's clearance applied to the screw's state at the step's start."""
        w = _Work(st)
        faults = self.all_faults(st)
        w.act = act = fl.active(faults, st.time_s)
        w.model = self._model(act)
        m = self.actuator.motor
        w.tlim = math.inf if m is None else self.ratio * m.peak_torque_nm * act.torque_factor
        if self.axial_chain:  # a backlash fault's clearance: only a nut on its own chain has one
            _apply_clearance(w, faults, st.time_s, self.p, self.params.elastic.axial_clearance_m)
        return w

    def _drive_loop(self, w: _Work, st: ActuatorState, command: float, key: int) -> None:
        """One update of the drive's loops on the encoder feedback (and a linear encoder's, if fitted):
        the torque reference, the speed integrator and, in position mode, the shaped reference."""
        act, p, screw = w.act, self.p, w.screw
        enc_new = self.sensing.read_encoder(w.th_r * self.ratio, screw.screw_angle_rad, act, key, w.enc)
        h_loop = self._h_loop
        if self.actuator.sensors.encoder_counts_per_rev == 0 and not (
                act.sensor and any(x[0] == "motor_encoder" for x in act.sensor)):
            w_meas = w.w_r if not self.rigid else screw.screw_speed_rad_s
        else:
            w_meas = (enc_new - w.enc) / h_loop
        w.enc = enc_new
        x_meas = self.sensing.read_linear(self._nut_x(screw), w.enc, act, key)
        if act.drive_off:
            w.tau_ref, w.integ, w.limited, w.w_ref = 0.0, 0.0, False, 0.0
            w.ref, w.ref_v, w.cmd_prev = math.nan, 0.0, math.nan  # restarts from the command when the drive is back
            return
        ff = ff_nm = 0.0
        target = command
        if st.mode == "position" and self.drive.position_feedforward:
            if not math.isfinite(w.ref):
                # the reference starts at the command: it shapes the command's changes (the loop
                # alone takes out an initial error, as without feed-forward)
                w.ref, w.ref_v = command, 0.0
            # the loops compare the nut now with the reference now; the torque that takes the
            # reference to its next point over this update is fed forward
            target, v0 = w.ref, w.ref_v
            rate = (command - w.cmd_prev) / h_loop if math.isfinite(w.cmd_prev) else 0.0
            w.cmd_prev = command
            w.ref, w.ref_v = shape_reference(w.ref, w.ref_v, command, rate, self.drive.speed_limit_rad_s * p,
                                             self._accel_limit(w.tlim) * p, h_loop)
            ff, ff_nm = v0 / p, self.J_drive * (w.ref_v - v0) / (p * h_loop)
        w.tau_ref, w.integ, w.limited, w.w_ref = drive_update(self.drive, st.mode, target, w.integ, w_meas, x_meas, p,
                                                              w.tlim, h_loop, ff, ff_nm)

    def _sub_step(self, w: _Work, load_n: float, halvings: int, last: bool) -> None:
        """A sub-step of h_sub / 2**halvings: motor (`_motor`), screw (`_advance`), ledger (`_book`), brake ramp.
        A piece whose brake or jam did work on the shaft (`brake.works_on_shaft`) or whose stop gave out energy
        (`stops.gives_out`), and the step's `last` piece ending at rest off its stop's law (`stops.off_rest`), are
        taken as two halves, each judged likewise (`stops` module doc; one piece per level); its time stays whole."""
        h = math.ldexp(self.h_sub, -halvings)
        tau_d = self._motor(w, h)
        lim = self._advance(w, load_n, tau_d, h, w.model if halvings == 0 else self._model(w.act, halvings))
        gave = w.work_halvings < MAX_REST_HALVINGS and (
            works_on_shaft(w.tau_st, w.new.screw_angle_rad - w.screw.screw_angle_rad)
            or lim is not None and gives_out(lim, w.f_stop, self._nut_x(w.screw), self._nut_x(w.new)))
        if halvings < MAX_REST_HALVINGS and (
                gave or last and lim is not None and off_rest(lim, w.f_stop, self._nut_x(w.new), self._nut_v(w.new))):
            t_end, w.halved = w.screw.time_s + h, True
            w.work_halvings += gave
            self._sub_step(w, load_n, halvings + 1, False)
            self._sub_step(w, load_n, halvings + 1, last)
            if w.screw.time_s != t_end:  # the halves' sum rounded
                w.screw, w.out = replace(w.screw, time_s=t_end), PackedOutputs((t_end,) + w.out[1:])
            return
        self._book(w, load_n, tau_d, h)
        w.level = brake_level(self.actuator.brake, w.level, w.engaged, h)

    def _motor(self, w: _Work, h: float) -> float:
        """The current loop over a sub-step: the motor's torque on the screw side, N·m (the torque
        reference itself without a motor). Keeps the current step and the winding voltage in `w`."""
        m = self.actuator.motor
        if m is None:
            return w.tau_ref
        N = self.ratio
        i_ref = 0.0 if w.act.drive_off else current_reference(m, w.tau_ref, w.w_r * N)
        w.cs = cs = current_step(m, w.i_a, i_ref, h)
        w.volt = voltage(m, cs, w.i_a, w.w_r * N, h)
        return N * m.torque_constant_nm_a * cs.mean_current_a

    def _advance(self, w: _Work, load_n: float, tau_d: float, h: float, model: Model) -> Limit | None:
        """The screw (`model`, built at the sub-step h) over it under the drive's torque `tau_d`, with dry
        friction (brake, jam), a compliant coupling and an end stop's force solved implicitly on the screw's local
        linear response ω1(τ, F) = ω_a + s (τ − τ_a) − p s (F − F_a), s from two model steps at this state (exact
        for the linear models; fu2018's effective inertia moves with its friction regime). Leaves the new screw
        state, its outputs and the solved torques and force in `w`; returns the limit pressed into (None: none)."""
        screw, p, act = w.screw, self.p, w.act
        if self.rigid:
            tau_drive_screw = tau_d
        else:
            k, c = self.k_coupling, self.c_coupling
            phi0 = w.th_r - screw.screw_angle_rad
            # linearise where the last step ended: the explicit spring torque k φ0 would swing with
            # the coupling's ringing and evaluate a set-valued friction on the wrong side
            tau_drive_screw = w.tau_c
        cap = w.level * self._holding_nm + act.jam_nm
        implicit = not self.rigid or cap > 0.0
        x = model.pack_state(screw)  # every trial starts here: packed once, its record kept packed (`_finish`)
        if implicit:
            w_a, s_w, th_a, s_th = linear_response(model, x, tau_drive_screw, load_n, h, self.J)
        else:
            s_th = 0.5 * h * h / self.J
        th_r, w_r = w.th_r, w.w_r
        step, unpack, rigid = model.step_from, model.unpack_state, self.rigid

        def advance(f_stop: float) -> tuple[State, PackedOutputs, float, float, float]:
            """The sub-step with the stop force f_stop (along +x_nut) on the nut: (state, its packed record,
            stiction torque, coupling torque, screw torque)."""
            load_in = load_n - f_stop if f_stop != 0.0 else load_n
            th_pred = th_a + p * s_th * f_stop if implicit else 0.0

            def trial(t_st: float) -> tuple[State, PackedOutputs, float, float, float]:
                """The sub-step with the dry friction torque t_st held over it."""
                if rigid:
                    tau_in = tau_drive_screw + t_st if t_st != 0.0 else tau_drive_screw
                    rec = step(x, tau_in, load_in)
                    return unpack(rec), rec, t_st, tau_d, tau_in
                th_sfree = th_pred + s_th * t_st - s_th * tau_drive_screw  # its end angle with no coupling torque
                t_c, nw, o = coupling_torque(model, x, t_st, load_in, th_r + h * w_r, tau_d, phi0, k, c,
                                             th_sfree, s_th, h, self.motor_inertia)
                return nw, o, t_st, t_c, t_c + t_st
            return held_torque(cap, w_a + p * s_w * f_stop, s_w, h, trial) if implicit else trial(0.0)

        res = advance(0.0)
        f_stop = 0.0
        lim = None
        if self.limits:
            # the stops act where the nut is: its own coordinate (across the chain in `elastic`)
            lim = engaged(self.limits, self._nut_x(res[0]))
            if lim is not None:
                with model.in_contact(screw.screw_speed_rad_s * res[0].screw_speed_rad_s < 0.0):
                    f_stop, res = solve_stop(lim, h, self._nut_x(screw), res, advance, lambda r: self._nut_x(r[0]),
                                             p * p * s_th, self._nut_v(screw))
        w.new, w.out, w.tau_st, w.tau_c, w.tau_in = res
        w.f_stop = f_stop
        return lim

    def _book(self, w: _Work, load_n: float, tau_d: float, h: float) -> None:
        """The motor side over the sub-step h (with the screw, or through the compliant coupling's spring) and
        the energy ledger (source in = load work + dissipated + stored); the sub-step's end becomes the
        next one's start."""
        m, screw, new, led = self.actuator.motor, w.screw, w.new, w.led
        dth = new.screw_angle_rad - screw.screw_angle_rad
        # where load and stop force act: the nut (its own coordinate in `elastic`)
        dx_nut = new.nut_axial_m - screw.nut_axial_m if self.axial_chain else self.p * dth
        th_r, w_r, tau_c = w.th_r, w.w_r, w.tau_c
        if self.rigid:
            th_r1, w_r1 = new.screw_angle_rad, new.screw_speed_rad_s
            dth_r = dth
        else:
            k = self.k_coupling
            w_r1 = w_r + h * (tau_d - tau_c) / self.motor_inertia
            th_r1 = th_r + 0.5 * h * (w_r + w_r1)
            dth_r = th_r1 - th_r
            phi0 = th_r - screw.screw_angle_rad
            v0 = 0.5 * k * phi0 * phi0
            phi1 = th_r1 - new.screw_angle_rad
            led = replace(led, coupling_j=led.coupling_j + tau_c * (dth_r - dth) - (0.5 * k * phi1 * phi1 - v0))
        if m is None:
            e_in = tau_d * dth
            copper = 0.0
        else:
            cs = w.cs
            copper = cs.copper_j
            e_in = cs.copper_j + cs.magnetic_j + tau_d * dth_r
            w.i_a = cs.current_a
        w.led = Ledger(energy_in_j=led.energy_in_j + e_in, copper_j=led.copper_j + copper, coupling_j=led.coupling_j,
                       stiction_j=led.stiction_j - w.tau_st * dth, stop_work_j=led.stop_work_j - w.f_stop * dx_nut,
                       load_work_j=led.load_work_j + load_n * dx_nut, backlash_j=led.backlash_j)
        w.th_r, w.w_r = th_r1, w_r1
        if self.n_sub > 1 or w.halved:  # weighted by the share of h_sub (a halved sub-step's pieces)
            out, sums, wt = w.out, w.sums, h / self.h_sub
            for i, q in enumerate((w.tau_in, out.power_in_w, out.power_out_w, out.power_dissipated_w)):
                sums[i] += wt * q
        w.screw = new

    def _finish(self, st: ActuatorState, w: _Work, command: float) -> tuple[ActuatorState, Outputs]:
        """The next state, and the outputs completed with the actuator block and what the sensors measured
        (the true sample now, delivered `latency_steps` later)."""
        a, m, screw, led, rec = self.actuator, self.actuator.motor, w.screw, w.led, w.out
        sample = self._sample(w.th_r, w.w_r, screw, rec.nut_force_n)
        lat = a.sensors.latency_steps
        history = (st.history + (sample,))[-(lat + 1):] if lat else (sample,)
        before = st.history[0] if st.history else history[0]
        meas, filt = self.sensing.measure(st.step + 1, st.measured, st.load_cell_filtered_n, history[0], before, w.act)
        nxt = ActuatorState(screw=screw, step=st.step + 1, mode=st.mode, motor_angle_rad=w.th_r,
                            motor_speed_rad_s=w.w_r, current_a=w.i_a, integral_nm=w.integ, torque_ref_nm=w.tau_ref,
                            speed_ref_rad_s=w.w_ref, limited=w.limited, encoder_rad=w.enc,
                            brake_engaged=st.brake_engaged, brake_level=w.level, faults=st.faults, history=history,
                            measured=meas, load_cell_filtered_n=filt, ledger=led,
                            coupling_nm=0.0 if self.rigid else w.tau_c, reference_m=w.ref, reference_m_s=w.ref_v,
                            command_prev=w.cmd_prev)
        x = self._nut_x(screw)
        stop_e = stop_stored_j(self.limits, x)
        depth, at_end = stop_penetration(self.limits, x)
        cap_b = w.level * self._holding_nm
        cap_all = cap_b + w.act.jam_nm
        brake_t = w.tau_st * cap_b / cap_all if cap_all > 0 else 0.0
        block = _ActuatorBlock(
            command=command, mode=_MODE_CODE[st.mode], speed_reference_rad_s=w.w_ref, torque_reference_nm=w.tau_ref,
            torque_limited=float(w.limited), motor_current_a=w.i_a,
            motor_torque_nm=0.0 if m is None else m.torque_constant_nm_a * w.i_a, motor_speed_rad_s=w.w_r * self.ratio,
            motor_voltage_v=w.volt, electrical_power_w=(led.energy_in_j - st.ledger.energy_in_j) / self.dt_s,
            coupling_torque_nm=w.tau_c, brake_level=w.level, brake_torque_nm=brake_t,
            jam_torque_nm=w.tau_st - brake_t, stop_force_n=w.f_stop, stop_penetration_m=depth,
            stop_absorbed_j=led.stop_work_j - stop_e, thread_end=float(at_end), energy_in_j=led.energy_in_j,
            load_work_j=led.load_work_j,
            dissipated_j=led.dissipated_j(screw.dissipated_j, stop_e),
            stored_j=self.stored_energy(nxt, stop_e),
            faults_active=float(sum(f.active(st.time_s) for f in self.all_faults(st))) if w.act is not fl.NONE else 0.0)
        # the last sub-step's record (kept packed through the solves) completed by the actuator's blocks; over
        # several sub-steps the held torque and the powers are their means
        internal = np.empty(self.layout.size)
        k = self.block_at
        internal[:k] = rec.internal
        internal[k:] = block + meas
        out = rec.to_outputs(internal)
        if self.n_sub > 1 or w.halved:
            n, sums = self.n_sub, w.sums
            pin, pout, pd = sums[1] / n, sums[2] / n, sums[3] / n
            out = replace(out, screw_torque_nm=sums[0] / n, power_in_w=pin, power_out_w=pout, power_dissipated_w=pd,
                          efficiency=efficiency(pin, pout, pd))
        return nxt, out

    # -- what the sensors say -------------------------------------------------------------
    def measured(self, out: Outputs) -> Outputs:
        """`out` with the joint quantities replaced by what the sensors measured (for `joint_states`).

        Screw angle and speed from the motor encoder, nut position and velocity from the
        linear encoder (or the motor encoder), nut force from the load cell; every other field
        is the true one. With ideal sensors this is `out`'s values exactly.
        """
        m = self.layout.view(out.internal, "measured")
        readings: dict[str, Any] = {n: float(m[_MEASURED_AT[n]]) for n in _JOINT_READINGS}
        return replace(out, **readings)

    # -- energy --------------------------------------------------------------------------
    def _nut_x(self, s: State) -> float:
        """Nut position (m): its own coordinate in `elastic`, (L/2π) θ_S in the rigid models."""
        return s.nut_axial_m if self.axial_chain else self.p * s.screw_angle_rad

    def _nut_v(self, s: State) -> float:
        """Nut velocity (m/s), as `_nut_x`."""
        return s.nut_speed_m_s if self.axial_chain else self.p * s.screw_speed_rad_s

    def nut_position_m(self, st: ActuatorState) -> float:
        """The nut's position in `st`, m (its own coordinate across the axial chain in `elastic`)."""
        return self._nut_x(st.screw)

    def stored_energy(self, st: ActuatorState, stop_j: float | None = None) -> float:
        """Kinetic (screw model incl. a rigid rotor, ½ q̇ᵀ M q̇, Jones 2016 eq. 27; `elastic`: its own
        total, core and nut kinetic plus the chain's elastic energy, docs/model.md §4.3), a compliant
        rotor's, magnetic ½ L i², coupling ½ k φ² and end-stop ½ k δ² energy (J); `stop_j`: the stops'
        ½ k δ² where the caller has it already (with stops fitted)."""
        s, m = st.screw, self.actuator.motor
        ws, wc = s.screw_speed_rad_s, s.carrier_speed_rad_s
        if self.axial_chain:
            e = self._model(fl.NONE).total_stored_energy_j(s)
        else:
            e = 0.5 * (self._kss * ws * ws + 2.0 * self._ksc * ws * wc + self._kcc * wc * wc)
        if self.limits:
            e += stop_stored_j(self.limits, self._nut_x(s)) if stop_j is None else stop_j
        if m is not None:
            e += 0.5 * m.inductance_h * st.current_a**2
            if not self.rigid:
                phi = st.motor_angle_rad - s.screw_angle_rad
                e += 0.5 * self.motor_inertia * st.motor_speed_rad_s**2 + 0.5 * self.k_coupling * phi * phi
        return e

    # -- sensors -------------------------------------------------------------------------
    def _sample(self, motor_angle_rad: float, motor_speed_rad_s: float, screw: State,
                nut_force_n: float) -> TrueSample:
        """The true values the sensors see (`TrueSample`).

        Motor angle and speed come in screw coordinates (motor / gear ratio); the nut's are its own
        (`elastic`: across the axial chain from the thread, so a linear encoder sees the backlash)."""
        v_nut = self._nut_v(screw)
        return TrueSample(motor_angle_rad=motor_angle_rad * self.ratio, screw_angle_rad=screw.screw_angle_rad,
                          screw_speed_rad_s=screw.screw_speed_rad_s if self.rigid else motor_speed_rad_s,
                          nut_position_m=self._nut_x(screw), nut_velocity_m_s=v_nut, nut_force_n=nut_force_n)
