"""The model contract: one public `step` and `run` every model shares, one private hook per model.

A model is built from parameters and a fixed step `dt_s`. ``step(state, command, load_n)`` checks
the inputs, advances one step with them held over it and returns the next state and the step's
outputs; it never mutates anything (the current state and the step counter live in `Simulator`).
``run(state, command, load_n)`` does the same over input arrays and returns a columnar `Trajectory`.
The public methods do what every model needs done once (input checks, the ledger, the records);
the model supplies only its physics through a private hook (SciPy's ``OdeSolver.step`` /
``_step_impl`` habit).

To write a model:

1. Subclass `Model`; set `name`, and in the constructor (after ``super().__init__``) `layout`
   (the internal-load vector's labels) and `kinetic` (the mass matrix in (ω_S, ω_C) the stored
   energy is computed with; a model with springs overrides `stored_energy_j` and
   `total_stored_energy_j`). Refuse parameters it cannot honour in `check_params` (one line,
   ParamError).
2. Memory of its own beyond angles, speeds and the ledger goes in `State.part`: a NamedTuple class
   as `part_type` (its defaults are the state at rest). Nothing else carries memory.
3. Implement `_make_step()`: it returns the step function
   ``step(x, command, load_n) -> PackedOutputs`` on the packed state x (`pack_state`), usually a
   closure over the model's constants. It computes the physics only and ends in the function
   `finisher` returns (the ledger, the guard, the nut's outputs); `Simulator` calls it directly.
   A model whose step takes its part in another form (a compiled kernel's floats and memory)
   overrides `packed_part` and `state_part`, so that the conversion runs when a state is packed or
   read, not in every step.
4. Optionally override `_run_impl` with a faster batch form ending in
   `stepping.trajectory.trajectory_from_columns` (the ledger's column form), and add it to the
   registry (`models.registry.MODELS`). tests/test_step_paths.py and tests/test_kernels.py hold the
   forms of a model together (1e-12).

A model that wraps others and has a state of its own (the actuator) overrides `_step_impl` instead.
"""

from __future__ import annotations

import copyreg
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from functools import cached_property
from typing import Any

import numpy as np

from prsm_sim.checks import is_finite_number, is_number
from prsm_sim.errors import InputError, ParamError
from prsm_sim.params import Params
from prsm_sim.stepping.ledger import energy_fault, over_static_rating
from prsm_sim.stepping.packed import PackedConstants, PackedOutputs, make_finisher
from prsm_sim.stepping.records import InternalLayout, Outputs, State
from prsm_sim.stepping.trajectory import Trajectory, trajectory_from_rows

def check_step_inputs(command, load_n, command_name: str = "torque_nm") -> tuple[float, float]:
    """The two inputs of a step as floats; InputError (naming the input) for a non-number or non-finite one."""
    if type(command) is float and type(load_n) is float and (command + load_n) * 0.0 == 0.0:
        return command, load_n  # (x + y) · 0 is 0 only for finite floats: one test for the common case
    for name, v in ((command_name, command), ("load_n", load_n)):
        if not is_finite_number(v):
            raise InputError(f"{name} = {v!r}: inputs must be finite numbers")
    return float(command), float(load_n)


def _real_array(name: str, value) -> np.ndarray:
    """`value` as a float array; InputError naming `name` for anything but real numbers (strings,
    complex numbers, booleans, or ints beyond the float range)."""
    arr = None
    try:
        raw = np.asarray(value)
        # Python numbers of mixed types are objects: converted as the numbers they are (an int too large raises)
        if raw.dtype.kind in "iuf" or (raw.dtype.kind == "O" and all(is_number(v) for v in raw.flat)):
            arr = np.asarray(raw, dtype=float)
    except (TypeError, ValueError, OverflowError):
        pass
    if arr is None:
        shown = repr(value)
        shown = shown if len(shown) <= 80 else shown[:77] + "..."
        raise InputError(f"{name} = {shown}: must be a number or an array of numbers (real; no strings, complex "
                         "numbers or booleans)")
    return arr


def input_columns(command, load_n, command_name: str = "torque_nm") -> tuple[np.ndarray, np.ndarray]:
    """The inputs of a batch run as two float arrays of one value per step, or InputError (one line).

    `command`: a 1-D array, one value per step (a scalar is refused: `step` takes one step);
    `load_n`: one value for the whole run or a 1-D array of the same length; all finite numbers.
    """
    u, f = (_real_array(name, value) for name, value in ((command_name, command), ("load_n", load_n)))
    if u.ndim == 1 and u.size == 0:
        raise InputError(f"{command_name} is empty: run() takes at least one step")
    if u.ndim != 1:
        got = f"{command_name} = {command!r}" if u.ndim == 0 else f"{command_name} has shape {u.shape}"
        what, unit = ("torque", " (N·m)") if command_name == "torque_nm" else ("command", "")
        raise InputError(f"{got}: run() takes a 1-D array with one {what} per step{unit}; use step() for one "
                         f"step, np.full(steps, {what}) for a constant {what}")
    if f.ndim > 1 or (f.ndim == 1 and f.shape != u.shape):
        raise InputError(f"load_n has shape {f.shape}: must be a number or a 1-D array of {len(u)} values, "
                         f"one per {'torque' if command_name == 'torque_nm' else 'command'}")
    f = np.broadcast_to(f, u.shape)
    for name, arr in ((command_name, u), ("load_n", f)):
        if not np.all(np.isfinite(arr)):
            k = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise InputError(f"{name}[{k}] = {arr[k]!r}: inputs must be finite numbers")
    return np.ascontiguousarray(u), np.ascontiguousarray(f)


class Model:
    """Base class of every model: the public `step` and `run`, the packed state, the stored energy."""

    name = "base"
    compiled_kernel = False  # True: the constructor takes kernel="compiled"|"reference" (`models.kernels`)
    # kinetic energy T = ½ (k_ss ω_S² + 2 k_sc ω_S ω_C + k_cc ω_C²): the model's mass matrix in
    # (ω_S, ω_C), set by every subclass; `stored_energy_j` uses it (models with springs add theirs)
    kinetic: tuple[float, float, float] = (math.nan, math.nan, math.nan)
    part_type: Any = None  # the NamedTuple class of the model's own memory in `State.part` (None: none)
    packed = True  # the model steps on the packed state (`step_packed`); the actuator does not
    command_name = "torque_nm"  # what the first input of a step is (a bare model: the screw torque, N·m)
    # -- capabilities: what callers ask of a model instead of comparing its name ------------------
    has_carrier = False  # the carrier (with the rollers) is a degree of freedom of its own, not tied at a ratio
    has_internal_forces = False  # the step reports internal loads (per roller/contact; `layout` labels them)
    has_friction_laws = False  # contact forces act through the selectable friction laws (`friction.*_law`)
    has_axial_chain = False  # the nut has its own axial DOF on a compliant screw–nut chain (preload, modes)
    takes_efficiencies = False  # its efficiencies are parameters, not the outcome of its friction (no calibration)

    steady_state_inputs: tuple[str, ...] = ("screw_speed_rad_s",)  # what may fix a steady state (speed; a torque)

    @classmethod
    def closed_form_steady_state(cls, params: Params, *, screw_speed_rad_s: float | None = None,
                                 torque_nm: float | None = None, load_n: float | None = None) -> dict | None:
        """The model's steady state in closed form (``method``, speeds, torque, load, efficiency), or None
        when the model has none (it is then found by simulation). Defaults: the preset's speed and load;
        a torque only where `steady_state_inputs` lists it."""
        return None

    @classmethod
    def check_params(cls, params: Params) -> None:
        """Refuse (ParamError, one line) a parameter combination this model cannot honour."""

    def __init__(self, params: Params, dt_s: float) -> None:
        if not (isinstance(dt_s, (int, float)) and math.isfinite(dt_s) and 0 < dt_s <= 0.1):
            raise ParamError(f"dt_s = {dt_s!r}: the step must be a finite number in (0, 0.1] s")
        self.params = params
        self.geo = params.geometry
        self.dt_s = float(dt_s)
        self.layout = InternalLayout(blocks=())

    def __reduce__(self):
        """A model is immutable: rebuilt from its parameters (its step function is a closure, its kernels a
        module); a model with a state of its own (the actuator) pickles its attributes as they are."""
        if not self.packed:
            return copyreg.__newobj__, (type(self),), self.__dict__
        kernel = (self.kernel,) if self.compiled_kernel else ()
        return (type(self), (self.params, self.dt_s, *kernel))

    @property
    def extra_state_fields(self) -> tuple[str, ...]:
        """Names of the model's own state fields (`part_type`'s)."""
        return self.part_type._fields if self.part_type is not None else ()

    def initial_state(self, nut_position_m: float = 0.0, load_n: float = 0.0) -> State:
        """At rest, nut at `nut_position_m` (x_nut = (L/2π) θ_S fixes the screw angle), in equilibrium
        under the nut load `load_n` (a rigid model has nothing to deflect; `fu2018` sets its friction
        state, `elastic` also pre-deflects its chain)."""
        return State(screw_angle_rad=nut_position_m / self.geo.lead_per_rad_m,
                     part=self.part_type() if self.part_type is not None else ())

    # -- one step -------------------------------------------------------------------------
    def step(self, state: State, command: float, load_n: float) -> tuple[State, Outputs]:
        """Advance one fixed step with the command (a bare model: the screw torque, N·m) and the nut
        load (N) held over it; returns the next state and the step's outputs. InputError for a
        non-finite or non-numeric input."""
        command, load_n = check_step_inputs(command, load_n, self.command_name)
        return self._step_impl(state, command, load_n)

    def _step_impl(self, state: State, command: float, load_n: float) -> tuple[State, Outputs]:
        rec = self.step_packed(self.pack_state(state), command, load_n)
        return self.unpack_state(rec), rec.to_outputs()

    def step_from(self, x: tuple, command: float, load_n: float) -> PackedOutputs:
        """`step` from the packed state `x` (`pack_state`), returning the packed record: its first
        PACKED_STATE_SIZE items are the next packed state (`unpack_state` makes the `State` `step` returns),
        and it reads as the `Outputs` `step` returns (`to_outputs` builds that record). For a caller that
        steps several times from one state and reads a few outputs of most of those steps (the actuator's
        implicit solves: a trial needs the end speed and angle, the accepted step everything), so the state
        is packed once and no full record is built for a trial. InputError as `step` for a bad input."""
        command, load_n = check_step_inputs(command, load_n, self.command_name)
        return self.step_packed(x, command, load_n)

    @cached_property
    def step_packed(self):
        """The model's step function on the packed state: ``step_packed(x, command, load_n) -> PackedOutputs``
        (`_make_step`; the record's first PACKED_STATE_SIZE items are the next packed state)."""
        return self._make_step()

    def _make_step(self):
        raise NotImplementedError

    def finisher(self, slip_speed, internal):
        """The ledger's per-step form for this model (`stepping.packed.make_finisher`), with the model's
        own slip speed and internal vector as functions of (ω_S, ω_C at the step's end, the step's aux)."""
        return make_finisher(self.packed_constants(slip_speed, internal), self.geo.lead_per_rad_m,
                             self.params.mass.moved_mass_kg)

    def packed_constants(self, slip_speed, internal) -> PackedConstants:
        """What this model's packed records derive their other outputs with (`finisher`'s arguments)."""
        return PackedConstants(self.dt_s, self.geo.gear_ratio, slip_speed, internal, self.static_rating_n)

    @cached_property
    def static_rating_n(self) -> float:
        """The static load rating C₀a the load is flagged against (`Outputs.over_static_rating`), N."""
        c0 = self.params.ratings.static_load_rating_n
        return math.inf if c0 is None else float(c0)

    # -- the packed state -------------------------------------------------------------------
    def pack_state(self, s: State) -> tuple:
        """(time, θ_S, ω_S, θ_C, ω_C, W_in, W_out, W_diss, energy flow, energy residual, stored energy, part)."""
        part = s.part
        if self.part_type is not None and not isinstance(part, self.part_type):
            part = self.part_type(*part) if part else self.part_type()
            s = replace(s, part=part)
        # floats here, once: a step takes them as they are (an int would make a compiled kernel specialise anew)
        return (*map(float, (s.time_s, s.screw_angle_rad, s.screw_speed_rad_s, s.carrier_angle_rad,
                             s.carrier_speed_rad_s, s.work_in_j, s.work_out_j, s.dissipated_j, s.energy_flow_j,
                             s.energy_residual_j, self.total_stored_energy_j(s))),
                self.packed_part(part) if self.part_type is not None else part)

    def unpack_state(self, x: tuple) -> State:
        part = x[11]
        if self.part_type is not None:
            part = self.part_type._make(self.state_part(part))
        return State(x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], x[8], x[9], part)

    def packed_part(self, part) -> tuple:
        """The model's part (a `part_type`) as its packed step holds it: converted here, once per state set,
        rather than in every step (a compiled kernel's memory as the kernel returns it). Default: as it is."""
        return part

    def state_part(self, packed: tuple) -> tuple:
        """`packed_part` undone: the fields of `part_type` in order (a tuple or the part itself)."""
        return packed

    # -- contact -----------------------------------------------------------------------------
    def set_contact(self, on: bool) -> None:
        """Whether the steps that follow are trials of an end's or stop's contact solve (`actuator.stops.solve`,
        on for its duration: `in_contact`) whose reversals are the contact's. A model whose step reflects the
        screw's speed off a contact it does not resolve takes its steps there in an L-stable form (`jones2016`
        every trial, `elastic` those that reverse the screw); the others ignore it."""

    @contextmanager
    def in_contact(self, free_reverses: bool = False) -> Iterator[None]:
        """`set_contact` on for the block (a contact solve's trials), off after it whatever ends the block; left off
        where the step without the contact's force already reverses the screw (`free_reverses`: a drive's torque
        turning it within the step). A reversal in the trials is then the drive's, not the contact's, and the
        L-stable form's first-order error over a long step (`elastic` at 83 ms: 87 mm, through the stop on
        the other side) is not the ring it is there to end."""
        on = not free_reverses
        self.set_contact(on)
        try:
            yield
        finally:
            if on:
                self.set_contact(False)

    # -- energy ------------------------------------------------------------------------------
    def stored_energy_j(self, screw_speed_rad_s, carrier_speed_rad_s):
        """Energy the model stores at these speeds, J (scalars or arrays): kinetic here; a model
        with potential energy overrides this (and must then be given the state it needs)."""
        kss, ksc, kcc = self.kinetic
        ws, wc = screw_speed_rad_s, carrier_speed_rad_s
        return 0.5 * (kss * ws * ws + 2.0 * ksc * ws * wc + kcc * wc * wc)

    def total_stored_energy_j(self, state: State) -> float:
        """Energy the model stores in `state`, J (`stored_energy_j` at its speeds; `elastic` adds the
        nut and the chain, which need more of the state)."""
        return self.stored_energy_j(state.screw_speed_rad_s, state.carrier_speed_rad_s)

    def rest_outputs(self, state: State, command: float = 0.0, load_n: float = 0.0) -> Outputs:
        """Outputs describing `state` as it stands, no step taken (after a reset, at rest): the command
        and load as given, the nut force the load (nothing accelerates before a step), no power,
        zero internal loads."""
        x = self.pack_state(state)
        zeros = np.zeros(self.layout.size)
        k = PackedConstants(self.dt_s, self.geo.gear_ratio, lambda w_s, w_c, aux: 0.0, lambda w_s, w_c, aux: zeros,
                            self.static_rating_n)
        nut_x, nut_v = self.nut_motion(state)
        fault = 1.0 if energy_fault(state.energy_flow_j, state.energy_residual_j) else 0.0
        return PackedOutputs(x + (float(command), float(load_n), 0.0, 0.0, 0.0, float(load_n), nut_x, nut_v, fault, k,
                                  None)).to_outputs()

    def nut_motion(self, state: State) -> tuple[float, float]:
        """The nut's position (m) and velocity (m/s) in `state`: x_nut = (L/2π) θ_S and its rate."""
        p = self.geo.lead_per_rad_m
        return p * state.screw_angle_rad, p * state.screw_speed_rad_s

    # -- a run -------------------------------------------------------------------------------
    def run(self, state: State, command, load_n) -> Trajectory:
        """Advance len(command) steps; input k is held over step k, output k is at its end.
        InputError for inputs that are not one finite number per step (the load may be one number)."""
        u, f = input_columns(command, load_n, self.command_name)
        traj = self._run_impl(state, u, f)
        # flagged here, once for every batch form (`trajectory_from_columns` knows no rating)
        traj.columns["over_static_rating"] = over_static_rating(traj.columns["load_force_n"], self.static_rating_n)
        return traj

    def _run_impl(self, state: State, command: np.ndarray, load_n: np.ndarray) -> Trajectory:
        """The step repeated; a model with a faster batch form overrides this."""
        if not self.packed:
            rows = []
            for u, f in zip(command.tolist(), load_n.tolist()):
                state, out = self._step_impl(state, u, f)
                rows.append(out)
            return trajectory_from_rows(rows, self.layout, state)
        step, x, records = self.step_packed, self.pack_state(state), []
        for u, f in zip(command.tolist(), load_n.tolist()):
            x = step(x, u, f)
            records.append(x)
        return trajectory_from_rows(records, self.layout, self.unpack_state(x))

