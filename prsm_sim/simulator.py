"""`Simulator`: a model, its state and its counters behind one fixed-step interface.

    sim = Simulator(preset("jones2016"), "jones2016", dt_s=1e-3)
    out = sim.step(torque_nm=0.1, load_n=100.0)      # → Outputs
    traj = sim.run(torque_array, load_array)          # → Trajectory (columns)

The models themselves are pure (state in, state out); this wrapper only holds the current
state and counts steps, so a node or a CLI can drive it without bookkeeping of its own.
"""

from __future__ import annotations

import math

import numpy as np

from prsm_sim.errors import InputError
from prsm_sim.models.base import Model
from prsm_sim.models.fu2018 import Fu2018
from prsm_sim.models.ideal import Ideal
from prsm_sim.models.jones2016 import Jones2016
from prsm_sim.outputs import Outputs, State, Trajectory
from prsm_sim.params import Params

MODELS: dict[str, type[Model]] = {"ideal": Ideal, "jones2016": Jones2016, "fu2018": Fu2018}


def build_model(params: Params, model: str, dt_s: float) -> Model:
    """The named model for these parameters; an unknown name is refused with the known ones."""
    try:
        cls = MODELS[model]
    except KeyError:
        raise ValueError(f"unknown model {model!r}; known models: {', '.join(MODELS)}") from None
    return cls(params, dt_s)


class Simulator:
    """Stateful wrapper: current state, step counter, input checks."""

    def __init__(self, params: Params, model: str = "jones2016", dt_s: float = 1e-3,
                 nut_position_m: float = 0.0) -> None:
        self.model = build_model(params, model, dt_s)
        self.params = params
        self.dt_s = self.model.dt_s
        self._initial_nut_position_m = float(nut_position_m)
        self.state = self.model.initial_state(nut_position_m)
        self.nstep = 0

    # The current state is a `State`, or for models with a packed step (Model.advance_packed) the
    # packed tuple between steps, turned into a `State` only when someone reads it.
    @property
    def state(self) -> State:
        if self._state is None:
            self._state = self.model.unpack_state(self._packed)
        return self._state

    @state.setter
    def state(self, value: State) -> None:
        self._state = value
        self._packed = self.model.pack_state(value) if self.model.packed else None

    @property
    def layout(self):
        return self.model.layout

    @property
    def time_s(self) -> float:
        return self._packed[0] if self._state is None else self._state.time_s

    def reset(self, nut_position_m: float | None = None) -> State:
        """Back to rest at the initial (or given) nut position, time zero, counters cleared."""
        if nut_position_m is not None:
            self._initial_nut_position_m = float(nut_position_m)
        self.state = self.model.initial_state(self._initial_nut_position_m)
        self.nstep = 0
        return self.state

    def step(self, torque_nm: float, load_n: float = 0.0) -> Outputs:
        """One step; a non-finite input is refused (InputError) and the state is left unchanged."""
        # (x + y) * 0 is 0 only for finite floats: one test for the common case, the full check otherwise
        if not (type(torque_nm) is float and type(load_n) is float and (torque_nm + load_n) * 0.0 == 0.0):
            for name, v in (("torque_nm", torque_nm), ("load_n", load_n)):
                if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(v):
                    raise InputError(f"{name} = {v!r}: inputs must be finite numbers")
            torque_nm, load_n = float(torque_nm), float(load_n)
        if self._packed is not None:
            self._packed, out = self.model.advance_packed(self._packed, torque_nm, load_n)
            self._state = None
        else:
            self._state, out = self.model.step(self._state, torque_nm, load_n)
        self.nstep += 1
        return out

    def run(self, torque_nm, load_n=0.0) -> Trajectory:
        """len(torque_nm) steps in one call (the model's batch form where it has one)."""
        traj = self.model.run(self.state, torque_nm, load_n)
        self.state = traj.final_state
        self.nstep += len(traj)
        return traj
