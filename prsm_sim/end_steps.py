"""A bare model's steps against its thread ends: the stop law (`actuator.stops`) solved on the model's own step.

The simulator steps a bare model freely and hands a step that ran past an end here (`EndSteps.packed`). The
end's force joins the load on the nut (`load_force_n` reports their sum, so the ledger holds its work). A step
that ends with the nut at rest off the end's law (`stops.off_rest`: the force held over it carries the damper's
c Δδ/h of a motion that ended within it) is taken again as two halves of the model built at dt/2, the second
judged likewise down to dt/2**MAX_REST_HALVINGS, as the actuator's sub-steps are, so the nut rests on the law;
the step's record sums the pieces' works (`packed.joined`).
"""

from __future__ import annotations

import math
from typing import Any

from prsm_sim.actuator.implicit import probe_inertia
from prsm_sim.actuator.stops import MAX_REST_HALVINGS, Limit, engaged, off_rest
from prsm_sim.actuator.stops import solve as solve_stop
from prsm_sim.errors import NonFiniteStateError
from prsm_sim.models.registry import build_model
from prsm_sim.params import Params
from prsm_sim.stepping.model import Model
from prsm_sim.stepping.packed import NUT_POSITION_ITEM, joined
from prsm_sim.stepping.records import State


def non_finite_error(model_name: str, time_s: float) -> NonFiniteStateError:
    """The error of a step that left the state non-finite (the state before it is kept)."""
    return NonFiniteStateError(f"model {model_name} produced a non-finite state at t = {time_s:.6f} s; "
                               "the state before it is kept", time_s)


class EndSteps:
    """The thread ends of a bare model (`limits`, the nut held within [lo, hi]) and its steps against them.
    `force_n`: the end's force on the nut over the last step solved here (N along +x_nut; 0 where it ended off)."""

    def __init__(self, model: Model, params: Params, limits: tuple[Limit, ...], lo_m: float, hi_m: float,
                 kernel: str) -> None:
        self.model, self.params, self.limits, self.kernel = model, params, limits, kernel
        self.lo_m, self.hi_m = lo_m, hi_m
        self.force_n = 0.0
        self._inertia: float | None = None  # `_contact_inertia`, on the first contact
        self._halved: dict[int, Any] = {}  # `_model_at`: the model at dt/2**k

    def packed(self, x, free, command: float, load_n: float, end_time_s: float, halvings: int = 0,
               last: bool = True):
        """The packed step from `x` (its free result `free` ran past an end) of the model at dt/2**halvings,
        solved against the end; the step's `last` piece, ending at rest off the end's law, in two halves
        (module doc). NonFiniteStateError where the nut ends non-finite."""
        model = self._model_at(halvings)
        step = model.step_packed
        out = self.solve(model, model.unpack_state(x), free, lambda f: step(x, command, load_n - f),
                         lambda r: r.nut_position_m, lambda r: r.screw_speed_rad_s, end_time_s)
        lim = engaged(self.limits, out.nut_position_m)
        if not (last and lim is not None and halvings < MAX_REST_HALVINGS
                and off_rest(lim, self.force_n, out.nut_position_m, out.nut_velocity_m_s)):
            return out
        half = self._model_at(halvings + 1)
        first = half.step_packed(x, command, load_n)
        if not self.lo_m <= first[NUT_POSITION_ITEM] <= self.hi_m:
            first = self.packed(x, first, command, load_n, end_time_s, halvings + 1, False)
        second = half.step_packed(first, command, load_n)
        self.force_n = 0.0  # the second half's, where it leaves the end
        if not self.lo_m <= second[NUT_POSITION_ITEM] <= self.hi_m:
            second = self.packed(first, second, command, load_n, end_time_s, halvings + 1, True)
        return joined(first, second, out)

    def solve(self, m: Model, before: State, free, advance, nut, speed, end_time_s: float):
        """The step of model `m` against the end its free result `free` ran past: the stop law solved on the
        model's own step (`advance(F)`: the step with the end's force F along +x_nut; `nut(result)`,
        `speed(result)`: the nut's end position and the screw's end speed). Sets `force_n`. NonFiniteStateError
        where the nut ends non-finite (also where no end is fitted: the bounds are then the float range)."""
        if not math.isfinite(nut(free)):
            raise non_finite_error(self.model.name, end_time_s)
        lim = engaged(self.limits, nut(free))
        assert lim is not None  # the free step ran past a finite end (non-finite ones were refused above)
        compliance = m.geo.lead_per_rad_m**2 * 0.5 * m.dt_s**2 / self._contact_inertia()
        x0, v0 = m.nut_motion(before)  # the nut's position and velocity at the step's start
        with m.in_contact(before.screw_speed_rad_s * speed(free) < 0.0):
            f, res = solve_stop(lim, m.dt_s, x0, free, advance, nut, compliance, v0)
        if not math.isfinite(nut(res)):
            raise non_finite_error(self.model.name, end_time_s)
        self.force_n = f
        return res

    def _model_at(self, halvings: int) -> Model:
        """The screw model at dt/2**halvings (built on first use, kept)."""
        if halvings == 0:
            return self.model
        m = self._halved.get(halvings)
        if m is None:
            m = self._halved[halvings] = build_model(self.params, self.model.name,
                                                     math.ldexp(self.model.dt_s, -halvings), self.kernel)
        return m

    def _contact_inertia(self) -> float:
        """The screw-side inertia (kg·m²) behind the end solve's first guess of the nut's compliance over a step:
        the model's own mass matrix where it has one, else probed from rest (`probe_inertia`). Without it the
        first trial force was the law's at the free end (an `elastic` screw at 43 ms, 2.8 MN), which carried the
        nut metres past the screw's bearing, where no chain law holds."""
        if self._inertia is None:
            j = self.model.kinetic[0]
            self._inertia = j if math.isfinite(j) and j > 0 else probe_inertia(self.model, self.model.dt_s)
        return self._inertia
