"""Named parameter sets (docs/model.md §1, "Presets")."""

from __future__ import annotations

from prsm_sim.params import DragParams, ElasticParams, Friction, Geometry, Loads, MassProperties, Material, ParamError, Params


def _jones2016() -> Params:
    """Jones, Velinsky, Lasky 2016 worked example, its radii read as diameters (docs/model.md §1).

    d_S = 19.5 mm, d_R = 6.5 mm (r_S = 3 r_R, the n = 5 standard design), 10 rollers × 40
    threads, c = 25 N·s/m per contact, moved mass 3000 kg, F_out = 100 N, steady 1 rad/s.
    """
    return Params(
        name="jones2016",
        geometry=Geometry(screw_radius_m=9.75e-3, roller_radius_m=3.25e-3, starts=5, pitch_m=1e-3,
                          n_rollers=10, n_teeth=40, flank_angle_deg=45.0),
        mass=MassProperties(moved_mass_kg=3000.0),
        friction=Friction(viscous_n_s_m=25.0),
        loads=Loads(nut_load_n=100.0, screw_speed_rad_s=1.0),
    )


def _jones2016_literal() -> Params:
    """The seed's numbers as printed: r_S = 19.5 mm, r_R = 5 mm.

    Not a consistent 5-start design (r_N / r_R = 5.9); its ideal ratio is 2.513, not the
    2.667 the seed reports. Kept so users can see the discrepancy (docs/model.md §1).
    """
    base = _jones2016()
    return Params.from_dict({"name": "jones2016_literal",
                             "geometry": {"screw_radius_m": 19.5e-3, "roller_radius_m": 5e-3,
                                          "nut_radius_m": None, "gear_ratio": None,
                                          "screw_length_m": None, "pin_radius_m": None},
                             "mass": {"screw_inertia_kgm2": None, "roller_mass_kg": None,
                                      "roller_inertia_kgm2": None, "carrier_inertia_kgm2": None},
                             "friction": {"drag_radius_m": None},
                             "elastic": {"bearing_position_m": None, "root_diameter_m": None,
                                         "nut_outer_diameter_m": None, "tooth_effective_width_m": None},
                             "ratings": {"static_load_rating_n": None, "dynamic_load_rating_n": None}},
                            base=base)


def _s30() -> Params:
    """A catalogue-sized standard 5-start design, d_S = 30 mm, lead 5 mm [assumed, docs/model.md §1].

    Elastic chain (docs/model.md §4.3): steel E = 206 GPa, ν = 0.3 (docs/model.md §1); screw fixed
    bearing 150 mm behind the nut's reference position and root diameter 27 mm (the shaft figure of
    docs/model.md §4.3, K ≈ 0.8 kN/µm); same-end mounting (a nut flange pushing on a load that the
    screw's bearing reacts, the usual actuator arrangement) [assumed]. Ratings: derived from the
    thread form (`physics.ratings`, docs/model.md "Ratings"): C_0a ≈ 281 kN by the ISO 76 line-contact
    criterion on flank-limited contacts, C_a by ISO 281's thrust roller formula with the f_c that
    reproduces a catalogue 30 × 5 size; the SRS-C line lists C_0a = 280 kN, C_a = 123 kN for its
    30 × 5 nut (docs/validation.md), which has a longer nut than this preset's 30 engaged teeth.
    Drag: a real screw's load-independent losses on, with their sourced defaults (docs/model.md §4.5:
    about 0.22 N·m at zero load); the friction stays the illustrative set of docs/model.md §4.2, through
    which the drag defaults were read. `drag.enabled: false` gives the papers' screw.
    """
    return Params(
        name="s30",
        geometry=Geometry(screw_radius_m=15e-3, roller_radius_m=5e-3, starts=5, pitch_m=1e-3,
                          n_rollers=10, n_teeth=30, flank_angle_deg=45.0, screw_length_m=0.3),
        mass=MassProperties(moved_mass_kg=50.0),
        friction=Friction(mu_screw_roller=0.05),
        loads=Loads(nut_load_n=5000.0, screw_speed_rad_s=100.0),
        material=Material(youngs_modulus_pa=206e9, poisson_ratio=0.3),
        elastic=ElasticParams(mounting="same_end", bearing_position_m=-0.15, root_diameter_m=0.027),
        drag=DragParams(enabled=True),
    )


PRESETS = {"jones2016": _jones2016, "jones2016_literal": _jones2016_literal, "s30": _s30}


def preset(name: str) -> Params:
    """A named, validated parameter set (docs/model.md §1, "Presets").

    Parameters
    ----------
    name : str
        One of `PRESETS`: ``"jones2016"`` (Jones 2016's worked example, radii read as
        diameters), ``"jones2016_literal"`` (its numbers as printed), ``"s30"`` (a catalogue-sized
        standard design).

    Returns
    -------
    Params
        A fresh parameter set with every derived value resolved.

    Raises
    ------
    ParamError
        An unknown name; the message lists the known ones.
    """
    try:
        return PRESETS[name]()
    except KeyError:
        raise ParamError(f"unknown preset {name!r}; known presets: {', '.join(PRESETS)}") from None
