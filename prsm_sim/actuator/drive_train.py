"""The screw's lead and the inertia a torque at the screw accelerates, motor and gear included.

What a model-based gain needs (`prsm_sim.control`, a drive's bandwidth tuning, a controller of
one's own): the nut travel per screw radian, and the inertia reflected to the screw of every
moving part, with the carrier and rollers at the ideal (pure rolling) carrier ratio
(docs/model.md §2, §4.1):

    J = J_S + (m_nut + n_R m_R) p² + 2 J_SC k + J_C k²   (+ J_rotor N² with a motor)

p = L/2π the lead per radian, k = ω_C/ω_S = r_S / (2 (r_S + r_R)), J_S, J_SC, J_C the entries of
the model's mass matrix, and with a motor through a gear of N motor turns per screw turn its
rotor reflected as J_rotor N². The same sum the actuator uses for a rigidly coupled motor; with
a compliant coupling the rotor is a separate body, and the figure is the inertia at low
frequency, below the coupling's resonance.
"""

from __future__ import annotations

from prsm_sim.actuator.params import ActuatorParams
from prsm_sim.physics.inertia import reflected_inertia
from prsm_sim.params import Params


def lead_m(params: Params) -> float:
    """Nut travel per screw turn L = n P (m)."""
    return params.geometry.lead_m


def lead_per_rad_m(params: Params) -> float:
    """Nut travel per screw radian p = L / 2π (m/rad): the nut force F and screw torque relate as τ = p F."""
    return params.geometry.lead_per_rad_m


def motor_inertia_at_screw_kgm2(actuator: ActuatorParams | None) -> float:
    """The motor's rotor reflected to the screw through its gear, J_rotor N² (0 without a motor)."""
    m = actuator.motor if actuator is not None else None
    return 0.0 if m is None else m.rotor_inertia_kgm2 * m.gear_ratio ** 2


def reflected_inertia_kgm2(params: Params, actuator: ActuatorParams | None = None) -> float:
    """Inertia at the screw of the whole drive train (kg·m²): screw, nut and load mass, rollers and
    carrier at the ideal ratio, and the actuator's motor rotor through its gear when one is fitted."""
    return reflected_inertia(params) + motor_inertia_at_screw_kgm2(actuator)


def reflected_mass_kg(params: Params, actuator: ActuatorParams | None = None) -> float:
    """The same inertia seen at the nut: J / p² (kg), the mass a nut-side force accelerates."""
    return reflected_inertia_kgm2(params, actuator) / lead_per_rad_m(params) ** 2
