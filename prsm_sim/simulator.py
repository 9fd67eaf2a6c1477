"""`Simulator`: a model, its state and its counters behind one fixed-step interface.

    sim = Simulator(preset("jones2016"), "jones2016", dt_s=1e-3)
    out = sim.step(0.1, load_n=100.0)                 # → Outputs (the screw torque, N·m, held over the step)
    traj = sim.run(torque_array, load_array)          # → Trajectory (columns)

The models themselves are pure (state in, state out); this wrapper only holds the current
state and counts steps, so a node or a CLI can drive it without bookkeeping of its own.
"""

from __future__ import annotations

import math
import sys
import warnings
from dataclasses import fields
from typing import Any, NamedTuple

import numpy as np

from prsm_sim.actuator import Actuator
from prsm_sim.actuator.stops import Limit, limits_of
from prsm_sim.checks import check_typed, is_finite_number, is_number
from prsm_sim.end_steps import EndSteps, non_finite_error
from prsm_sim.errors import InputError
from prsm_sim.models.registry import MODELS, build_model  # noqa: F401  # MODELS: importable from here too
from prsm_sim.params import Params
from prsm_sim.plain import from_plain, reachable_types, to_plain
from prsm_sim.stepping.model import check_step_inputs
from prsm_sim.stepping.packed import NUT_POSITION_ITEM, PACKED_STATE_SIZE
from prsm_sim.stepping.records import InternalLayout, Outputs, State
from prsm_sim.stepping.trajectory import Trajectory, trajectory_from_rows

_RESIDUAL_ITEM = 9  # the packed state's energy residual (`Model.pack_state`)
_PART_ITEM = PACKED_STATE_SIZE - 1  # ... and the model's part, in the form its step holds it (`Model.packed_part`)


# the state-carrying columns of a run (with the nut force): efficiency and speed_ratio may be NaN by design
_STATE_COLUMNS = ("screw_angle_rad", "screw_speed_rad_s", "carrier_angle_rad", "carrier_speed_rad_s")


def _check_state(state, kind: type, path: str) -> None:
    """InputError naming the field unless `state` holds what its annotations say, with a finite screw state."""
    check_typed(state, kind, path)
    screw = getattr(state, "screw", state)
    for f in fields(screw):
        if f.name != "part" and not math.isfinite(getattr(screw, f.name)):
            raise InputError(f"{path}.{f.name} = {getattr(screw, f.name)!r}: must be a finite number")


class RatingEvent(NamedTuple):
    """The nut load went past the static load rating C₀a, or back within it, at the end of the step ending at `time_s`."""

    time_s: float
    what: str  # "exceeded" or "within"
    force_n: float  # the nut load then, N
    rating_n: float  # the static load rating C₀a, N

    @property
    def event_name(self) -> str:
        return f"static_rating_{self.what}"

    def describe(self) -> str:
        if self.what == "exceeded":
            return (f"the nut load {self.force_n:.6g} N exceeds the static load rating {self.rating_n:.6g} N: "
                    "past it the threads deform permanently (ISO 76)")
        return f"the nut load is back within the static load rating {self.rating_n:.6g} N"


class Simulator:
    """A model with its current state and step counter: the object a script or a node drives.

    Parameters
    ----------
    params : Params
        A validated parameter set (`preset` or `Params.from_dict`).
    model : str, default "jones2016"
        Model name, one of `MODELS` (see `build_model`).
    dt_s : float, default 1e-3
        Fixed step, s. Inputs are held constant over each step (zero-order hold).
    nut_position_m : float, default 0.0
        Initial nut position x_nut, m (the screw angle follows from x_nut = (L/2π) θ_S).
    kernel : {"compiled", "reference"}, default "compiled"
        Compiled (numba) or pure-Python step for ``fu2018`` and ``elastic`` (see `build_model`).
    initial_load_n : float, optional
        Start in equilibrium under this nut load, N: ``elastic``'s chain deflected to carry it,
        ``fu2018``'s friction state at it, an actuator's drive holding it in velocity and position
        mode (`Model.initial_state`); resets return to it. None: at rest and unloaded.

    Thread ends (`Geometry.thread_ends`, on by default): the nut stays within
    ±(screw_length_m − nut_length_m)/2; a bare model is held there by the stop law in `step` and
    `run` (`thread_end_force_n` is the end's force over the last step, N along +x_nut, 0 off the
    ends); an actuator holds them with its stops.

    Attributes
    ----------
    model : Model
        The pure model (state in, state out).
    params : Params
        The parameter set the model was built from.
    dt_s : float
        The fixed step, s.
    state : State
        The current state (angles rad, speeds rad/s, energy ledger J).
    nstep : int
        Steps taken since construction or the last `reset`.

    Examples
    --------
    >>> from prsm_sim import Simulator, preset
    >>> sim = Simulator(preset("jones2016"), "jones2016", dt_s=1e-3)
    >>> out = sim.step(0.0922, load_n=100.0)
    >>> traj = sim.run([0.0922] * 500, load_n=100.0)
    >>> len(traj), sim.nstep
    (500, 501)
    """

    _packed: Any  # the packed record of the state (packed models) or None
    _state_of: Any  # the packed record `_state` was unpacked from
    _step_packed: Any  # the model's packed step (packed models) or None
    _before: Any  # the state before the last step (for `undo`) or None

    def __init__(self, params: Params, model: str = "jones2016", dt_s: float = 1e-3,
                 nut_position_m: float = 0.0, actuator=None, kernel: str = "compiled", *,
                 initial_load_n: float | None = None) -> None:
        if actuator is None:
            self.model = build_model(params, model, dt_s, kernel)
        else:  # the actuator around the screw (prsm_sim.actuator): `step`'s first input is then its command
            self.model = Actuator(params, dt_s, model, actuator, kernel)
        self.command_name = self.model.command_name  # what `step`'s first input is (torque_nm, or an actuator's command)
        self.params = params
        self.dt_s = self.model.dt_s
        # thread ends: the actuator holds them itself (with its stops); a bare model here
        travel = params.geometry.travel_m
        self._limits = () if actuator is not None or travel is None else \
            limits_of(None, travel, params.geometry.nut_length_m)
        # without ends the bounds are the float range: `step` still sends an infinite or NaN nut to `_at_end`
        self._lo, self._hi = (-0.5 * travel, 0.5 * travel) if self._limits and travel is not None else \
            (-sys.float_info.max, sys.float_info.max)
        self._ends = EndSteps(self.model, params, self._limits, self._lo, self._hi, kernel)
        self._end_step = -1  # the step `_ends.force_n` belongs to
        # the static load rating C₀a (ISO 76's permanent-deformation limit, `Ratings`): a load past it is said once
        c0 = params.ratings.static_load_rating_n
        self._static_rating_n = math.inf if c0 is None else float(c0)
        self._over_step, self._over_warned = -1, False
        self.check_on_threads(nut_position_m)
        if initial_load_n is not None and not is_finite_number(initial_load_n):
            raise InputError(f"initial_load_n = {initial_load_n!r}: must be a finite number (N) or None")
        self._initial_nut_position_m = float(nut_position_m)
        self._initial_load_n = 0.0 if initial_load_n is None else float(initial_load_n)
        self.state = self.model.initial_state(nut_position_m, self._initial_load_n)
        self.nstep = 0

    def __repr__(self) -> str:
        return (f"Simulator(model={self.model.name!r}, params={self.params.name!r}, dt_s={self.dt_s:g}, "
                f"time_s={self.time_s:.6g}, nstep={self.nstep})")

    # The current state is a `State`, or for models with a packed step (Model.step_packed) the
    # packed record of the last step (or `Model.pack_state`'s tuple), turned into a `State` only
    # when someone reads it (`_state` caches the `State` of `_state_of`).
    @property
    def state(self) -> Any:  # a `State`, or with an actuator its `ActuatorState`
        x = self._packed
        if x is not None and x is not self._state_of:
            self._state, self._state_of = self.model.unpack_state(x), x
        return self._state

    @state.setter
    def state(self, value: Any) -> None:
        self._state = value
        self._packed = self._state_of = self.model.pack_state(value) if self.model.packed else None
        self._step_packed = self.model.step_packed if self.model.packed else None
        self._before = None  # the state (packed record or State) before the last step, for `undo`

    def __getstate__(self) -> dict:  # pickled with its state as a `State` (the packed record holds closures)
        d = {k: v for k, v in self.__dict__.items()
             if k not in ("_state", "_packed", "_state_of", "_step_packed", "_before")}
        d["state"] = self.state
        return d

    def __setstate__(self, d: dict) -> None:
        state = d.pop("state")
        self.__dict__.update(d)
        self.state = state

    @property
    def layout(self) -> InternalLayout:
        """Labels of the model's internal-load vector (`Outputs.internal`, `Trajectory.internal`)."""
        return self.model.layout

    @property
    def time_s(self) -> float:
        """Simulation time of the current state, s."""
        x = self._packed
        return x[0] if x is not None else self._state.time_s

    def reset(self, nut_position_m: float | None = None, *, initial_load_n: float | None = None) -> State:
        """Back to rest at the initial (or the given) nut position, time zero, counters cleared.

        Parameters
        ----------
        nut_position_m : float, optional
            New initial nut position, m; kept for later resets.
        initial_load_n : float, optional
            New load to start in equilibrium under, N; kept for later resets.

        Returns
        -------
        State
            The new current state.
        """
        if nut_position_m is not None:
            self.check_on_threads(nut_position_m)
            self._initial_nut_position_m = float(nut_position_m)
        if initial_load_n is not None:
            if not is_finite_number(initial_load_n):
                raise InputError(f"initial_load_n = {initial_load_n!r}: must be a finite number (N)")
            self._initial_load_n = float(initial_load_n)
        self.state = self.model.initial_state(self._initial_nut_position_m, self._initial_load_n)
        self._end_step = -1
        self.nstep = 0
        return self.state

    def restore(self, state: State, nstep: int) -> None:
        """Continue from `state`, reached after `nstep` steps (undo a step, or carry a run over to
        a simulator with new parameters).

        Parameters
        ----------
        state : State
            The state to continue from, kept as given.
        nstep : int
            Steps taken to reach it (>= 0).
        """
        if not isinstance(state, type(self.state)):  # State, or the actuator's ActuatorState
            raise InputError(f"state = {state!r}: must be a prsm_sim {type(self.state).__name__}")
        if not isinstance(nstep, (int, np.integer)) or isinstance(nstep, bool) or nstep < 0:
            raise InputError(f"nstep = {nstep!r}: must be a whole number >= 0")
        self.state = state
        self.nstep = int(nstep)

    def get_state(self) -> dict:
        """Everything that decides the next steps as plain data (`prsm_sim.plain`: json.dumps writes it)."""
        x = self._packed
        return to_plain({"nstep": self.nstep, "nut_position_m": self._initial_nut_position_m,
                         "initial_load_n": self._initial_load_n, "state": self.state,
                         "packed": None if x is None else x[:_PART_ITEM] + (self.model.state_part(x[_PART_ITEM]),)})

    def set_state(self, data: dict) -> None:
        """Continue from `get_state`'s data, bit for bit (also in another process, same parameters).
        InputError (one line naming the field, nothing changed) for data `get_state` could not have written."""
        self.apply_state(self.read_state(data))

    def read_state(self, data: Any) -> dict:
        """`get_state`'s data checked whole and rebuilt (nothing changed): for `apply_state`. InputError
        naming the field for a value of the wrong type, a non-finite screw state or load, or a start
        position off the threads."""
        d = from_plain(data, reachable_types(self.state), "state")
        if not (isinstance(d, dict) and {"nstep", "nut_position_m", "state", "packed"} <= d.keys()):
            raise InputError("state: not a Simulator.get_state result (nstep, nut_position_m, state, packed)")
        packed = d["packed"]
        if packed is not None:
            if not (self.model.packed and type(packed) is tuple and len(packed) == PACKED_STATE_SIZE
                    and all(is_number(v) for v in packed[:PACKED_STATE_SIZE - 1])):
                raise InputError(f"state.packed: a packed record of {PACKED_STATE_SIZE} items for a packed model "
                                 "expected")
            _check_state(self.model.unpack_state(packed), State, "state.packed")
        state = d["state"]
        if not isinstance(state, type(self.state)):  # State, or the actuator's ActuatorState
            raise InputError(f"state.state = {type(state).__name__}: must be a prsm_sim {type(self.state).__name__}")
        _check_state(state, type(state), "state.state")
        nstep = d["nstep"]
        if not isinstance(nstep, int) or isinstance(nstep, bool) or nstep < 0:
            raise InputError(f"state.nstep = {nstep!r}: must be a whole number >= 0")
        self.check_on_threads(d["nut_position_m"], "state.nut_position_m")
        load = d.get("initial_load_n", 0.0)
        if not is_finite_number(load):
            raise InputError(f"state.initial_load_n = {load!r}: must be a finite number (N)")
        return {**d, "nut_position_m": float(d["nut_position_m"]), "initial_load_n": float(load)}

    def apply_state(self, d: dict) -> None:
        """Continue from `read_state`'s result (cannot fail)."""
        self.restore(d["state"], d["nstep"])
        self._initial_nut_position_m = d["nut_position_m"]
        self._initial_load_n = d["initial_load_n"]
        packed = d["packed"]
        if packed is not None:  # the packed record as it was (its stored energy is not recomputed)
            m, part = self.model, packed[_PART_ITEM]
            if m.part_type is not None:  # the part in the form the model's packed step holds it
                part = m.packed_part(m.part_type._make(m.state_part(part)))
            self._packed = self._state_of = packed[:_PART_ITEM] + (part,)

    def step(self, command: float | None = None, load_n: float = 0.0, *, torque_nm: float | None = None) -> Outputs:
        """Advance one step with the command and the nut load held over it.

        Parameters
        ----------
        command : float
            A bare model: the screw torque, N·m, positive right-handed about +z (drives the nut
            toward +x_nut). With an actuator fitted: its command in the active interface's unit
            (effort N·m, velocity screw rad/s, position nut m).
        load_n : float, default 0.0
            Nut load force, N, positive when it resists positive nut motion.
        torque_nm : float, optional
            The former name of `command`, accepted for one release (DeprecationWarning).

        Returns
        -------
        Outputs
            The step's outputs at its end (powers and efficiency are step averages).

        Raises
        ------
        InputError
            A missing, non-finite or non-numeric input; the state is left unchanged.
        NonFiniteStateError
            The step left the nut's position non-finite (a `ModelError`); the state is left
            unchanged. `Session.step` checks every state-carrying output.
        """
        if torque_nm is not None:
            command = self._deprecated_torque_nm(command, torque_nm)
        # `check_step_inputs`' test for the common case, here to save the call on the node's path
        if not (type(command) is float and type(load_n) is float and (command + load_n) * 0.0 == 0.0):
            command, load_n = check_step_inputs(command, load_n, self.command_name)
        if not -self._static_rating_n <= load_n <= self._static_rating_n:
            self._over_rating(load_n)
        x = self._packed
        if x is not None:  # the record is the outputs and the next packed state
            out = self._step_packed(x, command, load_n)
            xn = out[NUT_POSITION_ITEM]  # the item, not the property: read on every step
            if not self._lo <= xn <= self._hi:  # the free step ran past a thread end, or is not finite
                out = self._at_end_packed(x, out, command, load_n)
                self._judge_rating(out.load_force_n)
            if out[_RESIDUAL_ITEM] * 0.0 != 0.0:  # the ledger overflowed (a finite nut, an infinite energy)
                self._non_finite(self.time_s + self.dt_s)
            self._packed = out
            self._before = x
        else:
            s0 = self._state
            new, out = self.model.step(s0, command, load_n)
            xn = out.nut_position_m
            if not self._lo <= xn <= self._hi:
                new, out = self._at_end_state(s0, (new, out), command, load_n)
            self._judge_rating(out.load_force_n)  # an end's or an actuator's stop's force joins the load
            if out.energy_residual_j * 0.0 != 0.0:
                self._non_finite(self.time_s + self.dt_s)
            self._state = new
            self._before = s0
        self.nstep += 1
        return out

    def undo(self) -> None:
        """Back to the state before the last `step` (once; a session keeps its last finite state so).

        Raises
        ------
        InputError
            No step to undo: none since construction, a reset, a state change or the last `undo`.
        """
        before = self._before
        if before is None:
            raise InputError("undo: no step to undo since the state was last set")
        if self._packed is not None:
            self._packed = before
        else:
            self._state = before
        self._before = None
        self.nstep -= 1

    def check_on_threads(self, nut_position_m, name: str = "nut_position_m") -> None:
        """InputError naming `name` unless `nut_position_m` is a finite number on the threads, m."""
        if not is_finite_number(nut_position_m):
            raise InputError(f"{name} = {nut_position_m!r}: must be a finite number (m)")
        travel = self.params.geometry.travel_m
        if travel is not None and abs(nut_position_m) > 0.5 * travel:
            raise InputError(f"{name} = {nut_position_m!r}: must lie on the threads, |x| <= "
                             f"{0.5 * travel:g} m ((screw_length_m - nut_length_m)/2; geometry.thread_ends = false "
                             f"removes the ends)")

    # The two paths' thread-end steps are methods of their own: a lambda inside `step` would make its
    # locals closure cells, which every step pays for (about 3 % of a linear model's step).
    def _at_end_packed(self, x, free, command, load_n):
        out = self._ends.packed(x, free, command, load_n, self.time_s + self.dt_s)
        self._end_step = self.nstep + 1  # `thread_end_force_n`: this step's (nstep counts it next)
        return out

    def _at_end_state(self, s0, free, command, load_n):
        m = self.model
        out = self._ends.solve(m, s0, free, lambda f: m.step(s0, command, load_n - f), lambda r: r[1].nut_position_m,
                               lambda r: r[0].screw_speed_rad_s, self.time_s + self.dt_s)
        self._end_step = self.nstep + 1
        return out

    @property
    def limits(self) -> tuple[Limit, ...]:
        """The stops the nut is held within (`actuator.stops.Limit`, innermost on each side): an
        actuator's end stops and thread ends, or the thread ends this simulator holds a bare model at;
        empty when none are fitted."""
        model = self.model
        return model.limits if isinstance(model, Actuator) else self._limits

    def _judge_rating(self, nut_load_n: float) -> None:
        """This step's `over_static_rating` from the nut's load as the output reports it (an end's or stop's
        force included), where that differs from the load `step` judged: flagged past the rating, cleared
        where the end took back a load that alone was past it."""
        if not -self._static_rating_n <= nut_load_n <= self._static_rating_n:
            self._over_rating(nut_load_n, stacklevel=4)  # the warning points at the caller of `step`
        elif self._over_step == self.nstep + 1:
            self._over_step = -1

    def _over_rating(self, load_n: float, stacklevel: int = 3) -> None:
        """Flag a step whose nut load exceeds the static rating (`over_static_rating`); said once per simulator,
        the warning at `stacklevel` (the caller of `step` or `run`)."""
        self._over_step = self.nstep + 1
        if not self._over_warned:
            self._over_warned = True
            warnings.warn(f"the nut load {load_n:g} N exceeds the static load rating ratings.static_load_rating_n = "
                          f"{self._static_rating_n:g} N at t = {self.time_s:.6f} s: past it the threads deform "
                          "permanently (ISO 76), which no model here represents", stacklevel=stacklevel)

    @property
    def over_static_rating(self) -> float:
        """1.0 while the last step's nut load exceeded the static load rating C₀a, else 0.0."""
        return 1.0 if self._over_step == self.nstep else 0.0

    @property
    def thread_end_force_n(self) -> float:
        """The thread end's force on the nut over the last step, N along +x_nut (0: off the ends)."""
        return self._ends.force_n if self._end_step == self.nstep else 0.0

    def _deprecated_torque_nm(self, command, torque_nm):
        if command is not None:
            raise InputError(f"command = {command!r}, torque_nm = {torque_nm!r}: give one of them (torque_nm is "
                             f"the former name of command)")
        warnings.warn("Simulator.step(torque_nm=...) is deprecated: pass the command first, step(command, load_n)",
                      DeprecationWarning, stacklevel=3)
        return torque_nm

    def _check_finite_run(self, traj: Trajectory) -> None:
        """NonFiniteStateError at the first row whose state-carrying columns are not all finite."""
        cols = traj.columns
        bad = ~np.isfinite(cols["nut_force_n"]) | ~np.isfinite(cols["energy_residual_j"])
        for name in _STATE_COLUMNS:
            bad |= ~np.isfinite(cols[name])
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            self._non_finite(float(cols["time_s"][k]))

    def _non_finite(self, time_s: float):
        raise non_finite_error(self.model.name, time_s)

    def run(self, command, load_n=0.0) -> Trajectory:
        """Advance one step per element of `command` (the model's batch form where it has one).

        Parameters
        ----------
        command : array_like, shape (steps,)
            What `step` takes, one per step: the screw torque held over each step, N·m (with an
            actuator: its command). A scalar is refused: use `step` for one step, or
            ``np.full(steps, value)`` for a constant one.
        load_n : float or array_like, shape (steps,), default 0.0
            Nut load force, N (positive resists positive nut motion): one value for the whole
            run or one per step.

        Returns
        -------
        Trajectory
            Columns of every output, one row per step, plus the labelled internal loads.

        Raises
        ------
        InputError
            A scalar, empty or non-1-D command, a load of another length, values that are not
            finite real numbers; the state is left unchanged.
        NonFiniteStateError
            The run produced a non-finite state (a `ModelError`); the state is left unchanged.
        """
        traj = self.model.run(self.state, command, load_n)
        self._check_finite_run(traj)
        x = traj.columns["nut_position_m"]
        if len(x) and (x.min() < self._lo or x.max() > self._hi):
            # the run reaches a thread end: stepped instead, each step against the end as `step` takes it
            tau = np.asarray(command, dtype=float)
            rows = [self.step(float(t), float(f)) for t, f in zip(tau, np.broadcast_to(np.asarray(load_n, float),
                                                                                     tau.shape), strict=True)]
            return trajectory_from_rows(rows, self.layout, self.state)
        f = traj.columns["load_force_n"]
        over = np.flatnonzero(np.abs(f) > self._static_rating_n)
        if len(over):
            self._over_rating(float(f[over[0]]))
            self._over_step = self.nstep + len(traj) if over[-1] == len(traj) - 1 else -1
        self.state = traj.final_state
        self.nstep += len(traj)
        return traj
