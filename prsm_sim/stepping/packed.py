"""The packed per-step record, and the ledger's per-step form that makes it (`make_finisher`).

A model step (`Model.step_packed`) works on the packed state, a tuple (time, θ_S, ω_S, θ_C, ω_C,
W_in, W_out, W_diss, energy flow, energy residual, stored energy, the model's part: `Model.pack_state`)
and returns a `PackedOutputs`: the step's outputs whose first PACKED_STATE_SIZE items are the next
packed state. Layout of a record after those: what the step alone knows (command, load, dissipated
work, input and output work), the outputs the node reads every step besides the state (nut force,
position and velocity, the energy guard's verdict), the model's `PackedConstants` and the step's
`aux` record (what the model's own outputs are derived from: fu2018 its end forces). The other
outputs are a few flops on these, done when read.
"""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError
from operator import itemgetter

import numpy as np

from prsm_sim.stepping.ledger import efficiency, ledger_step, over_static_rating, speed_ratio
from prsm_sim.stepping.records import OUTPUT_FIELDS, Outputs

PACKED_STATE_SIZE = 12
(_TAU, _LOAD, _DISS, _WIN, _WOUT, _NUT_F, _NUT_X, _NUT_V, _FAULT, _K,
 _AUX) = range(PACKED_STATE_SIZE, PACKED_STATE_SIZE + 11)
NUT_POSITION_ITEM = _NUT_X  # where a record holds the nut position (a caller on the per-step path reads it so)
NUT_FORCE_ITEM = _NUT_F  # ... and the nut force


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
    static_rating_n : float, default inf
        The static load rating C₀a the load is flagged against (`Outputs.over_static_rating`), N.
    """

    __slots__ = ("dt_s", "gear_ratio", "slip_speed", "internal", "static_rating_n")

    def __init__(self, dt_s, gear_ratio, slip_speed, internal, static_rating_n=math.inf) -> None:
        self.dt_s, self.gear_ratio = dt_s, gear_ratio
        self.slip_speed, self.internal = slip_speed, internal
        self.static_rating_n = static_rating_n


def make_finisher(k: PackedConstants, lead_per_rad_m: float, moved_mass_kg: float):
    """The ledger's per-step form for one model: a function
    ``finish(x, θ_S, ω_S, θ_C, ω_C, command, load, dissipated, stored, part=(), aux=None,
    nut_force=None, nut=None) -> PackedOutputs``
    from the packed state before the step and the model's results at its end (stored: the stored
    energy there; part: the model's own next state). It advances time, the work accumulators and
    the energy guard (`ledger_step`), and fills the nut's force, position and
    velocity: by default (L/2π) θ_S and its rate, and the load plus the moved mass's acceleration;
    a model that knows better passes `nut_force`, and a nut with an axial state of its own
    (`elastic`) passes `nut` = (x_N, v_N, the load's work over the step). The record derives the
    other outputs when read with `k` (the step, the model's own slip speed and internal vector as
    functions of ω_S, ω_C at the step's end and the step's `aux`, the static rating a load is flagged
    past). `fu2018` makes its records in its compiled step (`models.kernels.step_record`), the same
    arithmetic in the same order.
    """
    h, p = k.dt_s, lead_per_rad_m
    mp = moved_mass_kg * p
    ledger = ledger_step  # a local name: one look-up less per step

    def finish(x, th_s, w_s, th_c, w_c, command, load_n, dissipated_j, stored_j, part=(), aux=None,
               nut_force=None, nut=None):
        dtheta = th_s - x[1]
        if nut is None:  # the nut rides the threads: x_nut = (L/2π) θ_S
            w_out = load_n * p * dtheta
            nut_x, nut_v = p * th_s, p * w_s
        else:
            nut_x, nut_v, w_out = nut
        if nut_force is None:
            nut_force = load_n + mp * (w_s - x[2]) / h
        w_in, flow, residual, fault = ledger(x[8], x[9], command, dtheta, w_out, dissipated_j, x[10], stored_j)
        return PackedOutputs((
            x[0] + h, th_s, w_s, th_c, w_c, x[5] + w_in, x[6] + w_out, x[7] + dissipated_j, flow, residual,
            stored_j, part, command, load_n, dissipated_j, w_in, w_out, nut_force, nut_x, nut_v,
            1.0 if fault else 0.0, k, aux))
    return finish


def joined(first: PackedOutputs, second: PackedOutputs, whole: PackedOutputs) -> PackedOutputs:
    """One step's record from its two pieces in turn (`second` continued `first`'s state): the state, end values
    and end forces of `second`, the step's works and dissipation summed over both, the energy guard's verdict of
    either, and the constants (the step's dt for its powers) of `whole`, a record of the whole step."""
    return PackedOutputs(second[:_DISS] + (first[_DISS] + second[_DISS], first[_WIN] + second[_WIN],
                                          first[_WOUT] + second[_WOUT]) + second[_NUT_F:_FAULT]
                         + (max(first[_FAULT], second[_FAULT]), whole[_K]) + second[_AUX:])


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
    """One step's `Outputs` as the per-step path makes them: a tuple of what the step computed,
    every other field derived when read.

    Building a full record costs more than a linear model's step, and a caller reads few fields
    (the node: the state, the nut's position, velocity and force and the energy guard's verdict
    each step, the rest only for the internal-loads message), so the record holds those and what
    the step computed anyway (module doc; its first `PACKED_STATE_SIZE` items are the next packed
    state), and the other fields are properties. The slip speed and the internal vector come from
    the model's own code on the step's `aux` record (fu2018: its end forces, expanded by
    `Fu2018.expand_one`); the internal vector is built on first read and kept. Reads as an
    `Outputs` (registered as one: ``isinstance(out, Outputs)`` holds), immutable; pickles and
    copies as a plain `Outputs` (`to_outputs`).
    """

    def __setattr__(self, name, value):
        raise FrozenInstanceError(f"cannot assign to field {name!r}")  # as on the frozen `Outputs`

    __delattr__ = __setattr__  # type: ignore[assignment]  # refused as assignment is

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
        return efficiency(self.power_in_w, self.power_out_w, self.power_dissipated_w)

    @property
    def over_static_rating(self) -> float:
        return over_static_rating(self[_LOAD], self[_K].static_rating_n)

    @property
    def speed_ratio(self) -> float:
        return speed_ratio(self[2], self[4])

    @_BuiltOnce
    def internal(self) -> np.ndarray:
        return self[_K].internal(self[2], self[4], self[_AUX])

    def scalar_values(self) -> tuple[float, ...]:
        """The scalar outputs as one tuple, in OUTPUT_FIELDS order: each as its property computes it, written
        out in one place (a full record is built every step on the actuator's path, where a call per field
        cost more than the fields; tests/test_stepping.py holds it to the properties, field by field)."""
        k, w_s, w_c, load = self[_K], self[2], self[4], self[_LOAD]
        dt = k.dt_s
        p_in, p_out, p_diss = self[_WIN] / dt, self[_WOUT] / dt, self[_DISS] / dt
        return (self[0], self[1], w_s, self[_TAU], self[3], w_c, -k.gear_ratio * w_c, self[_NUT_X], self[_NUT_V],
                self[_NUT_F], load, k.slip_speed(w_s, w_c, self[_AUX]), p_in, p_out, p_diss,
                efficiency(p_in, p_out, p_diss), speed_ratio(w_s, w_c), self[10], self[8], self[9], self[_FAULT],
                over_static_rating(load, k.static_rating_n))

    def scalars(self) -> dict[str, float]:
        """The scalar outputs by name, in `OUTPUT_FIELDS` order (everything but `internal`)."""
        return dict(zip(_FIELD_NAMES, self.scalar_values()))

    def to_outputs(self, internal: np.ndarray | None = None) -> Outputs:
        """The record as a plain `Outputs` (every field computed); `internal`: an internal vector in place of the
        model's (a wrapper that appends blocks of its own to it: the actuator)."""
        return Outputs(*self.scalar_values(),  # type: ignore[arg-type, call-arg]  # the fields in order
                       self.internal if internal is None else internal)

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

    __hash__ = None  # type: ignore[assignment]  # compared by value, so unhashable (as `Outputs`)


_FIELD_NAMES = tuple(n for n, _ in OUTPUT_FIELDS)
Outputs.register(PackedOutputs)
