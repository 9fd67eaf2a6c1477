"""The load-independent losses of a real screw (`DragParams`, docs/model.md §4.5), each law written once.

`fu2018` and `elastic` carry them in their step's constants (`kernels.Fu2018Constants`: the seal torque on
the screw, the film traction and the idle flanks' force at the screw–roller contacts); `ideal` takes their
steady sum at its own efficiency as an equivalent no-load torque (`ideal_no_load_torque_nm`).
"""

from __future__ import annotations

import math

from prsm_sim.params import NEEDLE_BEARING_MU, Params


def seal_torque_nm(params: Params) -> float:
    """Seal/wiper torque on the screw, N·m: T_s = n_seals · f′ · 2π r_S · r_S (a lip of friction f′ per metre
    of circumference sliding round the screw at its radius; the axial part of the slip, tan λ of it, is left
    out). Zero with the drag off."""
    d, r = params.drag, params.geometry.screw_radius_m
    return d.n_seals * d.seal_friction_n_per_m * 2.0 * math.pi * r * r if d.enabled else 0.0


def film_traction_n_s_per_m(params: Params) -> float:
    """Newtonian shear traction of the lubricant film at one screw–roller thread contact, N·s/m: c = η A / h
    with η = ρ ν (`friction.lubricant_*`), the wetted area A and the film thickness h. Zero with the drag off."""
    d, fr = params.drag, params.friction
    if not d.enabled:
        return 0.0
    return fr.lubricant_density_kg_m3 * fr.lubricant_viscosity_m2_s * d.film_area_m2 / d.film_thickness_m


def idle_flank_force_n(params: Params) -> float:
    """Axial force each flank set carries at zero external load (the internal preload P_i), N: the flanks
    that carry no net load still press with it. Zero with the drag off."""
    return params.drag.internal_preload_n if params.drag.enabled else 0.0


def pin_friction_coefficient(params: Params) -> float:
    """μ of the carrier pins at their radius: `friction.mu_pin` for a plain journal, a needle bearing's
    constant coefficient (SKF "Rolling bearings" 2016, table 1: 0.0020, moment ½ μ P d at the bore)."""
    return NEEDLE_BEARING_MU if params.drag.pin_bearing == "needle" else params.friction.mu_pin


def ideal_no_load_torque_nm(params: Params, sliding_efficiency_forward: float) -> float:
    """The `ideal` model's equivalent no-load torque, N·m: the seals plus the idle flanks' friction at the
    screw–roller sliding efficiency, T₀ = T_s + 2 P_i (L/2π)(1/η_f − 1) (both flank sets, docs/model.md §4.5).
    Zero with the drag off."""
    if not params.drag.enabled:
        return 0.0
    p = params.geometry.lead_per_rad_m
    return seal_torque_nm(params) + 2.0 * idle_flank_force_n(params) * p * (1.0 / sliding_efficiency_forward - 1.0)
