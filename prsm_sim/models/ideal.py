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
trapezoidal rule, which makes the step's work balance exactly with ΔT, except on a step
that reverses the screw at a step too long to resolve an end's contact: there by backward
Euler (L-stable, so the unresolved ringing dies instead of flipping ω_S every step), its
numerical dissipation booked.
"""

from __future__ import annotations

import math

import numpy as np

from prsm_sim.errors import InputError
from prsm_sim.models.drag import ideal_no_load_torque_nm
from prsm_sim.models.elastic import sliding_efficiencies
from prsm_sim.params import END_STOP_STIFFNESS_N_M, Params
from prsm_sim.physics.inertia import reflected_inertia
from prsm_sim.physics.kinematics import ideal_carrier_ratio, ideal_speed_ratio
from prsm_sim.stepping.model import Model

__all__ = ["Ideal", "reflected_inertia"]  # reflected_inertia stays importable here (its home: physics.inertia)


class Ideal(Model):
    name = "ideal"
    takes_efficiencies = True

    @classmethod
    def closed_form_steady_state(cls, params: Params, *, screw_speed_rad_s: float | None = None,
                                 torque_nm: float | None = None, load_n: float | None = None) -> dict | None:
        """Steady rolling at a screw speed: τ = τ_L/η_f forward, τ_L η_b backward, plus b ω (the model's
        own efficiency law, LossyGear's modes; no fading: steady power is above its threshold), plus the drag's
        no-load torque T₀ against the motion."""
        if torque_nm is not None:
            raise InputError(f"torque_nm = {torque_nm!r}: the ideal model's steady state is given by a speed")
        w = params.loads.screw_speed_rad_s if screw_speed_rad_s is None else screw_speed_rad_s
        f = params.loads.nut_load_n if load_n is None else load_n
        il = params.ideal
        tau_l = f * params.geometry.lead_per_rad_m
        forward = tau_l * w >= 0
        tau = tau_l / il.efficiency_forward if forward else tau_l * il.efficiency_backward
        tau += il.viscous_nm_s_rad * w
        geo = params.geometry
        tau += math.copysign(ideal_no_load_torque_nm(params, sliding_efficiencies(geo, params.friction.mu_screw_roller)[0]),
                             w) if w != 0.0 else 0.0
        return {"method": "closed form (efficiency law)", "screw_speed_rad_s": w, "carrier_over_screw": 1.0 / ideal_speed_ratio(params.geometry),
                "speed_ratio_screw_over_carrier": ideal_speed_ratio(params.geometry), "torque_nm": tau,
                "load_force_n": f,
                "efficiency": (tau_l * w) / (tau * w) if tau * w > 0 and tau_l * w > 0 else math.nan}

    def __init__(self, params: Params, dt_s: float) -> None:
        super().__init__(params, dt_s)
        self.J = reflected_inertia(params)
        self.kinetic = (self.J, 0.0, 0.0)  # energy guard: carrier and rollers are in J (ideal ratio)
        self.k_carrier = ideal_carrier_ratio(self.geo)
        il = params.ideal
        self.k_forward = 1.0 / il.efficiency_forward - 1.0
        self.k_backward = 1.0 - il.efficiency_backward
        self.self_locking = il.efficiency_backward <= 0.0
        self.slip_per_nut_speed = 1.0 / math.sin(self.geo.flank_angle_rad)  # docs/model.md §3 sliding
        # The trapezoidal rule is not L-stable: a contact the step does not resolve (h ω > 2, ω = √(k/m) of the
        # nut's reflected mass on the stop) rings in its spurious mode, ω_S flipping sign every step with the
        # nut at rest (eigenvalue → −1 as h ω → ∞; the stop absorbs only ~16/(h ω)² of it per step), and a
        # rigid screw has no damping of its own to end it. At such steps a step that reverses the screw is
        # taken by backward Euler (L-stable: the ringing dies within a step, as a contact damped at ζ ≈ 0.5
        # does within a few ms); at steps that resolve the ends' default contact it stays trapezoidal
        # (second order, no numerical loss on a resolved bounce).
        omega_end = math.sqrt(END_STOP_STIFFNESS_N_M * self.geo.lead_per_rad_m**2 / self.J)
        self.reverses_l_stable = self.dt_s * omega_end > 2.0
        # the drag's equivalent no-load torque (`models.drag`): a Coulomb torque that holds at rest like the loss
        self.no_load_torque_nm = ideal_no_load_torque_nm(
            params, sliding_efficiencies(self.geo, params.friction.mu_screw_roller)[0])

    def _make_step(self):
        """The step: the step law (`_step_law`) and the ledger."""
        p, s = self.geo.lead_per_rad_m, self.slip_per_nut_speed
        finish = self.finisher(lambda w_s, w_c, aux: abs(w_s) * p * s, lambda w_s, w_c, aux: _EMPTY)
        solve, k, half_j = self._step_law(), self.k_carrier, 0.5 * self.J

        def step(x, torque_nm: float, load_n: float):
            w1, dtheta, dissipated = solve(x[2], torque_nm, load_n)
            # stored energy ½ J ω_S² (`stored_energy_j` with kinetic = (J, 0, 0); ×½ is exact)
            return finish(x, x[1] + dtheta, w1, x[3] + k * dtheta, k * w1, torque_nm, load_n, dissipated,
                          half_j * w1 * w1)
        return step

    def _step_law(self):
        """The step law, ``solve(ω_S at the start, τ, F) -> (ω_S at the end, Δθ_S, dissipated work)``,
        as a closure over the constants.

        Mesh loss for motion in direction d = ±1 with the load torque τ_L = F L/2π: |τ_L| (1/η_f − 1)
        rolling forward (d τ_L ≥ 0), |τ_L| (1 − η_b) backward, faded by tanh(|τ_L ω|/P_th) except
        when backward and self-locking (then a stiction that holds the screw); plus the drag's no-load torque
        T₀ (`models.drag.ideal_no_load_torque_nm`), not faded: a Coulomb torque that holds the screw at rest.
        """
        h, J = self.dt_s, self.J
        b = self.params.ideal.viscous_nm_s_rad
        p = self.geo.lead_per_rad_m
        j_hb = J + h * b
        k_forward, k_backward, self_locking = self.k_forward, self.k_backward, self.self_locking
        t0 = self.no_load_torque_nm
        power_threshold_w = self.params.ideal.power_threshold_w
        tanh, copysign = math.tanh, math.copysign
        l_stable = self.reverses_l_stable

        def loss(d: float, tau_l: float, w: float) -> float:
            """The mesh loss and no-load torque opposing motion in direction d (N·m, ≥ 0)."""
            forward = d * tau_l >= 0.0
            mu = abs(tau_l) * (k_forward if forward else k_backward)
            if forward or not self_locking:
                mu *= tanh(abs(tau_l * w) / power_threshold_w)
            return mu + t0

        stopped = self._stop_law(loss)

        def solve(w0: float, torque_nm: float, load_n: float) -> tuple[float, float, float]:
            tau_l = load_n * p
            w_free = (J * w0 + h * (torque_nm - tau_l)) / j_hb
            if w_free == 0.0:
                w1 = 0.0
            else:
                d = copysign(1.0, w_free)
                w_slide = w_free - d * h * loss(d, tau_l, w_free) / j_hb
                w1 = w_slide if w_slide * d > 0.0 else 0.0  # the loss can stop the screw, never reverse it
            # the screw stops within the step (and rests, or turns back): event-located (`stopped`), so the turn
            # is continuous in ω₀ across the edges of stopping; a reversal at a step too long for an end's contact
            # is backward Euler instead (below)
            if w0 != 0.0 and w1 * w0 <= 0.0 and not (l_stable and w1 != 0.0):
                return stopped(w0, w_free, torque_nm - tau_l, tau_l)
            # loss + bearing torque actually applied over the step
            friction_nm = (torque_nm - tau_l) - J * (w1 - w0) / h
            if w0 * w1 >= 0.0 or not l_stable:
                dtheta = 0.5 * h * (w0 + w1)
                return w1, dtheta, friction_nm * dtheta
            # reversed within a step too long for an end's contact: backward Euler (see `reverses_l_stable`);
            # its numerical dissipation ½ J (ω₁ − ω₀)² (the trapezoid's work balance less its own) is booked,
            # so the ledger still closes exactly
            dtheta = h * w1
            dw = w1 - w0
            return w1, dtheta, friction_nm * dtheta + 0.5 * J * dw * dw

        return solve

    def _stop_law(self, loss):
        """``stopped(ω₀, ω_free, τ_net, τ_L) -> (ω_S at the end, Δθ_S, dissipated work)`` of a step in which the
        screw comes to rest (`_step_law`; `loss(d, τ_L, ω)`: the loss opposing motion in direction d)."""
        h, J, b = self.dt_s, self.J, self.params.ideal.viscous_nm_s_rad
        copysign, half_j = math.copysign, 0.5 * self.J

        def stopped(w0: float, w_free: float, net_nm: float, tau_l: float) -> tuple[float, float, float]:
            """(ω_S at the end, Δθ_S, dissipated work) of a step in which the screw, turning at ω₀, comes to rest.

            Event-located: until it stops the loss opposes the motion it had (direction d₀ of ω₀, not that of
            the free end speed, which a reversing torque points the other way; its size, faded or not, at the
            free end speed as a whole step's is, so t* = h exactly where sliding on would end at rest), so the
            screw decelerates by D = loss(d₀) − d₀ τ_net and rests at t* = J|ω₀|/D (≤ h), having turned ½ ω₀ t*
            (the bearing's viscous torque acts on the end speed, as in the whole step: zero at rest). From rest
            it turns back over the rest of the step, r = h − t*, where the net torque exceeds the loss it meets
            (taken at the free speed r τ_net/(J + r b) and clipped at rest, as a whole step's is, so the end
            speed is continuous where turning back begins): ω₁ = (r τ_net − d₁ r loss(d₁))/(J + r b), turning
            ½ ω₁ r more. The dissipation is the step's balance, τ_net Δθ + ½ J (ω₀² − ω₁²): until the stop
            ½ J ω₀² loss/D ≥ 0, after it ½ ω₁ r (d₁ loss + b ω₁) ≥ 0 (a trapezoid over the whole step instead
            turned ½ (ω₀ + ω₁) h while the loss pushed back the other way, and booked the energy a reversing
            torque took from the screw as negative dissipation). The turn is then continuous in ω₀ across
            every edge: sliding on, resting, turning back."""
            d0 = copysign(1.0, w0)
            decel = loss(d0, tau_l, w_free) - d0 * net_nm
            t_stop = min(h, J * abs(w0) / decel) if decel > 0.0 else h
            dtheta = 0.5 * w0 * t_stop
            w1, r = 0.0, h - t_stop
            if r > 0.0 and net_nm != 0.0:
                j_rb = J + r * b
                w_back = r * net_nm / j_rb
                d1 = copysign(1.0, w_back)
                w1 = w_back - d1 * r * loss(d1, tau_l, w_back) / j_rb
                if w1 * d1 <= 0.0:
                    w1 = 0.0
                dtheta += 0.5 * w1 * r
            return w1, dtheta, net_nm * dtheta + half_j * (w0 * w0 - w1 * w1)

        return stopped


_EMPTY = np.zeros(0)
