"""The records of stepping: the state, the outputs, and the labelled internal loads.

Every model fills the same `Outputs` record, so the ROS node, the MCAP recorder and the
Rerun sink are written once for all models. Internal loads differ by model (the rigid
`jones2016` model has no normal forces; `fu2018` has per-tooth loads), so they travel as a
flat float vector with a model-specific `InternalLayout` that labels every element.

Sign convention (the one place it is stated; docs/node.md "Sign convention" says it for users):
right-hand threads, z along the screw axis. Screw angle, speed and torque are positive
right-handed about +z. The nut position `nut_position_m` is measured along the direction a
positive screw rotation drives the nut: x_nut = (L / 2π) θ_S (for right-hand threads this
is the −z direction of the body frame). The external load force `load_force_n` is positive
when it resists positive nut motion (a compressive working load on an extending actuator).
"""

from __future__ import annotations

from abc import ABCMeta
from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any, cast

import numpy as np

from prsm_sim.errors import InputError


# Fields of the models' parts (`State.part`) that read as attributes of any State and are taken as keywords by
# its constructor, with the value a state whose part lacks them reads: aliases kept for one release.
LEGACY_PART_FIELDS: dict[str, object] = {
    "flank_sign": 1, "pin_force_n": 0.0, "gear_force_n": 0.0, "solver": (), "nut_axial_m": 0.0,
    "nut_speed_m_s": 0.0, "screw_accel_rad_s2": 0.0, "extra_clearance_m": 0.0,
}


@dataclass(frozen=True, slots=True, init=False)
class State:
    """Generalised coordinates and velocities, the energy ledger, and the model's own part (pure data, frozen).

    A model step maps (State, inputs) to the next State; nothing else carries memory. The
    energy accumulators make the balance ``work_in_j = work_out_j + ΔT + dissipated_j``
    checkable over any run (docs/model.md §4, "The energy ledger"); `time_s` and the
    accumulators are filled by the ledger (`stepping.ledger`).

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
    energy_flow_j, energy_residual_j : float
        Energy guard: the energy through the mechanism, Σ max(|ΔW_in|, |ΔW_out|) over the steps
        (the larger port work of each), and the cumulative residual work_in − work_out − Δ(stored
        energy) − dissipated, both since the state was made.
    part : tuple
        The model's own memory, a NamedTuple of the model's `part_type` (empty for `ideal` and
        `jones2016`): `fu2018.Fu2018Part` (the lagged flank pair and pin/gear forces entering its
        friction laws, the integrator memory), `elastic.ElasticPart` (those of its core plus the nut's
        own axial state, the coupling's last acceleration and the clearance a fault added). Its
        fields read as attributes of the state (``state.flank_sign``) and are taken as keywords by
        the constructor and `dataclasses.replace` (``replace(state, extra_clearance_m=2e-5)``).
    """

    time_s: float
    screw_angle_rad: float
    screw_speed_rad_s: float
    carrier_angle_rad: float
    carrier_speed_rad_s: float
    work_in_j: float
    work_out_j: float
    dissipated_j: float
    energy_flow_j: float
    energy_residual_j: float
    part: tuple

    def __init__(self, time_s: float = 0.0, screw_angle_rad: float = 0.0, screw_speed_rad_s: float = 0.0,
                 carrier_angle_rad: float = 0.0, carrier_speed_rad_s: float = 0.0, work_in_j: float = 0.0,
                 work_out_j: float = 0.0, dissipated_j: float = 0.0, energy_flow_j: float = 0.0,
                 energy_residual_j: float = 0.0, part: tuple = (), **part_fields) -> None:
        if part_fields:
            part = _with_part_fields(part, part_fields)
        # each field through its slot's own setter (`_SET`): a third of object.__setattr__'s cost, and states
        # are made on every step and every trial of an implicit solve
        t, a, s, ca, cs, wi, wo, d, ef, er, p = _SET
        t(self, time_s)
        a(self, screw_angle_rad)
        s(self, screw_speed_rad_s)
        ca(self, carrier_angle_rad)
        cs(self, carrier_speed_rad_s)
        wi(self, work_in_j)
        wo(self, work_out_j)
        d(self, dissipated_j)
        ef(self, energy_flow_j)
        er(self, energy_residual_j)
        p(self, part)

    def __getattr__(self, name: str):
        """A field of the model's part by name (called only when the state itself has no such attribute)."""
        if name not in LEGACY_PART_FIELDS:
            return object.__getattribute__(self, name)  # the usual AttributeError
        return getattr(object.__getattribute__(self, "part"), name, LEGACY_PART_FIELDS[name])


# the slots' setters of `State`, in field order (a frozen record's fields are set past its own __setattr__)
_SET = tuple(getattr(State, f.name).__set__ for f in fields(State))


def _with_part_fields(part: tuple, values: dict) -> tuple:
    """`part` with the named fields replaced; a field the part lacks may only be given its default."""
    unknown = [k for k in values if k not in LEGACY_PART_FIELDS]
    if unknown:
        raise InputError(f"State: unknown field {unknown[0]!r}")
    own = getattr(part, "_fields", ())
    mine = {k: v for k, v in values.items() if k in own}
    for k, v in values.items():
        if k not in own and v != LEGACY_PART_FIELDS[k]:
            held = ", ".join(own) or "nothing"
            raise InputError(f"{k} = {v!r}: this model's state has no {k} (its part holds {held})")
    return cast(Any, part)._replace(**mine) if mine else part  # a named tuple: it has the fields


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
    ("over_static_rating", "1"),
)


@dataclass(frozen=True, slots=True, init=False)
class Outputs(metaclass=ABCMeta):  # ABCMeta: the packed record (`stepping.packed`) registers as one
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
        Of the mechanism, from the power through it (`stepping.ledger.efficiency`):
        P_out / (P_out + P_diss) when the screw drives the load, 1 − P_diss / |P_out| when the
        load drives the screw; defined only while power flows through (P_in P_out > 0) above
        EFFICIENCY_MIN_POWER_W, with friction absorbing and the stored energy changing by at most
        5 % of the power through; then in [0, 1] and equal to the port ratios at constant speed.
        NaN otherwise: "undefined" (start-up, reversals, standstill), not a fault.
    speed_ratio : float
        ζ_PS = ω_C / ω_S (NaN at ω_S = 0).
    stored_energy_j : float
        Energy the model stores at the step's end (kinetic; potential too in models with
        springs), J.
    energy_flow_j, energy_residual_j : float
        Energy guard (`stepping.ledger`): Σ max(|ΔW_in|, |ΔW_out|) (each step's larger port work) and
        work_in − work_out − Δstored − dissipated, both cumulative since the run started, J.
    energy_fault : float
        1.0 while |energy_residual_j| > 1e-3 · energy_flow_j once the flow exceeds 1 J (the
        model's energy books do not close: do not trust its results), else 0.0.
    over_static_rating : float
        1.0 while the load held over the step exceeds the static load rating C₀a
        (|load_force_n| > `Ratings.static_load_rating_n`: past it the threads deform permanently,
        ISO 76, which no model here represents), else 0.0.
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
    over_static_rating: float
    internal: np.ndarray

    def __init__(self, time_s: float, screw_angle_rad: float, screw_speed_rad_s: float, screw_torque_nm: float,
                 carrier_angle_rad: float, carrier_speed_rad_s: float, roller_spin_rad_s: float, nut_position_m: float,
                 nut_velocity_m_s: float, nut_force_n: float, load_force_n: float, slip_speed_m_s: float,
                 power_in_w: float, power_out_w: float, power_dissipated_w: float, efficiency: float,
                 speed_ratio: float, stored_energy_j: float, energy_flow_j: float, energy_residual_j: float,
                 energy_fault: float, over_static_rating: float, internal: np.ndarray) -> None:
        # each field through its slot's own setter (`_OUT_SET`), as `State`: a record is made every step
        (t, a, s, tau, ca, cs, spin, x, v, f, load, slip, p_in, p_out, p_diss, eff, ratio, stored, flow, resid,
         fault, over, inner) = _OUT_SET
        t(self, time_s)
        a(self, screw_angle_rad)
        s(self, screw_speed_rad_s)
        tau(self, screw_torque_nm)
        ca(self, carrier_angle_rad)
        cs(self, carrier_speed_rad_s)
        spin(self, roller_spin_rad_s)
        x(self, nut_position_m)
        v(self, nut_velocity_m_s)
        f(self, nut_force_n)
        load(self, load_force_n)
        slip(self, slip_speed_m_s)
        p_in(self, power_in_w)
        p_out(self, power_out_w)
        p_diss(self, power_dissipated_w)
        eff(self, efficiency)
        ratio(self, speed_ratio)
        stored(self, stored_energy_j)
        flow(self, energy_flow_j)
        resid(self, energy_residual_j)
        fault(self, energy_fault)
        over(self, over_static_rating)
        inner(self, internal)

    def scalars(self) -> dict[str, float]:
        """The scalar outputs by name, in `OUTPUT_FIELDS` order (everything but `internal`)."""
        return {name: getattr(self, name) for name, _ in OUTPUT_FIELDS}

    def scalar_values(self) -> tuple[float, ...]:
        """The scalar outputs as one tuple, in OUTPUT_FIELDS order (cheap on `PackedOutputs`)."""
        return tuple(getattr(self, name) for name, _ in OUTPUT_FIELDS)


assert tuple(f.name for f in fields(Outputs))[:-1] == tuple(n for n, _ in OUTPUT_FIELDS)
_OUT_SET = tuple(getattr(Outputs, f.name).__set__ for f in fields(Outputs))  # the slots' setters, in field order


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
    The per-roller block of fu2018 has dims ("roller", "quantity") and shape (N_R, 23).
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

    @cached_property
    def size(self) -> int:
        """Length of the flat vector."""
        return sum(b.size for b in self.blocks)

    @cached_property
    def _spans(self) -> dict[str, tuple[int, int, tuple[int, ...]]]:
        """(start, end, shape) of each block by name, worked out once (a session reads a block every step)."""
        out, at = {}, 0
        for b in self.blocks:
            out[b.name] = (at, at + b.size, b.shape)
            at += b.size
        return out

    def offsets(self) -> dict[str, int]:
        """Start index of each block in the flat vector, by block name."""
        return {name: span[0] for name, span in self._spans.items()}

    def view(self, flat: np.ndarray, block: str) -> np.ndarray:
        """The named block of `flat` reshaped to its shape (a view, no copy)."""
        at, end, shape = self._spans[block]
        return flat[at:end].reshape(shape)

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
