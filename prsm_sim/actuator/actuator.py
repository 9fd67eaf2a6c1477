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
dry friction (brake, jam) solved on the screw's linear response → screw model step. The
energy ledger (source in = load work + dissipated + stored) is kept in the state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from prsm_sim.actuator import faults as fl
from prsm_sim.actuator.brake import brake_level, stiction_torque
from prsm_sim.actuator.drive import drive_update, shape_reference
from prsm_sim.actuator.motor import current_reference, current_step, voltage
from prsm_sim.actuator.params import COMMAND_INTERFACES, ActuatorParams, Fault, check_interface
from prsm_sim.actuator.sensors import DROPOUT_STREAM, STREAM, first_order, normal, quantise, uniform
from prsm_sim.actuator.stops import engaged, limits_of, stop_penetration, stop_stored_j
from prsm_sim.actuator.stops import solve as solve_stop
from prsm_sim.errors import InputError
from prsm_sim.models.registry import build_model
from prsm_sim.stepping.ledger import efficiency
from prsm_sim.stepping.model import Model, check_step_inputs
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
MEASURED_QUANTITIES = (
    ("motor_angle_rad", "rad"),
    ("screw_angle_rad", "rad"),
    ("screw_speed_rad_s", "rad/s"),
    ("nut_position_m", "m"),
    ("nut_velocity_m_s", "m/s"),
    ("nut_force_n", "N"),
    ("motor_encoder_fresh", "1"),
    ("linear_encoder_fresh", "1"),
    ("load_cell_fresh", "1"),
)
_MODE_CODE = {m: float(i) for i, m in enumerate(COMMAND_INTERFACES)}
_SENSOR_INDEX = {"motor_encoder": 0, "linear_encoder": 1, "load_cell": 2}
_GROUPS = {"motor_encoder": (0, 1, 2), "linear_encoder": (3, 4), "load_cell": (5,)}  # indices into MEASURED_QUANTITIES


@dataclass(frozen=True, slots=True)
class Ledger:
    """Energy accumulators of the actuator (J); the screw's own friction is in `State.dissipated_j`."""

    energy_in_j: float = 0.0  # electrical energy drawn (ideal torque source: its mechanical work)
    copper_j: float = 0.0
    coupling_j: float = 0.0  # dissipated in the coupling's damper
    stiction_j: float = 0.0  # dissipated by the brake and jams
    stop_work_j: float = 0.0  # work the nut did on the end stops
    load_work_j: float = 0.0  # work done against the external load
    backlash_j: float = 0.0  # elastic energy a widening clearance released from a loaded flank (growing backlash)


@dataclass(frozen=True, slots=True)
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
    history: tuple[tuple[float, ...], ...] = ()
    measured: tuple[float, ...] = ()
    load_cell_filtered_n: float = 0.0
    ledger: Ledger = Ledger()
    coupling_nm: float = 0.0  # the compliant coupling's torque over the last step (its next linearisation point)
    reference_m: float = math.nan  # the drive's shaped position reference (`shape_reference`; NaN: not started)
    reference_m_s: float = 0.0  # its rate, the position loop's feed-forward
    command_prev: float = math.nan  # the position command at the last loop update (its rate: the command's speed)

    @property
    def time_s(self) -> float:
        return self.screw.time_s


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
        self.elastic = model == "elastic"
        self.actuator = a = actuator if actuator is not None else ActuatorParams()
        if not isinstance(a, ActuatorParams):
            raise InputError(f"actuator: expected ActuatorParams, got {type(a).__name__}")
        m = a.motor
        self.ratio = m.gear_ratio if m is not None else 1.0
        for f in a.faults:  # refused before anything is built or stepped
            fl.check_fault(f, params, model, m is not None)
        self.rigid = m is None or m.coupling_stiffness_nm_rad is None
        if m is not None and self.rigid:  # the rotor turns with the screw: its inertia, reflected, joins the screw's
            mass = replace(params.mass, screw_inertia_kgm2=params.mass.screw_inertia_kgm2
                           + m.rotor_inertia_kgm2 * m.gear_ratio**2)
            self.screw_params = replace(params, mass=mass)
        else:
            self.screw_params = params
        self.motor_inertia = 0.0 if m is None else m.rotor_inertia_kgm2 * m.gear_ratio**2  # screw side
        rate = a.drive.loop_rate_hz
        self.n_sub, self.hold_steps = 1, 1
        if rate is not None and rate * self.dt_s >= 1.0:
            self.n_sub = int(round(rate * self.dt_s))
        elif rate is not None:
            self.hold_steps = int(round(1.0 / (rate * self.dt_s)))
        self.h_sub = self.dt_s / self.n_sub
        # end stops and thread ends, the innermost on each side (stops.py)
        self.limits = limits_of(a.stops, params.geometry.travel_m) if a.stops.fitted or params.geometry.thread_ends \
            else ()
        self._models: dict[tuple[float, float], Model] = {}
        base = self._model(fl.NONE)
        self.p = self.geo.lead_per_rad_m
        self.J = self._probe_inertia(base)
        # the drive's gains, those left None tuned on the inertia it drives (rigid: J; compliant: J + rotor)
        self.J_drive = self.J + (0.0 if self.rigid else self.motor_inertia)  # the inertia the drive moves
        self.drive = a.drive.tuned(self.J_drive)
        self.M = mass_matrix(self.screw_params)
        self._kss, self._ksc, self._kcc = float(self.M[0, 0]), float(self.M[0, 1]), float(self.M[1, 1])
        self.layout = InternalLayout(blocks=base.layout.blocks + (
            InternalBlock("actuator", ("quantity",), (len(ACTUATOR_QUANTITIES),), ACTUATOR_QUANTITIES),
            InternalBlock("measured", ("quantity",), (len(MEASURED_QUANTITIES),), MEASURED_QUANTITIES),
        ))
        self._n_screw_internal = base.layout.size

    # -- construction helpers ------------------------------------------------------------
    def _model(self, act: fl.Active) -> Model:
        key = (act.friction_factor, act.lubrication_factor)
        mod = self._models.get(key)
        if mod is None:
            p = self.screw_params if key == (1.0, 1.0) else fl.scaled_params(self.screw_params, *key)
            mod = self._models[key] = build_model(p, self.model_name, self.h_sub, self.kernel)
        return mod

    def _accel_limit(self, torque_limit_nm: float) -> float:
        """Screw acceleration (rad/s²) the position reference may ask for: half the torque limit on the inertia
        the drive moves (the other half for the load, friction and the error), unlimited without a motor."""
        return 0.5 * torque_limit_nm / self.J_drive

    def _probe_inertia(self, model: Model) -> float:
        """Screw-side inertia seen by a torque over one sub-step, J = h / (∂ω1/∂τ), probed from rest.

        Exact for the linear models; for `fu2018` its value at rest. Used only to solve the
        implicit stop, coupling and dry-friction torques; the step itself is the model's.
        """
        s0 = model.initial_state(0.0)
        w1 = model.step(s0, 1.0, 0.0)[0].screw_speed_rad_s
        w0 = model.step(s0, 0.0, 0.0)[0].screw_speed_rad_s
        return self.h_sub / (w1 - w0)

    def _response(self, model: Model, screw: State, tau_nm: float, load_n: float) -> tuple[float, float, float, float]:
        """End speed ω1 and angle θ1 at (τ, F) and their sensitivities to τ, by two steps from this state.

        Returns (ω1, ∂ω1/∂τ, θ1, ∂θ1/∂τ); a load acts as τ = −(L/2π) F. Exact for the linear
        models; for fu2018 the local slope (its effective inertia moves with the friction regime).
        """
        a = model.step(screw, tau_nm, load_n)[0]
        d = 1e-3 * max(1.0, abs(tau_nm))
        b = model.step(screw, tau_nm + d, load_n)[0]
        s_w = (b.screw_speed_rad_s - a.screw_speed_rad_s) / d
        s_th = (b.screw_angle_rad - a.screw_angle_rad) / d
        if not (math.isfinite(s_w) and s_w > 0.0 and math.isfinite(s_th) and s_th > 0.0):
            s_w, s_th = self.h_sub / self.J, 0.5 * self.h_sub**2 / self.J  # a stuck response: the probed inertia's
        return a.screw_speed_rad_s, s_w, a.screw_angle_rad, s_th

    def _coupling(self, model: Model, screw: State, tau_st: float, load_n: float, th_r_free: float, tau_d: float,
                  phi0: float, k: float, c: float, th_sfree: float, s_th: float):
        """The compliant coupling's torque held over the step, solved to consistency with the screw model.

        τ_c = k (φ0 + φ1)/2 + c (φ1 − φ0)/h, φ1 = θ_r1(τ_c) − θ_s1(τ_c): the motor at constant
        acceleration, the screw by the model itself. The residual is strictly increasing in τ_c
        (the screw turns further, the motor less, the more torque the coupling carries), so the
        root is unique: Newton from the linear estimate, then secant steps, to 1e-12 of the
        torque scale (one model step for the linear models). Its work is then ΔV + c Δφ²/h:
        the ledger stays exact and the scheme cannot gain energy, so a stiff coupling stays
        stable at the step (trapezoidal rule). Returns (τ_c, screw state, outputs).
        """
        h, jr = self.h_sub, self.motor_inertia
        G, H = 0.5 * k + c / h, 0.5 * k - c / h
        q_r = 0.5 * h * h / jr

        def residual(tau):
            new, out = model.step(screw, tau + tau_st, load_n)
            phi1 = th_r_free + q_r * (tau_d - tau) - new.screw_angle_rad
            return tau - (G * phi1 + H * phi0), new, out

        slope = 1.0 + G * (q_r + s_th)
        t0 = (G * (th_r_free + q_r * tau_d - th_sfree) + H * phi0) / slope  # the linear solution
        r0, new, out = residual(t0)
        scale = 1e-12 * max(1.0, abs(t0), abs(tau_d))
        if abs(r0) <= scale:
            return t0, new, out
        t1 = t0 - r0 / slope
        for _ in range(30):
            r1, new, out = residual(t1)
            if abs(r1) <= scale or r1 == r0:
                break
            t0, t1, r0 = t1, t1 - r1 * (t1 - t0) / (r1 - r0), r1
        return t1, new, out

    # -- state ---------------------------------------------------------------------------
    def initial_state(self, nut_position_m: float = 0.0, load_n: float = 0.0) -> ActuatorState:
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
        th_r = th if self.rigid or hold == 0.0 else th + hold / m.coupling_stiffness_nm_rad
        i_a = 0.0 if m is None else hold / (self.ratio * m.torque_constant_nm_a)
        st = ActuatorState(screw=screw, mode=mode, motor_angle_rad=th_r, current_a=i_a,
                           integral_nm=hold if mode != "effort" else 0.0, torque_ref_nm=hold,
                           coupling_nm=0.0 if self.rigid else hold)
        sample = self._sample(th_r, 0.0, screw, float(load_n))
        enc = self._encoder_screw_angle(th_r * self.ratio, th)
        *meas, filt = self._measure(0, (), 0.0, sample, sample, fl.NONE, first=True)
        return replace(st, encoder_rad=enc, history=(sample,), measured=tuple(meas), load_cell_filtered_n=filt)

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
        t0 = before.time_s
        return fl.fault_events(self.all_faults(after), t0 - self.dt_s, t0)

    # -- the step ------------------------------------------------------------------------
    def step(self, state: ActuatorState, command: float, load_n: float) -> tuple[ActuatorState, Outputs]:
        """One step with `command` (active interface: N·m, screw rad/s or nut m) and the nut load."""
        command, load_n = check_step_inputs(command, load_n, self.command_name)
        if not isinstance(state, ActuatorState):
            raise InputError(f"state: expected an ActuatorState (Actuator.initial_state), got {type(state).__name__}")
        return self._step_impl(state, command, load_n)

    def _step_impl(self, st: ActuatorState, command: float, load_n: float):
        a, m = self.actuator, self.actuator.motor
        h, p, J, N = self.h_sub, self.p, self.J, self.ratio
        faults = self.all_faults(st)
        act = fl.active(faults, st.time_s)
        model = self._model(act)
        screw, led = st.screw, st.ledger
        extra = fl.extra_clearance_m(faults, st.time_s) if self.elastic else 0.0
        if extra < screw.extra_clearance_m:
            # a cleared fault: the gap closes back only as far as the flanks are apart (2|δ| − c), never
            # into a loaded flank (that would be a force step of k Δc/2 out of nothing); it reaches the
            # parameter's clearance at the next pass through the gap
            delta = p * screw.screw_angle_rad - screw.nut_axial_m
            extra = max(extra, min(screw.extra_clearance_m, 2.0 * abs(delta) - self.params.elastic.axial_clearance_m))
        if extra != screw.extra_clearance_m:
            # the clearance steps at the step's start: a wider gap at the same deflection unloads the
            # flank in contact, releasing its elastic energy (booked as dissipated: ≥ 0, since the gap
            # never closes onto a flank), so the ledger and the model's guard stay closed
            widened = replace(screw, extra_clearance_m=extra)
            led = replace(led, backlash_j=led.backlash_j + float(model.total_stored_energy_j(screw)
                                                                 - model.total_stored_energy_j(widened)))
            screw = widened
        th_r, w_r, i_a = st.motor_angle_rad, st.motor_speed_rad_s, st.current_a
        integ, tau_ref, w_ref, limited, enc = st.integral_nm, st.torque_ref_nm, st.speed_ref_rad_s, st.limited, st.encoder_rad
        level = st.brake_level
        sums = [0.0, 0.0, 0.0, 0.0]  # screw torque·h, power in, out, dissipated (for n_sub > 1)
        volt = tau_st = f_stop = 0.0
        tau_c = st.coupling_nm
        ref, ref_v, cmd_prev = st.reference_m, st.reference_m_s, st.command_prev
        tlim = math.inf if m is None else N * m.peak_torque_nm * act.torque_factor
        loop_due = st.step % self.hold_steps == 0
        for j in range(self.n_sub):
            # drive loop on the encoder feedback
            if loop_due:
                enc_new = self._read_encoder(th_r * N, screw.screw_angle_rad, act, st.step * self.n_sub + j, enc)
                h_loop = h * self.hold_steps
                if a.sensors.encoder_counts_per_rev == 0 and not any(x[0] == "motor_encoder" for x in act.sensor):
                    w_meas = w_r if not self.rigid else screw.screw_speed_rad_s
                else:
                    w_meas = (enc_new - enc) / h_loop
                enc = enc_new
                x_meas = self._read_linear(self._nut_x(screw), enc, act, st.step * self.n_sub + j)
                if act.drive_off:
                    tau_ref, integ, limited, w_ref = 0.0, 0.0, False, 0.0
                    ref, ref_v, cmd_prev = math.nan, 0.0, math.nan  # restarts from the command when the drive is back
                else:
                    ff = ff_nm = 0.0
                    target = command
                    if st.mode == "position" and self.drive.position_feedforward:
                        if not math.isfinite(ref):
                            # the reference starts at the command: it shapes the command's changes (the loop
                            # alone takes out an initial error, as without feed-forward)
                            ref, ref_v = command, 0.0
                        # the loops compare the nut now with the reference now; the torque that takes the
                        # reference to its next point over this update is fed forward
                        target, v0 = ref, ref_v
                        rate = (command - cmd_prev) / h_loop if math.isfinite(cmd_prev) else 0.0
                        cmd_prev = command
                        ref, ref_v = shape_reference(ref, ref_v, command, rate, self.drive.speed_limit_rad_s * p,
                                                     self._accel_limit(tlim) * p, h_loop)
                        ff, ff_nm = v0 / p, self.J_drive * (ref_v - v0) / (p * h_loop)
                    d = drive_update(self.drive, st.mode, target, integ, w_meas, x_meas, p, tlim, h_loop, ff, ff_nm)
                    tau_ref, integ, limited, w_ref = d
            # current loop and motor torque (screw side)
            if m is None:
                tau_d = tau_ref
            else:
                i_ref = 0.0 if act.drive_off else current_reference(m, tau_ref, w_r * N)
                cs = current_step(m, i_a, i_ref, h)
                volt = voltage(m, cs, i_a, w_r * N, h)
                tau_d = N * m.torque_constant_nm_a * cs.mean_current_a
            if self.rigid:
                tau_drive_screw = tau_d
            else:
                k, c = m.coupling_stiffness_nm_rad, m.coupling_damping_nm_s_rad
                phi0 = th_r - screw.screw_angle_rad
                # linearise where the last step ended: the explicit spring torque k φ0 would swing with
                # the coupling's ringing and evaluate a set-valued friction on the wrong side
                tau_drive_screw = tau_c
            # dry friction (brake, jam) and a compliant coupling are solved implicitly on the screw's local
            # linear response ω1(τ, F) = ω_a + s (τ − τ_a) − p s (F − F_a): s comes from two model steps at
            # this state (exact for the linear models; fu2018's effective inertia moves with its friction
            # regime, so a fixed J would not do)
            cap = level * a.brake.holding_torque_nm + act.jam_nm
            implicit = not self.rigid or cap > 0.0
            if implicit:
                w_a, s_w, th_a, s_th = self._response(model, screw, tau_drive_screw, load_n)
            else:
                s_th = 0.5 * h * h / J

            def advance(f_stop, screw=screw, tau_drive_screw=tau_drive_screw, th_r=th_r, w_r=w_r, tau_d=tau_d):
                """The sub-step with the stop force f_stop (along +x_nut) on the nut: (state, outputs,
                stiction torque, coupling torque, screw torque)."""
                load_in = load_n - f_stop if f_stop != 0.0 else load_n
                t_st = 0.0
                if implicit:
                    w_pred, th_pred = w_a + p * s_w * f_stop, th_a + p * s_th * f_stop
                    t_st = stiction_torque(cap, w_pred, h / s_w, h)
                    th_pred += s_th * t_st
                if self.rigid:
                    tau_in = tau_drive_screw + t_st if t_st != 0.0 else tau_drive_screw
                    return (*model.step(screw, tau_in, load_in), t_st, tau_d, tau_in)
                th_sfree = th_pred - s_th * tau_drive_screw  # the screw's end angle with no coupling torque
                t_c, nw, o = self._coupling(model, screw, t_st, load_in, th_r + h * w_r, tau_d, phi0, k, c,
                                            th_sfree, s_th)
                return nw, o, t_st, t_c, t_c + t_st

            res = advance(0.0)
            f_stop = 0.0
            if self.limits:
                # the stops act where the nut is: its own coordinate (across the chain in `elastic`)
                lim = engaged(self.limits, self._nut_x(res[0]))
                if lim is not None:
                    f_stop, res = solve_stop(lim, h, self._nut_x(screw), res, advance, lambda r: self._nut_x(r[0]),
                                             p * p * s_th)
            new, out, tau_st, tau_c, tau_in = res
            if not self.rigid:
                tau_drive_screw = tau_c
            dth = new.screw_angle_rad - screw.screw_angle_rad
            # where load and stop force act: the nut (its own coordinate in `elastic`)
            dx_nut = new.nut_axial_m - screw.nut_axial_m if self.elastic else p * dth
            # motor side and the ledger
            if self.rigid:
                th_r1, w_r1 = new.screw_angle_rad, new.screw_speed_rad_s
                dth_r = dth
            else:
                w_r1 = w_r + h * (tau_d - tau_c) / self.motor_inertia
                th_r1 = th_r + 0.5 * h * (w_r + w_r1)
                dth_r = th_r1 - th_r
                v0 = 0.5 * k * phi0 * phi0
                phi1 = th_r1 - new.screw_angle_rad
                led = replace(led, coupling_j=led.coupling_j + tau_c * (dth_r - dth) - (0.5 * k * phi1 * phi1 - v0))
            if m is None:
                e_in = tau_d * dth
                copper = 0.0
            else:
                copper = cs.copper_j
                e_in = cs.copper_j + cs.magnetic_j + tau_d * dth_r
                i_a = cs.current_a
            led = Ledger(energy_in_j=led.energy_in_j + e_in, copper_j=led.copper_j + copper, coupling_j=led.coupling_j,
                         stiction_j=led.stiction_j - tau_st * dth, stop_work_j=led.stop_work_j - f_stop * dx_nut,
                         load_work_j=led.load_work_j + load_n * dx_nut, backlash_j=led.backlash_j)
            th_r, w_r = th_r1, w_r1
            if self.n_sub > 1:
                sums[0] += tau_in
                sums[1] += out.power_in_w
                sums[2] += out.power_out_w
                sums[3] += out.power_dissipated_w
            screw = new
            level = brake_level(a.brake, level, st.brake_engaged, h)
        if self.n_sub > 1:
            n = self.n_sub
            pin, pout, pd = sums[1] / n, sums[2] / n, sums[3] / n
            out = replace(out, screw_torque_nm=sums[0] / n, power_in_w=pin, power_out_w=pout,
                          power_dissipated_w=pd, efficiency=efficiency(pin, pout, pd))
        # sensors: the true sample now, delivered `latency_steps` later
        sample = self._sample(th_r, w_r, screw, out.nut_force_n)
        lat = a.sensors.latency_steps
        history = (st.history + (sample,))[-(lat + 1):] if lat else (sample,)
        before = st.history[0] if st.history else history[0]
        *meas, filt = self._measure(st.step + 1, st.measured, st.load_cell_filtered_n, history[0], before, act)
        meas = tuple(meas)
        nxt = ActuatorState(screw, st.step + 1, st.mode, th_r, w_r, i_a, integ, tau_ref, w_ref, limited, enc,
                            st.brake_engaged, level, st.faults, history, meas, filt, led, 0.0 if self.rigid else tau_c, ref, ref_v,
                            cmd_prev)
        # the actuator block
        x = self._nut_x(screw)
        stop_e = stop_stored_j(self.limits, x)
        depth, at_end = stop_penetration(self.limits, x)
        stored = self.stored_energy(nxt)
        diss = (screw.dissipated_j + led.copper_j + led.coupling_j + led.stiction_j + led.stop_work_j - stop_e
                + led.backlash_j)
        cap_b = level * a.brake.holding_torque_nm
        cap_all = cap_b + act.jam_nm
        brake_t = tau_st * cap_b / cap_all if cap_all > 0 else 0.0
        motor_torque = 0.0 if m is None else m.torque_constant_nm_a * i_a
        n_active = float(sum(f.active(st.time_s) for f in self.all_faults(st))) if act is not fl.NONE else 0.0
        block = (command, _MODE_CODE[st.mode], w_ref, tau_ref, float(limited), i_a, motor_torque,
                 w_r * N, volt, (led.energy_in_j - st.ledger.energy_in_j) / self.dt_s, tau_c, level, brake_t,
                 tau_st - brake_t, f_stop, depth, led.stop_work_j - stop_e, float(at_end), led.energy_in_j, led.load_work_j, diss, stored, n_active)
        # `out` was made by the screw model for this call alone: completing its internal vector in
        # place saves a copy of the whole record per step
        object.__setattr__(out, "internal", np.concatenate((out.internal, block, meas)))
        return nxt, out

    # -- what the sensors say -------------------------------------------------------------
    def measured(self, out: Outputs) -> Outputs:
        """`out` with the joint quantities replaced by what the sensors measured (for `joint_states`).

        Screw angle and speed from the motor encoder, nut position and velocity from the
        linear encoder (or the motor encoder), nut force from the load cell; every other field
        is the true one. With ideal sensors this is `out`'s values exactly.
        """
        m = self.layout.view(out.internal, "measured")
        return replace(out, screw_angle_rad=float(m[1]), screw_speed_rad_s=float(m[2]), nut_position_m=float(m[3]),
                       nut_velocity_m_s=float(m[4]), nut_force_n=float(m[5]))

    # -- energy --------------------------------------------------------------------------
    def _nut_x(self, s: State) -> float:
        """Nut position (m): its own coordinate in `elastic`, (L/2π) θ_S in the rigid models."""
        return s.nut_axial_m if self.elastic else self.p * s.screw_angle_rad

    def stored_energy(self, st: ActuatorState) -> float:
        """Kinetic (screw model incl. a rigid rotor, ½ q̇ᵀ M q̇, Jones 2016 eq. 27; `elastic`: its own
        total, core and nut kinetic plus the chain's elastic energy, docs/model.md §4.3), a compliant
        rotor's, magnetic ½ L i², coupling ½ k φ² and end-stop ½ k δ² energy (J)."""
        s, m = st.screw, self.actuator.motor
        ws, wc = s.screw_speed_rad_s, s.carrier_speed_rad_s
        if self.elastic:
            e = self._model(fl.NONE).total_stored_energy_j(s)
        else:
            e = 0.5 * (self._kss * ws * ws + 2.0 * self._ksc * ws * wc + self._kcc * wc * wc)
        if self.limits:
            e += stop_stored_j(self.limits, self._nut_x(s))
        if m is not None:
            e += 0.5 * m.inductance_h * st.current_a**2
            if not self.rigid:
                phi = st.motor_angle_rad - s.screw_angle_rad
                e += 0.5 * self.motor_inertia * st.motor_speed_rad_s**2 + 0.5 * m.coupling_stiffness_nm_rad * phi * phi
        return e

    # -- sensors -------------------------------------------------------------------------
    def _encoder_screw_angle(self, motor_angle_rad: float, screw_angle_rad: float) -> float:
        counts = self.actuator.sensors.encoder_counts_per_rev
        if counts == 0:
            return screw_angle_rad if self.rigid else motor_angle_rad / self.ratio
        return quantise(motor_angle_rad, 2.0 * math.pi / counts) / self.ratio

    def _faulted(self, sensor: str, value: float, held: float, act: fl.Active, key: int) -> tuple[float, bool]:
        """Apply the active faults of `sensor` to a fresh reading: (value, fresh?)."""
        seed = self.actuator.sensors.seed
        for s, kind, v in act.sensor:
            if s != sensor:
                continue
            if kind == "sensor_bias":
                value += v
            elif kind == "sensor_noise":
                value += v * normal(seed, key, 100 + STREAM[sensor])
            elif kind == "sensor_stuck":
                return held, False
            elif kind == "sensor_dropout" and uniform(seed, key, 110 + STREAM[sensor]) <= v:
                return held, False
        return value, True

    def _read_encoder(self, motor_angle_rad: float, screw_angle_rad: float, act: fl.Active, key: int,
                      held: float) -> float:
        v = self._encoder_screw_angle(motor_angle_rad, screw_angle_rad)
        return self._faulted("motor_encoder", v, held, act, key)[0] if act.sensor else v

    def _read_linear(self, nut_m: float, encoder_screw_rad: float, act: fl.Active, key: int) -> float:
        res = self.actuator.sensors.linear_encoder_resolution_m
        if res is None:
            return self.p * encoder_screw_rad
        v = quantise(nut_m, res)
        return self._faulted("linear_encoder", v, v, act, key)[0] if act.sensor else v

    def _sample(self, motor_angle_rad: float, motor_speed_rad_s: float, screw: State,
                nut_force_n: float) -> tuple[float, ...]:
        """The true values the sensors see: motor angle (motor shaft), screw angle/speed, nut position/velocity/force.

        Motor angle and speed come in screw coordinates (motor / gear ratio); the nut's are its own
        (`elastic`: across the axial chain from the thread, so a linear encoder sees the backlash)."""
        p = self.p
        v_nut = screw.nut_speed_m_s if self.elastic else p * screw.screw_speed_rad_s
        return (motor_angle_rad * self.ratio, screw.screw_angle_rad,
                screw.screw_speed_rad_s if self.rigid else motor_speed_rad_s,
                self._nut_x(screw), v_nut, nut_force_n)

    def _measure(self, key: int, prev: tuple, filtered_n: float, now: tuple, before: tuple, act: fl.Active,
                 first: bool = False) -> tuple:
        """What the sensors report at step `key` for the delayed true sample `now` (`before`: a step earlier).

        `prev`: the last reading (held on dropout or a stuck fault); `filtered_n`: the load
        cell filter's memory. Returns the MEASURED_QUANTITIES values and the new filter memory.
        """
        sp, p, h = self.actuator.sensors, self.p, self.dt_s
        prev = prev if prev else None
        # motor encoder → screw angle and speed
        ang = self._encoder_screw_angle(now[0], now[1])
        if sp.encoder_counts_per_rev == 0:
            spd = now[2]
        else:
            spd = 0.0 if first else (ang - self._encoder_screw_angle(before[0], before[1])) / h
        fresh = [1.0, 1.0, 1.0]
        out = [now[0] if sp.encoder_counts_per_rev == 0 else ang * self.ratio, ang, spd]
        # nut position and velocity: linear encoder if fitted, else from the motor encoder
        if sp.linear_encoder_resolution_m is None:
            if sp.encoder_counts_per_rev == 0 and self.rigid:
                out += [now[3], now[4]]
            else:
                out += [p * ang, p * spd]
        else:
            res = sp.linear_encoder_resolution_m
            x = quantise(now[3], res)
            v = now[4] if res == 0 else (0.0 if first else (x - quantise(before[3], res)) / h)
            out += [x, v]
        # load cell, in a conditioning chain's order: element (true force) → amplifier (bias, white noise of
        # σ per sample at the step rate) → anti-alias first-order low-pass, so the filter acts on the noise
        raw = now[5] + sp.load_cell_bias_n if sp.load_cell_bias_n else now[5]
        if sp.load_cell_noise_n:
            raw += sp.load_cell_noise_n * normal(sp.seed, key, STREAM["load_cell"])
        filt = first_order(filtered_n, raw, sp.load_cell_bandwidth_hz, h) if not first else raw
        out.append(filt)
        if prev is not None:
            lin = sp.linear_encoder_resolution_m is not None
            for sensor, idx in _GROUPS.items():
                if sensor == "linear_encoder" and not lin:
                    continue
                si = _SENSOR_INDEX[sensor]
                dropped = sp.dropout_probability > 0 and uniform(sp.seed, key, DROPOUT_STREAM[sensor]) <= sp.dropout_probability
                if not dropped and act.sensor:
                    # bias and noise act on the primary reading (screw angle rad, nut position m, force N)
                    primary = idx[1] if sensor == "motor_encoder" else idx[0]
                    v, ok = self._faulted(sensor, out[primary], prev[primary], act, key)
                    dropped = not ok
                    if ok and v != out[primary]:
                        out[primary] = v
                        if sensor == "motor_encoder":
                            out[0] = v * self.ratio
                if dropped:
                    for i in idx:
                        out[i] = prev[i]
                    fresh[si] = 0.0
                if sensor == "motor_encoder" and not lin and (dropped or act.sensor):
                    out[3], out[4] = p * out[1], p * out[2]
        return tuple(out) + tuple(fresh) + (filt,)
