"""Lead and reflected inertia of the drive train, against a hand calculation.

Independent numbers: the s30 preset's values put into the closed form by hand (kinetic energy
of each body at the ideal carrier ratio k = r_S / (2 (r_S + r_R)), Jones 2016 eq. 27 with the
migration term zero for the standard design g = n, docs/model.md §4.1), a motor rotor through an
ideal gear adding J_rotor N² (energy: ½ J_rotor (N ω)² = ½ (J_rotor N²) ω²), and the inertia the
actuator itself probes from its model's response to a torque (J = h / (∂ω/∂τ)).
"""

from __future__ import annotations

import math

import pytest

from prsm_sim import preset
from prsm_sim.actuator import Actuator, ActuatorParams, MotorParams
from prsm_sim.actuator.drive_train import lead_m, lead_per_rad_m, reflected_inertia_kgm2, reflected_mass_kg


def test_lead_of_s30():
    p = preset("s30")  # 5 starts, 1 mm pitch
    assert lead_m(p) == pytest.approx(5e-3, rel=1e-15)
    assert lead_per_rad_m(p) == pytest.approx(5e-3 / (2 * math.pi), rel=1e-15)


def hand_inertia_s30() -> float:
    # s30: r_S 15 mm, r_R 5 mm, 10 rollers, lead 5 mm, gear ratio 5 = starts (no migration coupling)
    p = preset("s30")
    m = p.mass
    k = 0.015 / (2 * (0.015 + 0.005))  # ω_C / ω_S = 0.375
    lead = 5e-3 / (2 * math.pi)
    screw = m.screw_inertia_kgm2
    axial = (50.0 + 10 * m.roller_mass_kg) * lead ** 2  # nut with its load and the rollers move with the nut
    carrier = m.carrier_inertia_kgm2 + 10 * (m.roller_mass_kg * 0.020 ** 2  # rollers orbit at a = 20 mm
                                             + m.roller_inertia_kgm2 * (1 - 5.0) ** 2)  # spin −g ω_C relative
    return screw + axial + carrier * k ** 2


def test_reflected_inertia_matches_the_hand_calculation():
    p = preset("s30")
    assert reflected_inertia_kgm2(p) == pytest.approx(hand_inertia_s30(), rel=1e-12)
    assert reflected_mass_kg(p) == pytest.approx(hand_inertia_s30() / (5e-3 / (2 * math.pi)) ** 2, rel=1e-12)


def test_motor_and_gear_add_the_rotor_times_the_ratio_squared():
    p = preset("s30")
    motor = MotorParams(rotor_inertia_kgm2=2e-4, gear_ratio=3.0)
    a = ActuatorParams(motor=motor)
    assert reflected_inertia_kgm2(p, a) == pytest.approx(hand_inertia_s30() + 2e-4 * 9.0, rel=1e-12)
    assert reflected_inertia_kgm2(p, ActuatorParams()) == pytest.approx(hand_inertia_s30(), rel=1e-12)
    # the actuator probes the inertia from its screw model's response (ideal: rigid lead, ideal ratio)
    probed = Actuator(p, 1e-3, "ideal", a).J
    assert probed == pytest.approx(reflected_inertia_kgm2(p, a), rel=1e-9)
