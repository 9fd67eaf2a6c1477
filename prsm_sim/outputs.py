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

from dataclasses import dataclass, fields

import numpy as np


@dataclass(frozen=True, slots=True)
class State:
    """Generalised coordinates and velocities plus the energy ledger (pure data).

    Carrier angle/speed are kinematic for the `ideal` model. The energy accumulators make the
    balance `work_in = work_out + ΔT + dissipated` checkable over any run.
    (`time_s` and the accumulators are filled by `Model.finish_step`.)
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
)


@dataclass(frozen=True, slots=True)
class Outputs:
    """One step's outputs, SI units, averaged over the step where a rate is meant.

    - `screw_torque_nm`: the applied screw torque held over the step (the input).
    - `roller_spin_rad_s`: roller spin relative to the carrier (ω_r = −g ω_C).
    - `nut_force_n`: axial force the threads deliver to the nut, positive in +x_nut
      (load force plus the moved mass times its acceleration).
    - `slip_speed_m_s`: magnitude of the screw–roller sliding velocity at the contact.
    - `power_in_w` = screw torque × screw speed, `power_out_w` = load force × nut velocity,
      `power_dissipated_w` = friction power; step averages, so their sum balances with ΔT/Δt.
    - `efficiency`: of the mechanism, from the power through it (`model_base.efficiency`):
      P_out / (P_out + P_diss) when the screw drives the load, 1 − P_diss / |P_out| when the
      load drives the screw (≤ 0: self-locking), NaN when no power reaches the load. Equal to
      the port ratios at constant speed, never above 1. Consumers must treat NaN here as
      "undefined", not as a fault.
    - `speed_ratio`: ζ_PS = ω_C / ω_S (NaN at ω_S = 0).
    - `internal`: flat internal-load vector described by the model's `InternalLayout`.
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
    internal: np.ndarray

    def scalars(self) -> dict[str, float]:
        """The scalar outputs by name, in OUTPUT_FIELDS order."""
        return {name: getattr(self, name) for name, _ in OUTPUT_FIELDS}


assert tuple(f.name for f in fields(Outputs))[:-1] == tuple(n for n, _ in OUTPUT_FIELDS)


@dataclass(frozen=True)
class InternalBlock:
    """A named block of the internal-load vector: an array of `shape` with named axes.

    The last axis is `quantity`: one entry per (name, unit) in `quantities`. Example: the
    per-roller block of fu2018 has dims ("roller", "quantity") and shape (N_R, 14).
    """

    name: str
    dims: tuple[str, ...]
    shape: tuple[int, ...]
    quantities: tuple[tuple[str, str], ...]

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))


@dataclass(frozen=True)
class InternalLayout:
    """Labels every element of a model's flat internal-load vector (blocks concatenated, C order)."""

    blocks: tuple[InternalBlock, ...]

    @property
    def size(self) -> int:
        return sum(b.size for b in self.blocks)

    def offsets(self) -> dict[str, int]:
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
    """Columnar results of a batch run: each OUTPUT_FIELDS name → 1-D array, plus `internal` (steps × layout.size).

    `internal` may be given as a zero-argument callable: a model whose internal vector is a
    cheap expansion of a compact per-step record (fu2018's per-tooth loads) builds the full
    array only when someone reads it.
    """

    __slots__ = ("columns", "layout", "final_state", "_internal")

    def __init__(self, columns: dict[str, np.ndarray], internal, layout: InternalLayout, final_state: State):
        self.columns = columns
        self.layout = layout
        self.final_state = final_state
        self._internal = internal

    @property
    def internal(self) -> np.ndarray:
        if callable(self._internal):
            self._internal = self._internal()
        return self._internal

    def __len__(self) -> int:
        return len(self.columns["time_s"])

    def __getitem__(self, name: str) -> np.ndarray:
        return self.columns[name]

    def __repr__(self) -> str:
        n = len(self)
        span = f"{self.columns['time_s'][0]:.6g}–{self.columns['time_s'][-1]:.6g} s" if n else "empty"
        return (f"Trajectory({n} steps, {span}, {len(self.columns)} scalar columns, "
                f"internal {n}×{self.layout.size} in blocks {[b.name for b in self.layout.blocks]})")

    def keys(self) -> list[str]:
        """The scalar column names, in OUTPUT_FIELDS order (units: `OUTPUT_FIELDS`)."""
        return list(self.columns)

    @property
    def time_s(self) -> np.ndarray:
        """Simulation time at the end of each step, s."""
        return self.columns["time_s"]

    def internal_block(self, name: str) -> np.ndarray:
        """One internal-load block over the run: shape (steps, *block.shape), labelled by `layout`."""
        at = self.layout.offsets()[name]
        b = next(b for b in self.layout.blocks if b.name == name)
        return self.internal[:, at:at + b.size].reshape(len(self), *b.shape)

    def to_dataframe(self, internal: bool = False):
        """The scalar columns as a pandas DataFrame indexed by `time_s` (pandas is optional).

        With `internal=True` every internal-load element is added as a column named by its
        label (e.g. ``per_roller[2].screw_normal_force_n [N]``).
        """
        try:
            import pandas as pd
        except ImportError as e:  # optional dependency: say how to get it
            raise ImportError("Trajectory.to_dataframe needs pandas: pip install pandas "
                              "(or the 'sweep' extra)") from e
        data = {k: v for k, v in self.columns.items() if k != "time_s"}
        if internal and self.layout.size:
            data.update(zip(self.layout.labels(), self.internal.T))
        return pd.DataFrame(data, index=pd.Index(self.columns["time_s"], name="time_s"))

    def row(self, k: int) -> Outputs:
        return Outputs(**{n: float(self.columns[n][k]) for n, _ in OUTPUT_FIELDS}, internal=self.internal[k])


class PackedOutputs(Outputs):
    """An `Outputs` backed by one tuple of the scalars, with `internal` built on first read.

    The per-step fast path of the linear models (`Model.step_packed`) returns these: building
    the frozen record field by field costs more than the step itself, and the node reads the
    internal vector only at its (decimated) publishing rate. Every field reads as on `Outputs`
    (the properties shadow the base class's slots); `isinstance(out, Outputs)` holds.
    `internal_src` is an array, or a (function, argument) pair evaluated once on first read.
    """

    __slots__ = ("_values", "_internal_src")

    def __init__(self, values: tuple[float, ...], internal_src) -> None:  # noqa: D107 (no dataclass init)
        object.__setattr__(self, "_values", values)
        object.__setattr__(self, "_internal_src", internal_src)

    @property
    def internal(self) -> np.ndarray:
        src = self._internal_src
        if type(src) is tuple:
            src = src[0](src[1])
            object.__setattr__(self, "_internal_src", src)
        return src

    def scalars(self) -> dict[str, float]:
        return dict(zip(_FIELD_NAMES, self._values))


def _packed_field(i: int) -> property:
    from operator import itemgetter
    get = itemgetter(i)
    return property(lambda self: get(self._values))


_FIELD_NAMES = tuple(n for n, _ in OUTPUT_FIELDS)
for _i, _name in enumerate(_FIELD_NAMES):
    setattr(PackedOutputs, _name, _packed_field(_i))
del _i, _name
