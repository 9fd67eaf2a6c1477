"""`Trajectory`, the columnar results of a batch run, and how a run's columns are assembled.

`trajectory_from_records` turns per-step records into columns; `trajectory_from_columns` assembles
every output column of a batch form from its per-step kinematics, works and stored energy, with the
ledger's column form (`stepping.ledger.ledger_columns`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from prsm_sim.errors import InputError
from prsm_sim.stepping.ledger import (accumulate, efficiency_columns, ledger_columns, over_static_rating,
                                     speed_ratio_columns)
from prsm_sim.stepping.records import OUTPUT_FIELDS, InternalBlock, InternalLayout, Outputs, State


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


def trajectory_from_rows(rows: list[Outputs], layout: InternalLayout, final: State) -> Trajectory:
    """Columns from per-step `Outputs` records (any `Outputs`, the packed ones included)."""
    n = len(rows)
    table = np.array([r.scalar_values() for r in rows], dtype=float).reshape(n, len(OUTPUT_FIELDS))
    cols = {name: table[:, i].copy() for i, (name, _) in enumerate(OUTPUT_FIELDS)}
    return Trajectory(columns=cols, layout=layout, final_state=final,
                      internal=lambda: np.array([r.internal for r in rows], dtype=float).reshape(n, layout.size))


def trajectory_from_columns(initial: State, final: State, stored0_j: float, *, dt_s: float, gear_ratio: float,
                            layout: InternalLayout, internal, torque_nm, load_n, th_s, w_s, th_c, w_c, dtheta, nut_x,
                            nut_v, nut_force, slip, work_out_j, dissipated_j, stored_j,
                            static_rating_n: float = math.inf) -> Trajectory:
    """A batch run's `Trajectory` from its per-step arrays (the column twin of `stepping.packed.make_finisher`).

    `initial` is the state the run started from (its stored energy `stored0_j`), `final` the model's
    state after the last step: its time and ledger (work accumulators, energy flow and residual) are
    filled here from the columns. The powers, efficiency, speed ratio, time and the guard's verdict
    are derived here; the works are J over each step. `over_static_rating` flags the load against
    `static_rating_n`, N (`Model.run` flags it against the model's own rating for every batch form).
    """
    h, n = dt_s, len(torque_nm)
    w_in, flow, residual, fault = ledger_columns(initial.energy_flow_j, initial.energy_residual_j, stored0_j,
                                                 torque_nm, dtheta, work_out_j, dissipated_j, stored_j)
    if n:
        final = replace(final, time_s=initial.time_s + h * n,
                        work_in_j=float(accumulate(initial.work_in_j, w_in)[-1]),
                        work_out_j=float(accumulate(initial.work_out_j, work_out_j)[-1]),
                        dissipated_j=float(accumulate(initial.dissipated_j, dissipated_j)[-1]),
                        energy_flow_j=float(flow[-1]), energy_residual_j=float(residual[-1]))
    p_out, p_d = work_out_j / h, dissipated_j / h
    columns = {
        "time_s": final.time_s - h * np.arange(n - 1, -1, -1),
        "screw_angle_rad": th_s, "screw_speed_rad_s": w_s, "screw_torque_nm": np.array(torque_nm, dtype=float),
        "carrier_angle_rad": th_c, "carrier_speed_rad_s": w_c, "roller_spin_rad_s": -gear_ratio * w_c,
        "nut_position_m": nut_x, "nut_velocity_m_s": nut_v, "nut_force_n": nut_force,
        "load_force_n": np.array(load_n, dtype=float), "slip_speed_m_s": slip, "power_in_w": w_in / h,
        "power_out_w": p_out, "power_dissipated_w": p_d, "efficiency": efficiency_columns(w_in / h, p_out, p_d),
        "speed_ratio": speed_ratio_columns(w_s, w_c), "stored_energy_j": stored_j, "energy_flow_j": flow,
        "energy_residual_j": residual, "energy_fault": fault.astype(float),
        "over_static_rating": over_static_rating(np.asarray(load_n, dtype=float), static_rating_n),
    }
    columns = {name: np.ascontiguousarray(columns[name], dtype=float) for name, _ in OUTPUT_FIELDS}
    return Trajectory(columns=columns, internal=internal, layout=layout, final_state=final)
