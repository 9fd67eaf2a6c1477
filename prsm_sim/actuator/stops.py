"""Stiff, damped end stops on the nut, treated implicitly over a step (issue 14).

A penalty contact F = k δ + c δ' on penetration δ beyond a stroke limit, never pulling.
Explicitly a 1e8 N/m stop on a nut reflecting ~100 kg oscillates at ~1000 rad/s, at the edge
of stability at 1 ms; so the force held over the step is solved with the nut's end-of-step
speed, using the screw's linear response ω1 = ω_free − (h p / J) F_stop (backward Euler on the
contact, trapezoidal on the position, as the models advance the angle).
"""

from __future__ import annotations

from prsm_sim.actuator.params import StopParams


def stop_force(stops: StopParams, x0_m: float, v0_m_s: float, v_free_m_s: float, h_s: float,
               compliance_m_s_n: float) -> float:
    """Stop force on the nut held over the step, signed along +x_nut (N; 0 out of contact).

    `v_free_m_s`: nut speed at the end of the step without the stop; `compliance_m_s_n`:
    ∂v1/∂F = h p² / J (the nut's speed change per newton held over the step).
    Penetration at the end of the step: δ1 = δ0 + ½ h (v0 + v1) into the stop.
    """
    k, c = stops.stiffness_n_m, stops.damping_n_s_m
    out = 0.0
    for limit, sign in ((stops.max_position_m, 1.0), (stops.min_position_m, -1.0)):
        if limit is None:
            continue
        d0 = sign * (x0_m - limit)  # penetration, > 0 inside the stop
        u0, uf = sign * v0_m_s, sign * v_free_m_s  # speeds into the stop
        if d0 + 0.5 * h_s * (u0 + uf) <= 0.0:
            continue  # no contact even without the stop's force
        # F = k (d0 + ½h(u0 + u1)) + c u1,  u1 = uf − C F  (F pushes out of the stop)
        cc = compliance_m_s_n
        f = (k * (d0 + 0.5 * h_s * (u0 + uf)) + c * uf) / (1.0 + (0.5 * h_s * k + c) * cc)
        if f > 0.0:
            out += -sign * f
    return out


def stop_penetration(stops: StopParams, x_m: float) -> float:
    """Penetration beyond either limit (m, ≥ 0)."""
    d = 0.0
    if stops.max_position_m is not None:
        d = max(d, x_m - stops.max_position_m)
    if stops.min_position_m is not None:
        d = max(d, stops.min_position_m - x_m)
    return d


def stop_stored_j(stops: StopParams, x_m: float) -> float:
    """Elastic energy in the stop, ½ k δ² (J)."""
    d = stop_penetration(stops, x_m)
    return 0.5 * stops.stiffness_n_m * d * d
