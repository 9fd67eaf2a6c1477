"""`Session`: an actuator (or a bare screw model) run the way a controller drives it, one step at a time.

    s = Session(preset("s30"), "fu2018", 1e-3, ActuatorParams(motor=MotorParams()), interface="velocity")
    s.offer("velocity", 40.0)          # a command, checked by the gate (None, or why it was refused)
    out = s.step(load_n=500.0)         # → Outputs; the gate's command, the load kept until changed
    s.brake(True); s.inject(Fault("jam", value=5.0)); s.take_events()
    s.status()                         # plain data: time, command, watchdog, faults, brake, energy

A `Simulator` advances a model; a `Session` adds what a runtime needs around it, the same for
every transport (the ROS node, offline runs, studies): the command gate and its watchdog
(`CommandGate`), the nut load held between steps, the interface switch, brake, runtime faults and
the fault events they raise, pause, reset, and the run's fault: a model that fails or produces a
non-finite state stops the session (`ModelError`, and `fault` says why) until `reset`, with the
last finite state kept.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from prsm_sim.actuator import ACTUATOR_QUANTITIES, Actuator, ActuatorParams, ActuatorState, Fault, FaultEvent
from prsm_sim.actuator.drive import warn_if_ringing
from prsm_sim.actuator.stops import ThreadEndEvent
from prsm_sim.checks import check_typed, is_finite_number
from prsm_sim.command_gate import INTERFACE_UNIT, CommandGate, GateCounters
from prsm_sim.errors import InputError, ModelError, NonFiniteStateError, ParamError, PrsmError
from prsm_sim.models.registry import build_model
from prsm_sim.params import Params
from prsm_sim.plain import from_plain, reachable_types, to_plain
from prsm_sim.simulator import RatingEvent, Simulator
from prsm_sim.stepping.packed import NUT_FORCE_ITEM, PackedOutputs
from prsm_sim.stepping.records import InternalLayout, Outputs
from prsm_sim.stepping.model import Model


STATE_FORMAT = "prsm_session/1"
_THREAD_END = [n for n, _ in ACTUATOR_QUANTITIES].index("thread_end")  # in the actuator's output block
_STOP_FORCE = [n for n, _ in ACTUATOR_QUANTITIES].index("stop_force_n")
# what a session holds besides its simulator and its gate, saved by `get_state`, and the types `set_state` takes
_RUN_TYPES = {"nut_position_m": float, "load_n": float, "initial_load_n": float | None, "_paused": bool,
              "fault": str | None, "_last": Outputs | None, "_events": list[FaultEvent], "_at_thread_end": bool,
              "_edge_events": list[ThreadEndEvent | RatingEvent]}
_RUN_FIELDS = tuple(_RUN_TYPES)
_GATE_TYPES = {"value": float, "command_time_s": float | None, "timed_out": bool, "counters": GateCounters}


def state_is_finite(out: Outputs) -> bool:
    """The state-carrying outputs are finite (efficiency and speed_ratio may be NaN by design).

    A `PackedOutputs` record's internal loads are derived when read, from its speeds (ideal,
    jones2016) or from the step's solved end forces, of which the nut force checked here is one
    (fu2018, elastic); building them every step just to check them would cost more than the step.
    """
    # x * 0 is ±0 for a finite float and NaN otherwise, so the sum is 0 exactly when all are finite
    # (a sum of the values themselves could overflow); one test instead of five calls, every step
    if type(out) is PackedOutputs:
        return out[1] * 0.0 + out[2] * 0.0 + out[3] * 0.0 + out[4] * 0.0 + out[NUT_FORCE_ITEM] * 0.0 == 0.0
    return (out.screw_angle_rad * 0.0 + out.screw_speed_rad_s * 0.0 + out.carrier_angle_rad * 0.0
            + out.carrier_speed_rad_s * 0.0 + out.nut_force_n * 0.0 == 0.0) and bool(np.isfinite(out.internal).all())


def _drive_in(actuator: ActuatorParams | None, interface: str) -> ActuatorParams | None:
    """`actuator` with its drive in the session's `interface`: the actuator is built in that mode, so the loop
    its build checks (`DriveLoopWarning`) is the one that runs, whatever `drive.mode` it was given."""
    if isinstance(actuator, ActuatorParams) and actuator.drive.mode != interface:
        return replace(actuator, drive=replace(actuator.drive, mode=interface))
    return actuator


def _warn_if_ringing(act: Actuator, mode: str) -> None:
    """`DriveLoopWarning` where the drive's loop of `mode` does not settle at its loop rate (as building says
    it for the mode it starts in: `actuator.drive.tuned_drive`)."""
    warn_if_ringing(act.drive, mode, act.drive_loop_radius(mode), act.J_drive, act.h_sub * act.hold_steps, act.dt_s,
                    stacklevel=4)


@dataclass(frozen=True)
class SessionConfig:
    """Everything a `Session` is built from: the one description every transport (the node, the FMU,
    studies, the CLI, the envelope) fills in and hands to `Session.from_config`.

    Attributes
    ----------
    params, model, dt_s, actuator, kernel
        The parameter set, the screw model's name, the fixed step (s), the actuator around the screw
        (`ActuatorParams`, None: the bare model, effort only) and the kernel, as for `Simulator`.
    faults : tuple of Fault
        Faults scheduled besides the actuator's own (`ActuatorParams.faults`); an actuator is needed.
    interface : {"effort", "velocity", "position"}
        The active command interface at the start.
    nut_position_m, load_n, initial_load_n
        The start: nut position (m), the nut load in force (N) and the load the start is in
        equilibrium under (N, None: at rest and unloaded), as for `Session`.
    max_effort_nm, cmd_timeout_s, timeout_behaviour
        The command gate's torque limit (N·m), watchdog timeout (simulation s, 0 disables) and what
        a timeout does ("zero" or "hold").
    paused : bool
        Start paused (the transport steps only on request).

    Values are checked where the session is built (one line naming the field).
    """

    params: Params
    model: str = "jones2016"
    dt_s: float = 1e-3
    actuator: ActuatorParams | None = None
    faults: tuple[Fault, ...] = ()
    kernel: str = "compiled"
    interface: str = "effort"
    nut_position_m: float = 0.0
    load_n: float = 0.0
    initial_load_n: float | None = None
    max_effort_nm: float = 50.0
    cmd_timeout_s: float = 0.0
    timeout_behaviour: str = "zero"
    paused: bool = False


class Session:
    """A simulator with its command gate, load, pause and fault state: one `step()` per step.

    Parameters
    ----------
    params, model, dt_s, actuator
        As for `Simulator`: the parameter set, the screw model's name, the fixed step (s), and
        the actuator around the screw (`ActuatorParams`) or None for the bare model (effort only).
    nut_position_m : float, default 0.0
        Initial nut position, m; `reset` returns there.
    load_n : float, default 0.0
        Nut load, N, held until `step(load_n=...)` or `load_n` changes it.
    initial_load_n : float, optional
        Start (and return on `reset`) in equilibrium under this nut load, N, and with it as the load
        in force (`Simulator`'s `initial_load_n`: a deflected `elastic` chain, an actuator's drive
        train at the holding torque (L/2π) F); None: at rest and unloaded, and a reset keeps the load
        in force. The session's `interface`, whatever the actuator's `drive.mode`, decides what holds
        it, also after `set_interface` before the first step and after `reset`: in velocity and
        position the drive's speed loop (a zero speed command, or the start's position, keeps it);
        in effort the command, which keeps it when it is the holding torque (the gate starts at 0 N·m).
    kernel : {"compiled", "reference"}
        As for `Simulator`.
    interface : {"effort", "velocity", "position"}
        The active command interface (the bare model has effort only).
    max_effort_nm, cmd_timeout_s, timeout_behaviour
        The gate's torque limit, watchdog timeout (simulation s; 0 disables) and what a timeout
        does ("zero" or "hold"); see `prsm_sim.command_gate`.

    Attributes
    ----------
    simulator : Simulator
        The simulator stepped (its model is an `Actuator` when one is fitted).
    gate : CommandGate
        The command gate: the active interface, the command in force, counters, watchdog.
    load_n : float
        The nut load held over the next steps, N.
    fault : str or None
        Why stepping stopped (until `reset`), or None.
    """

    def __init__(self, params: Params, model: str, dt_s: float, actuator: ActuatorParams | None = None, *,
                 nut_position_m: float = 0.0, load_n: float = 0.0, initial_load_n: float | None = None,
                 kernel: str = "compiled", interface: str = "effort", max_effort_nm: float = 50.0,
                 cmd_timeout_s: float = 0.0, timeout_behaviour: str = "zero") -> None:
        for name, v in (("nut_position_m", nut_position_m), ("load_n", load_n), ("initial_load_n", initial_load_n)):
            if not (v is None and name == "initial_load_n") and not is_finite_number(v):
                raise InputError(f"{name} = {v!r}: must be a finite number")
        self.model_name = model
        self.kernel = kernel
        self.gate = CommandGate(max_effort_nm, cmd_timeout_s, timeout_behaviour, interface)
        self.actuator_params = actuator = _drive_in(actuator, interface)
        self.simulator = Simulator(params, model, dt_s, nut_position_m, actuator=actuator, kernel=kernel,
                                   initial_load_n=initial_load_n)
        self.nut_position_m = float(nut_position_m)
        self.initial_load_n = None if initial_load_n is None else float(initial_load_n)
        self.load_n = float(load_n) if initial_load_n is None or load_n != 0.0 else float(initial_load_n)
        self._at_thread_end = False  # the nut pressed on a thread end after the last step
        self._edge_events: list = []  # thread-end and rating events (ThreadEndEvent, RatingEvent) not yet taken
        self._over_rating = False  # the last step's nut load exceeded the static rating
        self._paused = False
        self.fault: str | None = None
        self._last: Outputs | None = None
        self._events: list = []  # fault starts and clears (actuator.FaultEvent) not yet taken
        self._screw_model: Model | None = None  # the actuator's screw model, built when rest outputs first need it
        reason = self.set_interface(interface) if interface != "effort" or actuator is not None else None
        if reason is not None:
            raise ParamError(reason)
        self.gate.reset(self.nut_position_m)

    @classmethod
    def from_config(cls, config: SessionConfig) -> Session:
        """The session `config` describes (InputError/ParamError naming the field when refused)."""
        if not isinstance(config, SessionConfig):
            raise InputError(f"config: expected a SessionConfig, got {type(config).__name__}")
        act = config.actuator
        if config.faults:
            if act is None:
                raise InputError("faults: the bare model takes no faults (fit an actuator)")
            if not isinstance(act, ActuatorParams):
                raise InputError(f"actuator: expected ActuatorParams, got {type(act).__name__}")
            act = replace(act, faults=act.faults + tuple(config.faults))
        if not isinstance(config.paused, bool):
            raise InputError(f"paused = {config.paused!r}: must be true or false")
        session = cls(config.params, config.model, config.dt_s, act, nut_position_m=config.nut_position_m,
                      load_n=config.load_n, initial_load_n=config.initial_load_n, kernel=config.kernel,
                      interface=config.interface, max_effort_nm=config.max_effort_nm,
                      cmd_timeout_s=config.cmd_timeout_s, timeout_behaviour=config.timeout_behaviour)
        if config.paused:
            session.pause()
        return session

    def __repr__(self) -> str:
        return (f"Session(model={self.model_name!r}, actuator={self.actuator is not None}, "
                f"interface={self.gate.interface!r}, time_s={self.time_s:.6g}, nstep={self.nstep}"
                + (f", fault={self.fault!r}" if self.fault else "") + ")")

    # -- what it is -----------------------------------------------------------------------
    @property
    def actuator(self) -> Actuator | None:
        """The actuator around the screw, or None for the bare model."""
        m = self.simulator.model
        return m if isinstance(m, Actuator) else None

    @property
    def params(self) -> Params:
        return self.simulator.params

    @property
    def dt_s(self) -> float:
        return self.simulator.dt_s

    @property
    def layout(self) -> InternalLayout:
        """Labels of the internal-load vector of every step's `Outputs`."""
        return self.simulator.layout

    @property
    def time_s(self) -> float:
        """Simulation time, s."""
        return self.simulator.time_s

    @property
    def nstep(self) -> int:
        """Steps since construction or the last `reset`."""
        return self.simulator.nstep

    @property
    def interface(self) -> str:
        """The active command interface."""
        return self.gate.interface

    @property
    def last(self) -> Outputs:
        """The last step's outputs; before the first step after a reset, the state at rest (`rest_outputs`)."""
        return self._last if self._last is not None else self.rest_outputs()

    @property
    def stepped(self) -> bool:
        """A step has run since construction or the last `reset`."""
        return self._last is not None

    # -- stepping -------------------------------------------------------------------------
    def step(self, command: float | None = None, load_n: float | None = None) -> Outputs:
        """One step with the gated command and the load held over it.

        Parameters
        ----------
        command : float, optional
            A command in the active interface's unit (N·m, screw rad/s or nut m), handed to the
            gate at the present simulation time (saturated, counted) before the step; None: the
            gate's command in force (zero or held after a watchdog timeout).
        load_n : float, optional
            A new nut load, N, kept for later steps; None: the load in force.

        Raises
        ------
        InputError
            A command or load that is not a finite number; nothing changed.
        ModelError
            The model failed or produced a non-finite state (now or before, until `reset`); the
            last finite state is kept.
        """
        if self.fault is not None:
            raise ModelError(self.fault)
        if load_n is not None and not is_finite_number(load_n):
            raise InputError(f"load_n = {load_n!r}: must be a finite number (N)")
        sim, gate = self.simulator, self.gate
        t0 = sim.time_s  # read off the packed record: no `State` is built on this path
        if command is not None:
            # a finite float passes on the first test (x · 0 is 0 only for finite x): the node's every step
            if not (type(command) is float and command * 0.0 == 0.0) and not is_finite_number(command):
                raise InputError(f"command = {command!r}: must be a finite number "
                                 f"({INTERFACE_UNIT[gate.interface]})")
            gate.offer(gate.interface, command, t0)
        if load_n is not None:
            self.load_n = float(load_n)
        command = gate.command(t0)
        act = self.actuator
        before = None if act is None else self._actuator_before(act)
        try:
            out = sim.step(command, self.load_n)
        except NonFiniteStateError as e:  # the simulator kept the last finite state
            raise self._non_finite(e.time_s, command) from None
        except Exception as e:  # any model failure stops stepping until reset
            self.fault = f"model {self.model_name} failed at t = {t0:.6f} s: {type(e).__name__}: {e}"
            raise ModelError(self.fault) from e
        if not state_is_finite(out):
            sim.undo()  # keep the last finite state; reset clears the fault
            raise self._non_finite(out.time_s, command)
        if act is not None and before is not None:
            self._events += act.events(before, sim.state)
            at_end = bool(out.internal[act.block_at + _THREAD_END]) if self.params.geometry.thread_ends else False
            end_force = out.internal[act.block_at + _STOP_FORCE] if at_end else 0.0
        else:
            at_end = (end_force := sim.thread_end_force_n) != 0.0
        if at_end != self._at_thread_end:
            self._at_thread_end = at_end
            self._edge_events.append(ThreadEndEvent(out.time_s, "reached" if at_end else "left", float(end_force)))
        over = sim.over_static_rating == 1.0
        if over != self._over_rating:
            self._over_rating = over
            self._edge_events.append(RatingEvent(out.time_s, "exceeded" if over else "within", out.load_force_n,
                                                 sim.params.ratings.static_load_rating_n or math.inf))
        self._last = out
        return out

    def _actuator_before(self, act):
        """The actuator's state before a step, its brake applied first where the watchdog timed out and the
        brake engages on it (an actuator's state is its own `ActuatorState`, never packed: reading it is free)."""
        before = self.simulator.state
        if self.gate.timed_out and act.actuator.brake.engage_on_watchdog and act.actuator.brake.fitted \
                and not before.brake_engaged:
            self.simulator.state = before = act.command_brake(before, True)
        return before

    def _non_finite(self, time_s: float, command: float) -> ModelError:
        """Stop stepping until reset: the step at `time_s` produced a non-finite state."""
        self.fault = (f"model {self.model_name} produced a non-finite state at t = {time_s:.6f} s "
                      f"(command {command:g} {self.gate.interface}, load {self.load_n:g} N); "
                      "stepping stopped until reset")
        return NonFiniteStateError(self.fault, time_s)

    def take_edge_events(self) -> list:
        """The plant's edge events since the last call: `ThreadEndEvent` (the nut reached or left an end) and
        `RatingEvent` (its load went past the static rating or back within it)."""
        ev, self._edge_events = self._edge_events, []
        return ev

    def fail(self, reason: str) -> None:
        """Stop stepping for a reason outside the model (e.g. a transport that cannot deliver the
        step's outputs), until `reset`."""
        self.fault = str(reason)

    # -- commands ---------------------------------------------------------------------------
    def offer(self, interface: str, value: float) -> str | None:
        """A command for `interface` at the present simulation time; the reason it was refused, or None."""
        return self.gate.offer(interface, value, self.simulator.time_s)

    def refuse_malformed(self, reason: str) -> str:
        """A command a transport could not read at all: counted as received and malformed; returns `reason`."""
        return self.gate.refuse_malformed(reason)

    def configure_gate(self, max_effort_nm: float, cmd_timeout_s: float, timeout_behaviour: str) -> None:
        """New gate limits (ParamError, nothing changed, when refused)."""
        self.gate.configure(max_effort_nm, cmd_timeout_s, timeout_behaviour)

    def set_interface(self, interface: str) -> str | None:
        """Switch the command interface; the command starts at the measured speed or position (or
        0 N·m). The reason it was refused, or None."""
        act = self.actuator
        if act is None:
            if interface == "effort":
                return None
            return (f"command_interface = {interface!r}: the session runs the bare model (no actuator), "
                    "which takes effort only")
        try:
            state = act.set_mode(self.simulator.state, interface)
        except PrsmError as e:
            return str(e)
        if interface != self.gate.interface:  # a switch to a loop that does not settle at the loop rate says so
            _warn_if_ringing(act, interface)
        meas = act.measured(self._last) if self._last is not None else None
        present = {"effort": 0.0,
                   "velocity": meas.screw_speed_rad_s if meas else 0.0,
                   "position": meas.nut_position_m if meas else self.nut_position_m}[interface]
        self.simulator.state = state
        self.gate.set_interface(interface, present)
        return None

    # -- the actuator's other inputs ----------------------------------------------------------
    def brake(self, engage: bool) -> str | None:
        """Engage or release the holding brake; the reason it was refused, or None."""
        return self._change_actuator(lambda act, s: act.command_brake(s, engage),
                                     "brake command refused: no actuator, so no brake fitted")

    def inject(self, fault: Fault) -> str | None:
        """Add a fault (start in absolute simulation time); the reason it was refused, or None."""
        return self._change_actuator(lambda act, s: act.inject(s, fault),
                                     "fault refused: no actuator (the bare model has no faults to inject)")

    def _change_actuator(self, change, no_actuator: str) -> str | None:
        """Apply `change(actuator, state) -> state`; the refusal (no actuator, or the actuator's
        one-line PrsmError) or None. The state is unchanged when refused."""
        act = self.actuator
        if act is None:
            return no_actuator
        try:
            self.simulator.state = change(act, self.simulator.state)
        except PrsmError as e:
            return str(e)
        return None

    def clear_faults(self) -> int:
        """End the runtime faults now; returns how many were active or pending."""
        act = self.actuator
        if act is None:
            return 0
        s = self.simulator.state
        n = sum(1 for f in s.faults if f.end_s > s.time_s)
        self.simulator.state = act.clear_faults(s)
        return n

    def take_events(self) -> list:
        """The fault events (`FaultEvent`: starts and clears) since the last call."""
        ev, self._events = self._events, []
        return ev

    @property
    def pending_events(self) -> bool:
        """Fault events wait to be taken."""
        return bool(self._events)

    @property
    def pending_edge_events(self) -> bool:
        """Thread-end events wait to be taken (`take_edge_events`)."""
        return bool(self._edge_events)

    # -- run control ------------------------------------------------------------------------
    @property
    def paused(self) -> bool:
        """Paused: the transport steps only on request (`step` itself does not look at it)."""
        return self._paused

    def pause(self) -> None:
        self._paused = True

    def resume(self) -> None:
        self._paused = False

    def reset(self, nut_position_m: float | None = None) -> None:
        """Back to time zero at rest (at `nut_position_m`, kept for later resets); clears the fault,
        the command, the gate's counters and the events, and returns the load to `initial_load_n`
        (when given). The interface and the pause state stay."""
        if nut_position_m is not None:
            if not is_finite_number(nut_position_m):
                raise InputError(f"nut_position_m = {nut_position_m!r}: must be a finite number (m)")
            self.nut_position_m = float(nut_position_m)
        mode = self.gate.interface
        self.simulator.reset(self.nut_position_m, initial_load_n=self.initial_load_n)
        self.gate.reset(self.nut_position_m)
        if self.actuator is not None:
            self.simulator.state = self.actuator.set_mode(self.simulator.state, mode)
        if self.initial_load_n is not None:
            self.load_n = self.initial_load_n
        self.fault = None
        self._last = None
        self._events = []
        self._at_thread_end = False
        self._edge_events = []
        self._over_rating = False

    def rebuild(self, params: Params) -> None:
        """New parameters for the same model, keeping the state and the step count (a runtime change)."""
        sim = Simulator(params, self.model_name, self.simulator.dt_s, self.nut_position_m,
                        actuator=_drive_in(self.actuator_params, self.gate.interface), kernel=self.kernel,
                        initial_load_n=self.initial_load_n)
        sim.restore(self.simulator.state, self.simulator.nstep)
        self.simulator = sim
        self._screw_model = None

    # -- what it says -------------------------------------------------------------------------
    def rest_outputs(self) -> Outputs:
        """Outputs for the current state as it stands, no step taken (after `reset`, at rest).

        Speeds and positions come from the state; the torque is the gate's command, the nut force
        the load (nothing accelerates before a step), no power flows and the internal loads are
        zero, except, with an actuator, what the sensors last measured (its `measured` block), so
        a measured joint state can be read from it as from a step's outputs.
        """
        sim, act = self.simulator, self.actuator
        s = sim.state
        screw = s.screw if isinstance(s, ActuatorState) else s
        out = _rest_model(self).rest_outputs(screw, self.gate.command_nm, self.load_n)
        if act is None:
            return out
        internal = np.zeros(sim.layout.size)
        sim.layout.view(internal, "measured")[:] = s.measured
        return replace(out, internal=internal)

    # -- save and restore -------------------------------------------------------------------
    def get_state(self) -> dict:
        """Everything that decides the next steps, as plain data (`json.dumps` writes it): the
        simulator's state (model, actuator, faults, brake, sensors), the gate and its watchdog, the
        load, pause, fault, the last outputs and the events not yet taken. `set_state` on a
        session built with the same arguments continues bit for bit, in this process or another."""
        return {"format": STATE_FORMAT, "model": self.model_name, "dt_s": self.simulator.dt_s,
                "actuator": self.actuator is not None, "simulator": self.simulator.get_state(),
                "gate": to_plain(vars(self.gate), "gate"),
                "session": to_plain({k: getattr(self, k) for k in _RUN_FIELDS}, "session")}

    def set_state(self, data: dict) -> None:
        """Continue from `get_state`'s data, all or nothing: the whole of it is checked before anything
        changes. InputError (one line naming the field, nothing changed) for data of another format,
        model, step or actuator fitting, data `get_state` did not write, values of the wrong type,
        non-finite loads or positions, or a nut position off the threads."""
        if not isinstance(data, dict) or data.get("format") != STATE_FORMAT:
            raise InputError(f"state format = {data.get('format') if isinstance(data, dict) else data!r}: "
                             f"expected {STATE_FORMAT!r} (a Session.get_state result)")
        mine = {"model": self.model_name, "dt_s": self.simulator.dt_s, "actuator": self.actuator is not None}
        for k, v in mine.items():
            if data.get(k) != v:
                raise InputError(f"state {k} = {data.get(k)!r}: this session has {k} = {v!r}; build it with "
                                 "the arguments of the session that saved the state")
        types = reachable_types(self.simulator.state, Outputs, FaultEvent, GateCounters, ThreadEndEvent,
                                RatingEvent)
        gate, run = from_plain(data.get("gate"), types, "gate"), from_plain(data.get("session"), types, "session")
        if not (isinstance(gate, dict) and gate.keys() == vars(self.gate).keys()
                and isinstance(run, dict) and run.keys() == set(_RUN_FIELDS)):
            raise InputError("state: the gate or session entries do not match this version's (save and restore "
                             "with the same prsm version)")
        _check_gate(gate)
        _check_run(run, self.simulator)
        sim = self.simulator.read_state(data.get("simulator"))
        # everything checked: from here on nothing can fail
        self.simulator.apply_state(sim)
        vars(self.gate).update(gate)
        for k, v in run.items():
            setattr(self, k, v)


    def status(self) -> dict:
        """The session as plain data (numbers, strings, lists, dicts): time, run state, command,
        watchdog and counters, load, energy books of the last step, and with an actuator its brake,
        current and active faults."""
        gate, t = self.gate, self.simulator.time_s
        age = gate.command_age_s(t)
        c = gate.counters
        d: dict = {
            "time_s": t, "nstep": self.simulator.nstep, "model": self.model_name, "paused": self._paused,
            "fault": self.fault, "command_interface": gate.interface, "command": gate.value,
            "command_nm": gate.command_nm, "command_age_s": None if math.isinf(age) else age,
            "timed_out": gate.timed_out, "timeout_behaviour": gate.timeout_behaviour,
            "cmd_timeout_s": gate.cmd_timeout_s, "load_n": self.load_n,
            "counters": {"received": c.received, "accepted": c.accepted, "rejected_non_finite": c.rejected_non_finite,
                         "rejected_malformed": c.rejected_malformed,
                         "rejected_inactive_interface": c.rejected_inactive_interface, "saturated": c.saturated, "timeouts": c.timeouts},
        }
        last = self._last
        d["energy"] = None if last is None else {"residual_j": last.energy_residual_j, "flow_j": last.energy_flow_j,
                                                 "fault": bool(last.energy_fault)}
        act = self.actuator
        if act is None:
            d["actuator"] = None
        else:
            a = self.simulator.state
            d["actuator"] = {"brake_engaged": a.brake_engaged, "brake_level": a.brake_level,
                             "motor_current_a": a.current_a, "torque_limited": a.limited,
                             "faults_active": [f.describe() for f in act.all_faults(a) if f.active(a.time_s)]}
        return d


def _rest_model(session: Session):
    """The screw model whose state `Session.rest_outputs` describes (an actuator's is built once, on first use)."""
    act = session.actuator
    if act is None:
        return session.simulator.model
    if session._screw_model is None:
        session._screw_model = build_model(act.screw_params, session.model_name, act.h_sub, session.kernel)
    return session._screw_model


def _check_gate(gate: dict) -> None:
    """InputError naming the field unless `gate` holds what `Session.get_state` writes for a gate: the
    limits and the interface as when built, the command a finite number, the counters whole numbers."""
    try:
        CommandGate(gate["max_effort_nm"], gate["cmd_timeout_s"], gate["timeout_behaviour"], gate["interface"])
    except ParamError as e:
        raise InputError(f"state gate: {e}") from None
    for k, hint in _GATE_TYPES.items():
        check_typed(gate[k], hint, f"state gate.{k}")
    if not math.isfinite(gate["value"]):
        raise InputError(f"state gate.value = {gate['value']!r}: must be a finite number")


def _check_run(run: dict, simulator: Simulator) -> None:
    """InputError naming the field unless `run` holds what `Session.get_state` writes for a session
    around `simulator`: values of their types, finite loads and a start position on the threads."""
    for k, hint in _RUN_TYPES.items():
        check_typed(run[k], hint, f"state session.{k}")
    for k in ("nut_position_m", "load_n", "initial_load_n"):
        v = run[k]
        if v is not None and not math.isfinite(v):
            raise InputError(f"state session.{k} = {v!r}: must be a finite number")
    simulator.check_on_threads(run["nut_position_m"], "state session.nut_position_m")
