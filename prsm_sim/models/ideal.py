"""The `ideal` model: a rigid lead with direction-dependent efficiency (docs/model.md §4, `ideal` row).

The parameter set of Simscape's Leadscrew block and Modelica's LossyGear (`IdealLoss`):
forward efficiency η_f when the screw drives the load, backward efficiency η_b when the load
drives the screw, a viscous bearing loss, and self-locking when η_b ≤ 0.

With the load torque τ_L = F L/2π (positive resisting positive motion), the mesh loss is a
friction torque opposing motion of magnitude |τ_L| (1/η_f − 1) in forward rolling and
|τ_L| (1 − η_b) in backward rolling (LossyGear's forward/backward modes). Below the power
threshold the loss fades as tanh(|P|/P_th) (Simscape's smoothing of the efficiency factor);
a self-locking backward loss is not faded, it is a stiction that holds the screw.

Integration: the loss is applied as a set-valued friction in an implicit step (velocity
clipped at zero when the loss impulse exceeds the momentum), so stuck, forward and
backward modes need no event detection at a fixed step; positions advance by the
trapezoidal rule, which makes the step's work balance exactly with ΔT.
"""

from __future__ import annotations

import math

import numpy as np

from prsm_sim.physics.inertia import mass_matrix
from prsm_sim.physics.kinematics import ideal_carrier_ratio
from prsm_sim.models.base import Model
from prsm_sim.outputs import State
from prsm_sim.params import Params


def reflected_inertia(params: Params) -> float:
    """Inertia at the screw with the carrier and rollers moving at the ideal ratio."""
    M = mass_matrix(params)
    k = ideal_carrier_ratio(params.geometry)
    return float(M[0, 0] + 2 * M[0, 1] * k + M[1, 1] * k * k)


class Ideal(Model):
    name = "ideal"

    def __init__(self, params: Params, dt_s: float) -> None:
        super().__init__(params, dt_s)
        self.J = reflected_inertia(params)
        self.kinetic = (self.J, 0.0, 0.0)  # energy guard: carrier and rollers are in J (ideal ratio)
        self._half_j = 0.5 * self.J
        self.k_carrier = ideal_carrier_ratio(self.geo)
        il = params.ideal
        self.k_forward = 1.0 / il.efficiency_forward - 1.0
        self.k_backward = 1.0 - il.efficiency_backward
        self.self_locking = il.efficiency_backward <= 0.0
        self.slip_per_nut_speed = 1.0 / math.sin(self.geo.flank_angle_rad)  # docs/model.md §3 sliding
        p, s = self.geo.lead_per_rad_m, self.slip_per_nut_speed
        self._packed_k = self.packed_constants(lambda w_s, w_c: abs(w_s) * p * s, lambda w_s, w_c: _EMPTY)

    def loss_limit_nm(self, load_torque_nm: float, direction: float, speed_rad_s: float) -> float:
        """Mesh-loss torque magnitude for motion in `direction` (±1) at `speed_rad_s`."""
        forward = direction * load_torque_nm >= 0.0
        k = self.k_forward if forward else self.k_backward
        loss = abs(load_torque_nm) * k
        if not forward and self.self_locking:
            return loss
        return loss * math.tanh(abs(load_torque_nm * speed_rad_s) / self.params.ideal.power_threshold_w)

    packed = True

    def _solve(self, w0: float, torque_nm: float, load_n: float) -> tuple[float, float, float]:
        """Speed at the end of the step, the angle over it and the work dissipated (the one step law)."""
        h, J = self.dt_s, self.J
        b = self.params.ideal.viscous_nm_s_rad
        tau_l = load_n * self.geo.lead_per_rad_m
        w_free = (J * w0 + h * (torque_nm - tau_l)) / (J + h * b)
        if w_free == 0.0:
            w1 = 0.0
        else:
            d = math.copysign(1.0, w_free)
            mu = self.loss_limit_nm(tau_l, d, w_free)
            w_slide = w_free - d * h * mu / (J + h * b)
            w1 = w_slide if w_slide * d > 0.0 else 0.0  # the loss can stop the screw, never reverse it
        dtheta = 0.5 * h * (w0 + w1)
        # loss + bearing torque actually applied over the step, times the angle it acted through
        friction_nm = (torque_nm - tau_l) - J * (w1 - w0) / h
        return w1, dtheta, friction_nm * dtheta

    def _advance(self, state: State, torque_nm: float, load_n: float):
        w1, dtheta, dissipated = self._solve(state.screw_speed_rad_s, torque_nm, load_n)
        after = State(screw_angle_rad=state.screw_angle_rad + dtheta, screw_speed_rad_s=w1,
                      carrier_angle_rad=state.carrier_angle_rad + self.k_carrier * dtheta,
                      carrier_speed_rad_s=self.k_carrier * w1)
        slip = abs(w1) * self.geo.lead_per_rad_m * self.slip_per_nut_speed
        return self.finish_step(state, after, torque_nm, load_n, dissipated_j=dissipated, slip_speed_m_s=slip,
                                internal=_EMPTY)

    def advance_packed(self, x, torque_nm: float, load_n: float):
        """`_advance` on the packed state (Model.advance_packed); same arithmetic."""
        w1, dtheta, dissipated = self._solve(x[2], torque_nm, load_n)
        k = self.k_carrier
        # stored energy ½ J ω_S² (`stored_energy_j` with kinetic = (J, 0, 0); ×½ is exact)
        return self.finish_packed(x, x[1] + dtheta, w1, x[3] + k * dtheta, k * w1, torque_nm, load_n, dissipated,
                                  self._half_j * w1 * w1)


_EMPTY = np.zeros(0)
