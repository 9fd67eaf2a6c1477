"""The motor and its current loop over one sub-step, with the electrical energy it draws.

Equivalent first-order current loop i' = ω_c (i_ref − i), stepped exactly for i_ref held over
the sub-step: i(t) = a + b e^(−ω_c t), a = i_ref, b = i0 − i_ref. The torque applied to the
mechanics over the sub-step is k_t times the mean current. Winding voltage
u = R i + L i' + k_t ω_m, so the electrical energy over the sub-step is
R ∫i² dt + ½ L (i1² − i0²) + k_t ī Δθ_m (the last term: the work the held torque does).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from prsm_sim.actuator.params import MotorParams


class CurrentStep(NamedTuple):
    current_a: float  # at the end of the sub-step
    mean_current_a: float
    copper_j: float  # R ∫ i² dt
    magnetic_j: float  # ½ L (i1² − i0²)


def current_step(motor: MotorParams, i0_a: float, i_ref_a: float, h_s: float) -> CurrentStep:
    """Advance the current loop over `h_s` with the reference held (exact exponential)."""
    c = 2.0 * math.pi * motor.current_bandwidth_hz
    e = math.exp(-c * h_s)
    a, b = i_ref_a, i0_a - i_ref_a
    i1 = a + b * e
    mean = a + b * (1.0 - e) / (c * h_s)
    sq = a * a * h_s + 2.0 * a * b * (1.0 - e) / c + b * b * (1.0 - e * e) / (2.0 * c)
    return CurrentStep(i1, mean, motor.resistance_ohm * sq, 0.5 * motor.inductance_h * (i1 * i1 - i0_a * i0_a))


def current_reference(motor: MotorParams, screw_torque_nm: float, motor_speed_rad_s: float) -> float:
    """Current for a screw-side torque through the gear; no torque that drives the motor further past its speed limit."""
    i = screw_torque_nm / (motor.gear_ratio * motor.torque_constant_nm_a)
    if abs(motor_speed_rad_s) > motor.speed_limit_rad_s and i * motor_speed_rad_s > 0.0:
        return 0.0
    return i


def voltage(motor: MotorParams, step: CurrentStep, i0_a: float, motor_speed_rad_s: float, h_s: float) -> float:
    """Mean winding voltage over the sub-step, R ī + L Δi/h + k_t ω_m (V)."""
    return (motor.resistance_ohm * step.mean_current_a + motor.inductance_h * (step.current_a - i0_a) / h_s
            + motor.torque_constant_nm_a * motor_speed_rad_s)
