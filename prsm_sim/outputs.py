"""What a model step returns: the state, the outputs, and the labelled internal loads.

Every model fills the same `Outputs` record, so the ROS node, the MCAP recorder and the
Rerun sink are written once for all models. Internal loads differ by model (the rigid
`jones2016` model has no normal forces; `fu2018` has per-tooth loads), so they travel as a
flat float vector with a model-specific `InternalLayout` that labels every element.

Sign convention (the one place it is stated; see README "Sign convention"):
right-hand threads, z along the screw axis. Screw angle, speed and torque are positive
right-handed about +z. The nut position `nut_position_m` is measured along the direction a
positive screw rotation drives the nut: x_nut = (L / 2π) θ_S (for right-hand threads this
is the −z direction of the body frame). The external load force `load_force_n` is positive
when it resists positive nut motion (a compressive working load on an extending actuator).
"""

from __future__ import annotations

import math
from abc import ABCMeta
from dataclasses import FrozenInstanceError, dataclass, fields
from operator import itemgetter

import numpy as np

from prsm_sim.errors import InputError


@dataclass(frozen=True, slots=True)
class State:
    """Generalised coordinates and velocities plus the energy ledger (pure data, frozen).

    A model step maps (State, inputs) to the next State; nothing else carries memory. The
    energy accumulators make the balance ``work_in_j = work_out_j + ΔT + dissipated_j``
    checkable over any run (docs/model.md §4, "The energy ledger"); `time_s` and the
    accumulators are filled by `Model.finish_step`.

    Attributes
    ----------
    time_s : float
        Simulation time, s.
    screw_angle_rad, screw_speed_rad_s : float
        Screw angle θ_S (rad) and speed ω_S (rad/s), right-handed about +z.
    carrier_angle_rad, carrier_speed_rad_s : float
        Carrier (roller orbit) angle θ_C (rad) and speed ω_C (rad/s); kinematic for `ideal`.
    work_in_j : float
        Work done by the screw torque since the start, J.
    work_out_j : float
        Work done on the nut load since the start, J (negative when the load drives the screw).
    dissipated_j : float
        Work dissipated by friction since the start, J.
    flank_sign : int
        `fu2018`: the loaded flank pair (+1: load resisting positive nut motion); lagged.
    pin_force_n, gear_force_n : float
        `fu2018`: |F_pin| and the gear's tangential force of the last step, N; they enter the
        friction laws lagged by one step (docs/model.md §4.2).
    solver : tuple of float
        Integrator memory (`fu2018`: its frozen Jacobian and its age), kept here so that a step
        stays a pure function of (state, inputs).
    """

    time_s: float = 0.0
    screw_angle_rad: float = 0.0
    screw_speed_rad_s: float = 0.0
    carrier_angle_rad: float = 0.0
    carrier_speed_rad_s: float = 0.0
    work_in_j: float = 0.0
    work_out_j: float = 0.0
    dissipated_j: float = 0.0
    # lagged algebraic quantities of `fu2018` (the loaded flank pair and the pin/gear forces
    # entering its friction laws); other models leave the defaults
    flank_sign: int = 1
    pin_force_n: float = 0.0
    gear_force_n: float = 0.0
    # integrator memory (fu2018: its frozen Jacobian and the steps since it was formed), kept in
    # the state so that a step stays a pure function of (state, inputs)
    solver: tuple[float, ...] = ()
    # energy guard (`models.base`): ∫|P_in| dt, and the cumulative residual
    # work_in − work_out − Δ(stored energy) − dissipated, both since the state was made
    energy_flow_j: float = 0.0
    energy_residual_j: float = 0.0
    # `elastic`: the nut's own axial position and velocity (the other models tie it to θ_S)
    nut_axial_m: float = 0.0
    nut_speed_m_s: float = 0.0
    screw_accel_rad_s2: float = 0.0  # last sub-step's, for the coupling's midpoint prediction
    # `elastic`: axial clearance added to `elastic.axial_clearance_m` (m), set by whoever steps the
    # model (the actuator's growing-backlash fault); an input carried in the state, 0 by default
    extra_clearance_m: float = 0.0


# Name and unit of every scalar output, in publication order. The ROS, MCAP and Rerun
# layers iterate this table instead of hard-coding field names.
OUTPUT_FIELDS: tuple[tuple[str, str], ...] = (
    ("time_s", "s"),
    ("screw_angle_rad", "rad"),
    ("screw_speed_rad_s", "rad/s"),
    ("screw_torque_nm", "N·m"),
    ("carrier_angle_rad", "rad"),
    ("carrier_speed_rad_s", "rad/s"),
    ("roller_spin_rad_s", "rad/s"),
    ("nut_position_m", "m"),
    ("nut_velocity_m_s", "m/s"),
    ("nut_force_n", "N"),
    ("load_force_n", "N"),
    ("slip_speed_m_s", "m/s"),
    ("power_in_w", "W"),
    ("power_out_w", "W"),
    ("power_dissipated_w", "W"),
    ("efficiency", "1"),
    ("speed_ratio", "1"),
    ("stored_energy_j", "J"),
    ("energy_flow_j", "J"),
    ("energy_residual_j", "J"),
    ("energy_fault", "1"),
)


@dataclass(frozen=True, slots=True)
class Outputs(metaclass=ABCMeta):  # ABCMeta: PackedOutputs registers as one
    """One step's outputs, SI units, at the step's end or averaged over it where a rate is meant.

    Every model fills the same record, so the node, the recorder and the viewer are written
    once; `OUTPUT_FIELDS` lists the scalar fields in order with their units.

    Attributes
    ----------
    time_s : float
        Simulation time at the end of the step, s.
    screw_angle_rad, screw_speed_rad_s : float
        Screw angle θ_S, rad, and speed ω_S, rad/s, right-handed about +z.
    screw_torque_nm : float
        The applied screw torque held over the step (the input), N·m.
    carrier_angle_rad, carrier_speed_rad_s : float
        Carrier (roller orbit) angle, rad, and speed ω_C, rad/s.
    roller_spin_rad_s : float
        Roller spin relative to the carrier, ω_r = −g ω_C, rad/s.
    nut_position_m, nut_velocity_m_s : float
        x_nut = (L/2π) θ_S, m, and its rate, m/s (positive where a positive torque drives the nut).
    nut_force_n : float
        Axial force the threads deliver to the nut along +x_nut, N (load force plus the moved
        mass times its acceleration; fu2018: the solved thread force).
    load_force_n : float
        The external load held over the step (the input), N, positive when it resists positive
        nut motion.
    slip_speed_m_s : float
        Magnitude of the screw–roller sliding velocity at the contact, m/s.
    power_in_w, power_out_w, power_dissipated_w : float
        Screw torque × screw speed, load force × nut velocity and friction power, W; step
        averages (the step's works / dt), so they balance with ΔT/dt.
    efficiency : float
        Of the mechanism, from the power through it (`models.base.efficiency`):
        P_out / (P_out + P_diss) when the screw drives the load, 1 − P_diss / |P_out| when the
        load drives the screw (≤ 0: self-locking), NaN when no power reaches the load. Equal to
        the port ratios at constant speed, never above 1. NaN means "undefined", not a fault.
    speed_ratio : float
        ζ_PS = ω_C / ω_S (NaN at ω_S = 0).
    stored_energy_j : float
        Energy the model stores at the step's end (kinetic; potential too in models with
        springs), J.
    energy_flow_j, energy_residual_j : float
        Energy guard (`models.base`): ∫|P_in| dt and work_in − work_out − Δstored − dissipated,
        both cumulative since the run started, J.
    energy_fault : float
        1.0 while |energy_residual_j| > 1e-3 · energy_flow_j once the flow exceeds 1 J (the
        model's energy books do not close: do not trust its results), else 0.0.
    internal : numpy.ndarray
        The flat internal-load vector, labelled by the model's `InternalLayout`.
    """

    time_s: float
    screw_angle_rad: float
    screw_speed_rad_s: float
    screw_torque_nm: float
    carrier_angle_rad: float
    carrier_speed_rad_s: float
    roller_spin_rad_s: float
    nut_position_m: float
    nut_velocity_m_s: float
    nut_force_n: float
    load_force_n: float
    slip_speed_m_s: float
    power_in_w: float
    power_out_w: float
    power_dissipated_w: float
    efficiency: float
    speed_ratio: float
    stored_energy_j: float
    energy_flow_j: float
    energy_residual_j: float
    energy_fault: float
    internal: np.ndarray

    def scalars(self) -> dict[str, float]:
        """The scalar outputs by name, in `OUTPUT_FIELDS` order (everything but `internal`)."""
        return {name: getattr(self, name) for name, _ in OUTPUT_FIELDS}

    def scalar_values(self) -> tuple[float, ...]:
        """The scalar outputs as one tuple, in OUTPUT_FIELDS order (cheap on `PackedOutputs`)."""
        return tuple(getattr(self, name) for name, _ in OUTPUT_FIELDS)


assert tuple(f.name for f in fields(Outputs))[:-1] == tuple(n for n, _ in OUTPUT_FIELDS)


@dataclass(frozen=True)
class InternalBlock:
    """A named block of the internal-load vector: an array of `shape` with named axes.

    Attributes
    ----------
    name : str
        Block name, e.g. ``"per_roller"``.
    dims : tuple of str
        Axis names; the last is always ``"quantity"``.
    shape : tuple of int
        Block shape; ``shape[-1] == len(quantities)``.
    quantities : tuple of (str, str)
        (name, unit) of each entry along the last axis, e.g. ``("screw_normal_force_n", "N")``.

    Examples
    --------
    The per-roller block of fu2018 has dims ("roller", "quantity") and shape (N_R, 14).
    """

    name: str
    dims: tuple[str, ...]
    shape: tuple[int, ...]
    quantities: tuple[tuple[str, str], ...]

    @property
    def size(self) -> int:
        """Number of elements in the block."""
        return int(np.prod(self.shape))


@dataclass(frozen=True)
class InternalLayout:
    """Labels every element of a model's flat internal-load vector.

    The vector is the model's blocks concatenated, each flattened in C order. Use `view` on
    one step's vector, `Trajectory.internal_block` / `Trajectory.internal_quantity` on a run,
    `labels` for one name per element (the column names of ``Trajectory.to_dataframe(internal=True)``).

    Attributes
    ----------
    blocks : tuple of InternalBlock
        The blocks in vector order (empty for the `ideal` model).
    """

    blocks: tuple[InternalBlock, ...]

    @property
    def size(self) -> int:
        """Length of the flat vector."""
        return sum(b.size for b in self.blocks)

    def offsets(self) -> dict[str, int]:
        """Start index of each block in the flat vector, by block name."""
        out, at = {}, 0
        for b in self.blocks:
            out[b.name] = at
            at += b.size
        return out

    def view(self, flat: np.ndarray, block: str) -> np.ndarray:
        """The named block of `flat` reshaped to its shape (a view, no copy)."""
        at = self.offsets()[block]
        b = next(b for b in self.blocks if b.name == block)
        return flat[at : at + b.size].reshape(b.shape)

    def labels(self) -> list[str]:
        """One label per element, e.g. "per_roller[2].screw_normal_force_n [N]"."""
        out: list[str] = []
        for b in self.blocks:
            for idx in np.ndindex(*b.shape):
                qname, unit = b.quantities[idx[-1]]
                where = ",".join(str(i) for i in idx[:-1])
                out.append(f"{b.name}[{where}].{qname} [{unit}]" if where else f"{b.name}.{qname} [{unit}]")
        return out

    def to_dict(self) -> dict:
        """A plain description (for the ROS labels topic and MCAP metadata)."""
        return {
            "blocks": [
                {"name": b.name, "dims": list(b.dims), "shape": list(b.shape),
                 "quantities": [{"name": q, "unit": u} for q, u in b.quantities]}
                for b in self.blocks
            ]
        }


class Trajectory:
    """Columnar results of a batch run (`Simulator.run`): one row per step, one column per output.

    Parameters
    ----------
    columns : dict of str to numpy.ndarray
        Every `OUTPUT_FIELDS` name → 1-D array of length steps (units: `OUTPUT_FIELDS`).
    internal : numpy.ndarray or callable
        Internal loads, shape (steps, layout.size), or a zero-argument callable returning them:
        a model whose internal vector is a cheap expansion of a compact per-step record
        (fu2018's per-tooth loads) builds the full array only when someone reads it.
    layout : InternalLayout
        Labels of the internal-load vector.
    final_state : State
        The state after the last step (a `Simulator` continues from it).

    Notes
    -----
    Row k holds the outputs at the end of step k (time ``time_s[k]``), with the inputs held
    over that step. `keys()` and ``traj[name]`` make it usable wherever a mapping of columns
    is (``dict(traj)``, ``pandas.DataFrame(dict(traj))``); `to_dataframe` does the latter with
    a time index and, on request, the labelled internal loads.

    Examples
    --------
    >>> import numpy as np
    >>> from prsm_sim import Simulator, preset
    >>> traj = Simulator(preset("jones2016")).run(np.full(100, 0.0922), load_n=100.0)
    >>> traj.keys()[:3]
    ['time_s', 'screw_angle_rad', 'screw_speed_rad_s']
    >>> traj.internal_quantity("per_roller", "screw_slip_axial_m_s").shape
    (100, 10)
    """

    __slots__ = ("columns", "layout", "final_state", "_internal")

    def __init__(self, columns: dict[str, np.ndarray], internal, layout: InternalLayout, final_state: State):
        self.columns = columns
        self.layout = layout
        self.final_state = final_state
        self._internal = internal

    @property
    def internal(self) -> np.ndarray:
        """Internal loads of every step, shape (steps, layout.size); `layout.labels()` names the columns."""
        if callable(self._internal):
            self._internal = self._internal()
        return self._internal

    def __len__(self) -> int:
        return len(self.columns["time_s"])

    def __getitem__(self, name: str) -> np.ndarray:
        """The named scalar column (a 1-D array over the steps); a KeyError lists the known names."""
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"{name!r}: Trajectory columns are {', '.join(self.columns)}") from None

    def __contains__(self, name: object) -> bool:
        return name in self.columns

    def __repr__(self) -> str:
        n = len(self)
        span = f"{self.columns['time_s'][0]:.6g}–{self.columns['time_s'][-1]:.6g} s" if n else "empty"
        return (f"Trajectory({n} steps, {span}, {len(self.columns)} scalar columns, "
                f"internal {n}×{self.layout.size} in blocks {[b.name for b in self.layout.blocks]})")

    def keys(self) -> list[str]:
        """The scalar column names, in `OUTPUT_FIELDS` order (their units are listed there)."""
        return list(self.columns)

    @property
    def time_s(self) -> np.ndarray:
        """Simulation time at the end of each step, s."""
        return self.columns["time_s"]

    def _block(self, name: str) -> InternalBlock:
        for b in self.layout.blocks:
            if b.name == name:
                return b
        known = ", ".join(b.name for b in self.layout.blocks) or "none (this model reports no internal loads)"
        raise InputError(f"internal block {name!r}: this model's blocks are {known}")

    def internal_block(self, name: str) -> np.ndarray:
        """One block of the internal loads over the run.

        Parameters
        ----------
        name : str
            Block name, one of ``[b.name for b in layout.blocks]`` (fu2018: ``"per_roller"``,
            ``"per_tooth"``, ``"carrier"``).

        Returns
        -------
        numpy.ndarray
            Shape ``(steps, *block.shape)``; the last axis runs over ``block.quantities``
            (name, unit). A view into `internal` where possible.

        Raises
        ------
        InputError
            An unknown block name (the message lists the model's blocks).
        """
        b = self._block(name)
        at = self.layout.offsets()[name]
        return self.internal[:, at:at + b.size].reshape(len(self), *b.shape)

    def internal_quantity(self, block: str, quantity: str) -> np.ndarray:
        """One named quantity of an internal-load block over the run.

        Parameters
        ----------
        block : str
            Block name (see `internal_block`).
        quantity : str
            Quantity name within the block, e.g. ``"screw_normal_force_n"`` (unit in the name,
            and in ``block.quantities``).

        Returns
        -------
        numpy.ndarray
            Shape ``(steps, *block.shape[:-1])``, e.g. (steps, rollers) for ``per_roller``.

        Raises
        ------
        InputError
            An unknown block or quantity (the message lists the known ones).
        """
        b = self._block(block)
        names = [q for q, _ in b.quantities]
        if quantity not in names:
            raise InputError(f"quantity {quantity!r} of internal block {block!r}: known quantities are "
                             f"{', '.join(names)}")
        return self.internal_block(block)[..., names.index(quantity)]

    def to_dataframe(self, internal: bool = False):
        """The run as a pandas DataFrame indexed by ``time_s`` (pandas is an optional dependency).

        Parameters
        ----------
        internal : bool, default False
            Also add every internal-load element as a column named by its label, e.g.
            ``"per_roller[2].screw_normal_force_n [N]"`` (`InternalLayout.labels`).

        Returns
        -------
        pandas.DataFrame
            One row per step; the scalar columns of `keys()` except ``time_s``, which is the index.

        Raises
        ------
        ImportError
            pandas is not installed (the message says how to install it).
        """
        try:
            import pandas as pd
        except ImportError as e:  # optional dependency: say how to get it
            raise ImportError("Trajectory.to_dataframe needs pandas: pip install pandas") from e
        data = {k: v for k, v in self.columns.items() if k != "time_s"}
        if internal and self.layout.size:
            data.update(zip(self.layout.labels(), self.internal.T))
        return pd.DataFrame(data, index=pd.Index(self.columns["time_s"], name="time_s"))

    def row(self, k: int) -> Outputs:
        """Step k as an `Outputs` record (the same record `Simulator.step` returns)."""
        return Outputs(**{n: float(self.columns[n][k]) for n, _ in OUTPUT_FIELDS}, internal=self.internal[k])


# -- the packed per-step record (Model.advance_packed) ----------------------------------------
# Layout of a packed record: the next packed state (Model.pack_state: time, θ_S, ω_S, θ_C, ω_C,
# W_in, W_out, W_diss, energy flow, energy residual, stored energy, and the model's own state as
# one tuple, `Model.extra_state_fields`), what the step alone knows (torque, load, dissipated work,
# input and output work), the outputs the node reads every step besides the state (nut force,
# position and velocity, the energy guard's verdict), the model's `PackedConstants` and the step's
# `aux` record (what the model's own outputs are derived from: fu2018 its end forces). The other
# outputs are a few flops on these, done when read.
PACKED_STATE_SIZE = 12
(_TAU, _LOAD, _DISS, _WIN, _WOUT, _NUT_F, _NUT_X, _NUT_V, _FAULT, _K,
 _AUX) = range(PACKED_STATE_SIZE, PACKED_STATE_SIZE + 11)


class PackedConstants:
    """What a model's packed records need to derive their other outputs: constants and functions.

    Attributes
    ----------
    dt_s : float
        The fixed step, s.
    gear_ratio : float
        g of ω_r = −g ω_C.
    slip_speed : callable
        (ω_S, ω_C at the step's end, the record's aux) → slip speed, m/s.
    internal : callable
        (ω_S, ω_C at the step's end, the record's aux) → the internal-load vector.
    efficiency : callable
        `models.base.efficiency`, passed in by `Model.packed_finisher` (models.base imports this module).
    """

    __slots__ = ("dt_s", "gear_ratio", "slip_speed", "internal", "efficiency")

    def __init__(self, dt_s, gear_ratio, slip_speed, internal, efficiency) -> None:
        self.dt_s, self.gear_ratio = dt_s, gear_ratio
        self.slip_speed, self.internal, self.efficiency = slip_speed, internal, efficiency


class _BuiltOnce:
    """A field computed on first read and kept in the record's own dict (a non-data descriptor)."""

    def __init__(self, fn) -> None:
        self.fn, self.name = fn, fn.__name__

    def __get__(self, obj, cls=None):
        if obj is None:
            return self
        value = obj.__dict__[self.name] = self.fn(obj)
        return value


class PackedOutputs(tuple):
    """One step's `Outputs` as the packed per-step path makes them: a tuple of what the step computed,
    every other field derived when read.

    Building a full record costs more than a linear model's step, and a caller reads few fields
    (the node: the state, the nut's position, velocity and force and the energy guard's verdict
    each step, the rest only for the internal-loads message), so the record holds those and what
    the step computed anyway (layout above; its first `PACKED_STATE_SIZE` items are the next
    packed state), and the other fields are properties with the arithmetic of `Model.finish_step`
    (tests/test_step_paths.py compares every field). The slip speed and the internal vector come
    from the model's own code on the step's `aux` record (fu2018: its end forces, expanded by
    `Fu2018.expand_one`); the internal vector is built on first read and kept. Reads as an
    `Outputs` (registered as one: ``isinstance(out, Outputs)`` holds), immutable; pickles and
    copies as a plain `Outputs`.
    """

    def __setattr__(self, name, value):
        raise FrozenInstanceError(f"cannot assign to field {name!r}")  # as on the frozen `Outputs`

    __delattr__ = __setattr__

    time_s = property(itemgetter(0))
    screw_angle_rad = property(itemgetter(1))
    screw_speed_rad_s = property(itemgetter(2))
    carrier_angle_rad = property(itemgetter(3))
    carrier_speed_rad_s = property(itemgetter(4))
    energy_flow_j = property(itemgetter(8))
    energy_residual_j = property(itemgetter(9))
    stored_energy_j = property(itemgetter(10))
    screw_torque_nm = property(itemgetter(_TAU))
    load_force_n = property(itemgetter(_LOAD))
    nut_force_n = property(itemgetter(_NUT_F))
    nut_position_m = property(itemgetter(_NUT_X))
    nut_velocity_m_s = property(itemgetter(_NUT_V))
    energy_fault = property(itemgetter(_FAULT))

    @property
    def roller_spin_rad_s(self) -> float:
        return -self[_K].gear_ratio * self[4]

    @property
    def slip_speed_m_s(self) -> float:
        return self[_K].slip_speed(self[2], self[4], self[_AUX])

    @property
    def power_in_w(self) -> float:
        return self[_WIN] / self[_K].dt_s

    @property
    def power_out_w(self) -> float:
        return self[_WOUT] / self[_K].dt_s

    @property
    def power_dissipated_w(self) -> float:
        return self[_DISS] / self[_K].dt_s

    @property
    def efficiency(self) -> float:
        return self[_K].efficiency(self.power_out_w, self.power_dissipated_w)

    @property
    def speed_ratio(self) -> float:
        w_s = self[2]
        return self[4] / w_s if w_s != 0.0 else math.nan

    @_BuiltOnce
    def internal(self) -> np.ndarray:
        return self[_K].internal(self[2], self[4], self[_AUX])

    def scalar_values(self) -> tuple[float, ...]:
        """The scalar outputs as one tuple, in OUTPUT_FIELDS order."""
        (t, th_s, w_s, th_c, w_c, _, _, _, flow, residual, e1, _, tau, load, diss, w_in, w_out, nut_f, nut_x, nut_v,
         fault, k, aux) = self
        h = k.dt_s
        p_out, p_d = w_out / h, diss / h
        return (t, th_s, w_s, tau, th_c, w_c, -k.gear_ratio * w_c, nut_x, nut_v, nut_f, load,
                k.slip_speed(w_s, w_c, aux), w_in / h, p_out, p_d, k.efficiency(p_out, p_d),
                w_c / w_s if w_s != 0.0 else math.nan, e1, flow, residual, fault)

    def scalars(self) -> dict[str, float]:
        """The scalar outputs by name, in `OUTPUT_FIELDS` order (everything but `internal`)."""
        return dict(zip(_FIELD_NAMES, self.scalar_values()))

    def __reduce__(self):
        return (Outputs, (*self.scalar_values(), self.internal))

    def __repr__(self) -> str:
        return "PackedOutputs(" + ", ".join(f"{n}={v!r}" for n, v in self.scalars().items()) + ")"

    # a record compares and hashes as its values (the constants' identity is no value)
    def __eq__(self, other):
        if isinstance(other, Outputs):
            return self.scalar_values() == other.scalar_values() and np.array_equal(self.internal, other.internal)
        return NotImplemented

    def __ne__(self, other):
        eq = self.__eq__(other)
        return eq if eq is NotImplemented else not eq

    __hash__ = None


_FIELD_NAMES = tuple(n for n, _ in OUTPUT_FIELDS)
assert set(_FIELD_NAMES) | {"internal"} <= set(dir(PackedOutputs))
Outputs.register(PackedOutputs)
