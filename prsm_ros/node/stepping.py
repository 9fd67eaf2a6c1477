"""The node's stepping and pacing logic, pure Python (no ROS), so it is tested without DDS.

- `SimStepper`: the simulator, its command gate, the load, pause and fault state. One `step()`
  asks the gate for the torque, steps the core, and stops for good (until `reset`) when the model
  produces a non-finite state: it never publishes garbage and never raises into the node.
- `DeadlinePacer`: realtime pacing on absolute deadlines t0 + k·period (no drift: lateness is
  never folded into the next period), with catch-up for late steps, a bound on how far it
  catches up, and the measured real-time factor and overruns.
- `every_n_steps`: publish decimation for a rate in Hz.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from prsm_sim import Outputs, Params, PrsmError, Simulator
from prsm_sim.actuator import Actuator, ActuatorParams, Fault
from prsm_sim.models.base import energy_fault
from prsm_sim.outputs import PackedOutputs

from prsm_ros.node.command_gate import CommandGate


def state_is_finite(out: Outputs) -> bool:
    """The state-carrying outputs are finite (efficiency and speed_ratio may be NaN by design).

    A `PackedOutputs` record's internal loads are derived when read, from its speeds (ideal,
    jones2016) or from the step's solved end forces, of which the nut force checked here is one
    (fu2018, elastic); building them every step just to check them would cost more than the step.
    """
    return all(math.isfinite(v) for v in (out.screw_angle_rad, out.screw_speed_rad_s, out.carrier_angle_rad,
                                          out.carrier_speed_rad_s, out.nut_force_n)) \
        and (type(out) is PackedOutputs or bool(np.all(np.isfinite(out.internal))))


class SimStepper:
    """Simulator (a bare model, or the actuator around it) + command gate + external load; `step()` once per step."""

    def __init__(self, params: Params, model: str, dt_s: float, gate: CommandGate, *,
                 nut_position_m: float = 0.0, load_n: float = 0.0, actuator: ActuatorParams | None = None) -> None:
        self.actuator_params = actuator
        self.sim = Simulator(params, model, dt_s, nut_position_m, actuator=actuator)
        self.nut_position_m = float(nut_position_m)
        self.model_name = model
        self.gate = gate
        self.load_n = float(load_n)
        self.paused = False
        self.fault: str | None = None
        self.last: Outputs | None = None
        self.events: list = []  # fault starts and clears (actuator.FaultEvent) since the node last took them

    @property
    def actuator(self) -> Actuator | None:
        """The actuator around the screw, or None when the node runs the bare model."""
        return self.sim.model if isinstance(self.sim.model, Actuator) else None

    @property
    def time_s(self) -> float:
        return self.sim.time_s

    @property
    def nstep(self) -> int:
        return self.sim.nstep

    def step(self) -> Outputs | None:
        """One step with the gated command; None (and nothing changed) once faulted."""
        if self.fault is not None:
            return None
        command = self.gate.command(self.sim.time_s)
        act = self.actuator
        if act is not None and self.gate.timed_out and act.actuator.brake.engage_on_watchdog \
                and act.actuator.brake.fitted and not self.sim.state.brake_engaged:
            self.sim.state = act.command_brake(self.sim.state, True)
        before = self.sim.state
        try:
            out = self.sim.step(command, self.load_n)
        except Exception as e:  # any model failure stops stepping; the node stays up for ~/reset
            self.fault = f"model {self.model_name} failed at t = {before.time_s:.6f} s: {type(e).__name__}: {e}"
            return None
        if not state_is_finite(out):
            self.sim.restore(before, self.sim.nstep - 1)  # keep the last finite state; reset clears the fault
            self.fault = (f"model {self.model_name} produced a non-finite state at t = {out.time_s:.6f} s "
                          f"(command {command:g} {self.gate.interface}, load {self.load_n:g} N); "
                          "stepping stopped, call ~/reset")
            return None
        if act is not None:
            self.events += act.events(before, self.sim.state)
        self.last = out
        return out

    # -- the actuator's inputs besides the command (the node's services and topics) ---------
    def set_interface(self, interface: str) -> str | None:
        """Switch the command interface; the command starts at the measured speed or position. The reason or None."""
        act = self.actuator
        if act is None:
            if interface == "effort":
                return None
            return (f"command_interface = {interface!r}: the node runs the bare model (parameter actuator is ''); "
                    "start it with an actuator (e.g. -p actuator:='{}') to use velocity or position")
        try:
            state = act.set_mode(self.sim.state, interface)
        except PrsmError as e:
            return str(e)
        meas = act.measured(self.last) if self.last is not None else None
        present = {"effort": 0.0,
                   "velocity": meas.screw_speed_rad_s if meas else 0.0,
                   "position": meas.nut_position_m if meas else self.nut_position_m}[interface]
        self.sim.state = state
        self.gate.set_interface(interface, present)
        return None

    def brake(self, engage: bool) -> str | None:
        """Engage or release the holding brake; the reason it was refused, or None."""
        return self._change_actuator(lambda act, s: act.command_brake(s, engage),
                                     "brake command refused: no actuator (parameter actuator is ''), so no brake fitted")

    def inject(self, fault: Fault) -> str | None:
        """Add a fault at runtime; the reason it was refused, or None."""
        return self._change_actuator(lambda act, s: act.inject(s, fault),
                                     "fault refused: no actuator (parameter actuator is ''); start the node with one")

    def _change_actuator(self, change, no_actuator: str) -> str | None:
        """Apply `change(actuator, state) -> state`; the refusal (no actuator, or the actuator's
        one-line PrsmError) or None. The state is unchanged when refused."""
        if self.actuator is None:
            return no_actuator
        try:
            self.sim.state = change(self.actuator, self.sim.state)
        except PrsmError as e:
            return str(e)
        return None

    def clear_faults(self) -> int:
        """End the runtime faults now; returns how many were active or pending."""
        act = self.actuator
        if act is None:
            return 0
        n = sum(1 for f in self.sim.state.faults if f.end_s > self.sim.time_s)
        self.sim.state = act.clear_faults(self.sim.state)
        return n

    def take_events(self) -> list:
        """The fault events since the last call (the node publishes and records them)."""
        ev, self.events = self.events, []
        return ev

    def reset(self, nut_position_m: float | None = None) -> None:
        """Back to time zero at rest; clears the fault, the command and the gate counters."""
        if nut_position_m is not None:
            self.nut_position_m = float(nut_position_m)
        mode = self.gate.interface
        self.sim.reset(self.nut_position_m)
        self.gate.reset(self.nut_position_m)
        if self.actuator is not None:
            self.sim.state = self.actuator.set_mode(self.sim.state, mode)
        self.fault = None
        self.last = None
        self.events = []

    def rebuild(self, params: Params) -> None:
        """New parameters for the same model, keeping the state and the step count (runtime change)."""
        sim = Simulator(params, self.model_name, self.sim.dt_s, self.nut_position_m, actuator=self.actuator_params)
        sim.restore(self.sim.state, self.sim.nstep)
        self.sim = sim


def rest_outputs(stepper: SimStepper) -> Outputs:
    """Outputs for the stepper's current state as it stands, no step taken (after `reset`, at rest).

    Speeds come from the state; the torque is the gate's command, the nut force the load (nothing
    accelerates before a step), no power flows and the internal loads are zero.
    """
    s, geo = stepper.sim.state, stepper.sim.params.geometry
    p = geo.lead_per_rad_m
    return Outputs(time_s=s.time_s, screw_angle_rad=s.screw_angle_rad, screw_speed_rad_s=s.screw_speed_rad_s,
                   screw_torque_nm=stepper.gate.command_nm, carrier_angle_rad=s.carrier_angle_rad,
                   carrier_speed_rad_s=s.carrier_speed_rad_s, roller_spin_rad_s=-geo.gear_ratio * s.carrier_speed_rad_s,
                   nut_position_m=p * s.screw_angle_rad, nut_velocity_m_s=p * s.screw_speed_rad_s,
                   nut_force_n=stepper.load_n, load_force_n=stepper.load_n, slip_speed_m_s=0.0, power_in_w=0.0,
                   power_out_w=0.0, power_dissipated_w=0.0, efficiency=math.nan, speed_ratio=math.nan,
                   stored_energy_j=stepper.sim.model.stored_energy_j(s.screw_speed_rad_s, s.carrier_speed_rad_s),
                   energy_flow_j=s.energy_flow_j, energy_residual_j=s.energy_residual_j,
                   energy_fault=1.0 if energy_fault(s.energy_flow_j, s.energy_residual_j) else 0.0,
                   internal=np.zeros(stepper.sim.layout.size))


def every_n_steps(rate_hz: float, update_rate_hz: float) -> int:
    """Publish every n-th step for `rate_hz` (0 or >= update rate: every step)."""
    if rate_hz <= 0 or rate_hz >= update_rate_hz:
        return 1
    return max(1, round(update_rate_hz / rate_hz))


@dataclass
class PacerStats:
    """Realtime pacing figures since start (or `DeadlinePacer.restart`)."""

    steps: int = 0
    overruns: int = 0  # steps that started more than one period after their deadline
    skipped_periods: int = 0  # periods dropped when too far behind to catch up
    lateness_s: list[float] = field(default_factory=list)  # per-step start − deadline (bounded ring)


class DeadlinePacer:
    """Absolute-deadline pacing: step k is due at t0 + k·period/rtf (wall clock, monotonic).

    `wait()` sleeps until the next deadline and returns; a late step is not waited for (catch-up),
    and when the loop falls more than `max_catchup_periods` behind it jumps the schedule forward
    (counting the skipped periods) instead of running a burst. Sleeping uses the monotonic clock
    with the thread's timer slack reduced to 1 µs (Linux prctl), so wake-ups are not rounded up by
    the default 50 µs slack.

    Thread safety: the step thread calls `wait`/`count_step` while the executor thread calls
    `restart` and `set_rate` (a reset, a parameter change), so the schedule and the counters are
    behind one lock, never held while sleeping. A restart during a sleep is seen on waking: the
    step then waits on the new schedule (so a rate change takes effect within one old period).
    Read the figures with `snapshot()`; `stats` is replaced on every restart.
    """

    def __init__(self, period_s: float, real_time_factor: float = 1.0, *, max_catchup_periods: int = 50,
                 clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep,
                 keep_lateness: int = 200_000, spin_s: float = 0.0) -> None:
        self.nominal_period_s = period_s
        self.spin_s = spin_s
        self.max_catchup_periods = max_catchup_periods
        self._clock, self._sleep = clock, sleep
        self._keep = keep_lateness
        self._lock = threading.Lock()
        self._generation = 0  # bumped by every restart: a wait() that slept across one re-plans
        self.set_rate(real_time_factor)

    def set_rate(self, real_time_factor: float) -> None:
        """Change the real-time factor; the schedule restarts from now so no burst or gap follows."""
        with self._lock:
            self.real_time_factor = real_time_factor
            self.period_s = self.nominal_period_s / real_time_factor
            self._restart_locked()

    def restart(self) -> None:
        """New schedule from now (after a pause, a reset or a rate change)."""
        with self._lock:
            self._restart_locked()

    def _restart_locked(self) -> None:
        self._t0 = self._clock()
        self._k = 0
        self._generation += 1
        self.stats = PacerStats()

    @property
    def next_deadline(self) -> float:
        with self._lock:
            return self._t0 + (self._k + 1) * self.period_s

    def wait(self) -> float:
        """Sleep until the next step is due; returns its lateness in seconds (>= 0 when on time)."""
        while True:
            with self._lock:
                generation, due = self._generation, self._t0 + (self._k + 1) * self.period_s
            now = self._clock()
            if due - self.spin_s > now:
                self._sleep(due - self.spin_s - now)
                now = self._clock()
            while now < due:  # the last spin_s: poll the clock instead of trusting the wake-up latency
                now = self._clock()
            with self._lock:
                if generation == self._generation:
                    return self._account_locked(now - due)
            # restarted (reset, new rate) while asleep: wait for the first deadline of the new schedule

    def _account_locked(self, late: float) -> float:
        period = self.period_s
        if late > self.max_catchup_periods * period:
            skip = int(late // period)
            self._k += skip
            self.stats.skipped_periods += skip
            late -= skip * period
        if late > period:
            self.stats.overruns += 1
        self._k += 1
        self.stats.steps += 1
        lat = self.stats.lateness_s
        if len(lat) >= self._keep:
            del lat[: self._keep // 2]
        lat.append(late)
        return late

    def count_step(self) -> int:
        """Count a step taken without pacing (fast mode); returns the steps since the last restart."""
        with self._lock:
            self.stats.steps += 1
            return self.stats.steps

    def snapshot(self, lateness: bool = False) -> PacerStats:
        """A consistent copy of the figures (the lateness ring only when asked: it can be long)."""
        with self._lock:
            s = self.stats
            return PacerStats(s.steps, s.overruns, s.skipped_periods, list(s.lateness_s) if lateness else [])

    def achieved_rtf(self, sim_dt_s: float) -> float:
        """Simulated time over wall time since the schedule started."""
        with self._lock:
            wall, steps = self._clock() - self._t0, self.stats.steps
        return steps * sim_dt_s / wall if wall > 0 else math.nan


def reduce_timer_slack() -> bool:
    """Set this thread's timer slack to 1 ns (Linux), so sleeps wake on time; False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_timerslack = 29
        return libc.prctl(pr_set_timerslack, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def request_realtime_priority(priority: int) -> str:
    """Put the calling thread under SCHED_FIFO at `priority` (Linux, needs CAP_SYS_NICE or an rtprio limit).

    A paced thread that sleeps most of each period loses little to this and gains on-time
    wake-ups when other processes keep the cores busy. Returns what was applied, in words.
    """
    if priority <= 0:
        return "normal (realtime_priority 0)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as e:
        return f"normal (SCHED_FIFO {priority} refused: {getattr(e, 'strerror', None) or e})"
    return f"SCHED_FIFO {priority}"
