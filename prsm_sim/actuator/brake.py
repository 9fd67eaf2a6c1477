"""Holding brake on the screw shaft: engage/release ramps and a set-valued friction torque."""

from __future__ import annotations

from prsm_sim.actuator.params import BrakeParams


def brake_level(brake: BrakeParams, level: float, engaged: bool, dt_s: float) -> float:
    """Brake level in [0, 1] after `dt_s`: ramps linearly to 1 over engage_time_s, to 0 over release_time_s."""
    if engaged:
        return 1.0 if brake.engage_time_s == 0.0 else min(1.0, level + dt_s / brake.engage_time_s)
    return 0.0 if brake.release_time_s == 0.0 else max(0.0, level - dt_s / brake.release_time_s)


def stiction_torque(capacity_nm: float, w_free_rad_s: float, inertia_kgm2: float, h_s: float) -> float:
    """The torque (|τ| ≤ capacity) that stops the screw within the step, or the capacity against its motion.

    A dry friction (brake pads, a jam) is set-valued: it holds when the torque needed to stop
    the shaft, −J ω_free / h, is within the capacity, else slips at the capacity. Solved on the
    screw's linear response; `Actuator` corrects once with the model's actual end speed.
    """
    if capacity_nm <= 0.0:
        return 0.0
    need = -inertia_kgm2 * w_free_rad_s / h_s
    return max(-capacity_nm, min(capacity_nm, need))
