"""Frozen, validated parameter records (docs/model.md §1), SI units, unit in the name.

Each group validates itself where it is built and names the field, the value and what is
allowed. Optional quantities (nut radius, gear ratio, masses and inertias) are derived from
the geometry and density when left as None, and stored resolved, so a saved parameter set
reproduces the run exactly.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, field, fields, replace
from functools import cached_property
from typing import Any, NamedTuple

from prsm_sim.errors import ParamError
from prsm_sim.physics.ratings import ISO76_LINE_CONTACT_PRESSURE_PA, dynamic_load_rating_n, static_load_rating_n


def check_field(group: str, name: str, value: Any, ok: bool, allowed: str) -> None:
    """ParamError naming the field, its value and what is allowed, unless `ok`."""
    if not ok:
        raise ParamError(f"{group}.{name} = {value!r}: {allowed}")


def is_finite_number(v: Any) -> bool:
    """A finite int or float (bool excluded)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_positive(group: str, obj: Any, *names: str) -> None:
    """`check_field` for each named attribute of `obj`: a finite number > 0."""
    for n in names:
        v = getattr(obj, n)
        check_field(group, n, v, is_finite_number(v) and v > 0, "must be a finite number > 0")


def check_non_negative(group: str, obj: Any, *names: str) -> None:
    """`check_field` for each named attribute of `obj`: a finite number >= 0."""
    for n in names:
        v = getattr(obj, n)
        check_field(group, n, v, is_finite_number(v) and v >= 0, "must be a finite number >= 0")


def _set(obj: Any, name: str, value: Any) -> None:
    object.__setattr__(obj, name, value)


# Thread form: tooth height per pitch. A roller-screw catalogue's screw outer and root diameters
# differ by 0.8 P in every row (docs/validation/data/srs_c_roller_screws.csv; docs/model.md "Thread form").
TOOTH_HEIGHT_PER_PITCH = 0.4
# f_c of the dynamic rating (physics.ratings): the value that gives the SRS-C 30 × 5 row's C_a = 123 kN
# with the datasheet rules of prsm_sim.datasheet (docs/model.md "Ratings").
DYNAMIC_FACTOR_DEFAULT = 164.6


@dataclass(frozen=True)
class Geometry:
    """Thread and carrier geometry (docs/model.md §1). Radii are pitch (nominal) radii.

    Attributes
    ----------
    screw_radius_m, roller_radius_m : float
        Pitch radii r_S and r_R, m.
    starts : int
        Starts n of screw and nut (≥ 3); rollers are single-start. Lead L = n P.
    pitch_m : float
        Thread pitch P, m, the same on screw, roller and nut.
    n_rollers, n_teeth : int
        Rollers N_R (≥ 3, as many as fit on the pin circle) and engaged teeth N_T per roller and side.
    flank_angle_deg : float, default 45
        Flank angle β in the axial section, degrees, in (0, 90).
    nut_radius_m : float, optional
        Pitch radius r_N, m; default r_S + 2 r_R (planetary fit).
    gear_ratio : float, optional
        Ring/spur gear tooth ratio g; default r_N / r_R (no roller migration, docs/model.md §2).
    screw_length_m : float, optional
        Threaded screw length, m (its inertia, the thread ends); default 4 × the threaded roller length.
    pin_radius_m : float, optional
        Roller journal radius in the carrier, m (pin friction lever); default r_R / 2.
    nut_length_m : float, optional
        Threaded nut length, m; default n_teeth × pitch.
    thread_ends : bool, default True
        The nut stays on the threads: x = 0 is the nut centred on the screw, and a stiff, damped
        stop (the actuator's stop law) holds it within ±(screw_length_m − nut_length_m)/2.
        False removes the ends (a screw of unlimited length); the lengths move them.
    tooth_height_per_pitch : float, default 0.4
        Thread form: radial tooth height h_t (root to crest) per pitch, so h_t = 0.4 P by default (the
        screw thread depth of a roller-screw catalogue, docs/model.md "Thread form"); at most the
        sharp V's depth 1 / (2 tan β). Sets the tooth compliance and, with the next, the ratings.
    flank_contact_fraction : float, default 1
        Thread form: the fraction of the straight flank (h_t / cos β along its generator in the
        axial section) a contact can spread over, in (0, 1]; ℓ_f = fraction × h_t / cos β is what
        limits a contact's size on the flank (`physics.ratings`). The contact point itself stays
        where docs/model.md §3 puts it (roller profile radius r_R / sin β).

    Raises
    ------
    ParamError
        A value out of range; the message names the field, the value and what is allowed.
    """

    screw_radius_m: float
    roller_radius_m: float
    starts: int
    pitch_m: float
    n_rollers: int
    n_teeth: int
    flank_angle_deg: float = 45.0
    # Derived where not given: None on input, a float in every built instance (`__post_init__` fills
    # it), so the fields are typed as what a reader gets
    nut_radius_m: float = None  # type: ignore[assignment]  # default r_S + 2 r_R (planetary fit)
    gear_ratio: float = None  # type: ignore[assignment]  # ring/spur tooth ratio g; default r_N / r_R (no migration)
    screw_length_m: float = None  # type: ignore[assignment]  # default 4 × the threaded roller length
    pin_radius_m: float = None  # type: ignore[assignment]  # roller journal radius in the carrier; default r_R / 2
    nut_length_m: float = None  # type: ignore[assignment]  # threaded nut length; default n_teeth × pitch
    thread_ends: bool = True  # the nut stops at ±(screw_length_m − nut_length_m)/2 (False: no ends)
    tooth_height_per_pitch: float = TOOTH_HEIGHT_PER_PITCH  # thread form: h_t / P (root to crest)
    flank_contact_fraction: float = 1.0  # share of the straight flank h_t / cos β a contact can span

    def __post_init__(self) -> None:
        g = "geometry"
        check_positive(g, self, "screw_radius_m", "roller_radius_m", "pitch_m")
        # starts >= 3: the planetary fit r_S = (n − 2) r_R needs it (docs/model.md §1)
        for n, lo in (("starts", 3), ("n_rollers", 3), ("n_teeth", 1)):
            v = getattr(self, n)
            check_field(g, n, v, isinstance(v, int) and not isinstance(v, bool) and v >= lo,
                   f"must be a whole number >= {lo}")
        fa = self.flank_angle_deg
        check_field(g, "flank_angle_deg", fa, is_finite_number(fa) and 0 < fa < 90, "must lie in (0, 90) degrees")
        if self.nut_radius_m is None:
            _set(self, "nut_radius_m", self.screw_radius_m + 2 * self.roller_radius_m)
        check_positive(g, self, "nut_radius_m")
        check_field(g, "nut_radius_m", self.nut_radius_m, self.nut_radius_m > self.screw_radius_m + self.roller_radius_m,
               f"must exceed screw + roller radius ({self.screw_radius_m + self.roller_radius_m:g} m)")
        if self.gear_ratio is None:
            _set(self, "gear_ratio", self.nut_radius_m / self.roller_radius_m)
        check_positive(g, self, "gear_ratio")
        if self.screw_length_m is None:
            _set(self, "screw_length_m", 4 * self.n_teeth * self.pitch_m)
        if self.pin_radius_m is None:
            _set(self, "pin_radius_m", self.roller_radius_m / 2)
        if self.nut_length_m is None:
            _set(self, "nut_length_m", self.n_teeth * self.pitch_m)
        check_positive(g, self, "screw_length_m", "pin_radius_m", "nut_length_m")
        self._check_thread_form()
        check_field(g, "thread_ends", self.thread_ends, isinstance(self.thread_ends, bool), "must be true or false")
        if self.thread_ends:
            check_field(g, "nut_length_m", self.nut_length_m, self.nut_length_m < self.screw_length_m,
                        f"must be shorter than screw_length_m ({self.screw_length_m:g} m) while thread_ends is on")
        n_max = math.floor(math.pi / math.asin(min(1.0, self.roller_radius_m / self.carrier_radius_m)))
        check_field(g, "n_rollers", self.n_rollers, self.n_rollers <= n_max,
               f"at most {n_max} rollers of radius {self.roller_radius_m:g} m fit on the {self.carrier_radius_m:g} m pin circle")

    def _check_thread_form(self) -> None:
        g = "geometry"
        v_depth = 1 / (2 * math.tan(math.radians(self.flank_angle_deg)))
        v = self.tooth_height_per_pitch
        check_field(g, "tooth_height_per_pitch", v, is_finite_number(v) and 0 < v <= v_depth * (1 + 1e-12),
                    f"must lie in (0, {v_depth:.6g}] (the sharp V's depth 1 / (2 tan β))")
        v = self.flank_contact_fraction
        check_field(g, "flank_contact_fraction", v, is_finite_number(v) and 0 < v <= 1, "must lie in (0, 1]")

    @property
    def tooth_height_m(self) -> float:
        """Radial tooth height h_t from root to crest (thread form), m."""
        return self.tooth_height_per_pitch * self.pitch_m

    @property
    def flank_contact_length_m(self) -> float:
        """ℓ_f: the flank length, along its generator in the axial section, a contact can span, m."""
        return self.flank_contact_fraction * self.tooth_height_m / math.cos(self.flank_angle_rad)

    @property
    def flank_angle_rad(self) -> float:
        return math.radians(self.flank_angle_deg)

    @property
    def lead_m(self) -> float:
        """Screw (= nut) lead L = n P."""
        return self.starts * self.pitch_m

    @property
    def lead_per_rad_m(self) -> float:
        """L / 2π: nut travel per radian of screw rotation."""
        return self.lead_m / (2 * math.pi)

    @property
    def carrier_radius_m(self) -> float:
        """Roller centre distance a = r_S + r_R (carrier pin circle)."""
        return self.screw_radius_m + self.roller_radius_m

    @property
    def screw_lead_angle_rad(self) -> float:
        return math.atan(self.lead_m / (2 * math.pi * self.screw_radius_m))

    @property
    def roller_lead_angle_rad(self) -> float:
        return math.atan(self.pitch_m / (2 * math.pi * self.roller_radius_m))

    @property
    def nut_lead_angle_rad(self) -> float:
        return math.atan(self.lead_m / (2 * math.pi * self.nut_radius_m))

    @property
    def travel_m(self) -> float | None:
        """Nut travel on the threads, screw_length_m − nut_length_m (x = 0: the nut centred); None
        without thread ends."""
        return self.screw_length_m - self.nut_length_m if self.thread_ends else None

    @property
    def roller_length_m(self) -> float:
        """Threaded roller length: one pitch per engaged tooth."""
        return self.n_teeth * self.pitch_m


@dataclass(frozen=True)
class MassProperties:
    """Masses and inertias; None means derived from geometry and density (docs/model.md §1, Jones 2016 eq. 14).

    Attributes
    ----------
    moved_mass_kg : float
        Nut plus everything attached to it, kg.
    density_kg_m3 : float, default 7850
        Density for the derived masses and inertias, kg/m³.
    screw_inertia_kgm2, roller_mass_kg, roller_inertia_kgm2, carrier_inertia_kgm2 : float, optional
        kg·m², kg, kg·m², kg·m² (carrier: both plates); `Params` stores them resolved.
    """

    moved_mass_kg: float  # nut plus everything attached to it
    density_kg_m3: float = 7850.0
    screw_inertia_kgm2: float | None = None  # solid cylinder r_S over screw_length_m
    roller_mass_kg: float | None = None  # solid cylinder r_R over roller_length_m
    roller_inertia_kgm2: float | None = None  # m_R r_R² / 2 (Jones eq. 14)
    carrier_inertia_kgm2: float | None = None  # both carrier plates: annuli r_S..a+r_R/2, 2 mm thick

    def __post_init__(self) -> None:
        check_positive("mass", self, "moved_mass_kg", "density_kg_m3")
        check_non_negative("mass", self, *(n for n in ("screw_inertia_kgm2", "roller_mass_kg", "roller_inertia_kgm2",
                                                   "carrier_inertia_kgm2") if getattr(self, n) is not None))

    def resolved(self, geo: Geometry) -> MassProperties:
        """Fill every None from the geometry (the Params constructor calls this)."""
        v = self.values(geo)
        return replace(self, screw_inertia_kgm2=v.screw_inertia_kgm2, roller_mass_kg=v.roller_mass_kg,
                       roller_inertia_kgm2=v.roller_inertia_kgm2, carrier_inertia_kgm2=v.carrier_inertia_kgm2)

    def values(self, geo: Geometry) -> MassValues:
        """Every mass and inertia as a float, those not given derived from the geometry (`Params.resolved_mass`)."""
        rho = self.density_kg_m3
        js = self.screw_inertia_kgm2
        if js is None:
            ms = rho * math.pi * geo.screw_radius_m**2 * geo.screw_length_m
            js = ms * geo.screw_radius_m**2 / 2
        mr = self.roller_mass_kg
        if mr is None:
            mr = rho * math.pi * geo.roller_radius_m**2 * geo.roller_length_m
        jr = self.roller_inertia_kgm2 if self.roller_inertia_kgm2 is not None else mr * geo.roller_radius_m**2 / 2
        jc = self.carrier_inertia_kgm2
        if jc is None:
            r_in, r_out, t = geo.screw_radius_m, geo.carrier_radius_m + geo.roller_radius_m / 2, 2e-3
            jc = 2 * rho * math.pi * t * (r_out**4 - r_in**4) / 2
        return MassValues(moved_mass_kg=self.moved_mass_kg, density_kg_m3=rho, screw_inertia_kgm2=js,
                          roller_mass_kg=mr, roller_inertia_kgm2=jr, carrier_inertia_kgm2=jc)


class MassValues(NamedTuple):
    """The mass properties of a built `Params` (`Params.resolved_mass`), each a float: the group's
    fields with the derived ones filled (kg, kg/m³, kg·m²)."""

    moved_mass_kg: float
    density_kg_m3: float
    screw_inertia_kgm2: float
    roller_mass_kg: float
    roller_inertia_kgm2: float
    carrier_inertia_kgm2: float


CONTACT_EVALUATIONS = ("exact", "line_of_centres")
# the default contact stiffness of end stops and thread ends, N/m (`actuator.StopParams`; docs/model.md, end stop)
END_STOP_STIFFNESS_N_M = 1e8


@dataclass(frozen=True)
class Friction:
    """Friction and lubrication parameters of the `jones2016` and `fu2018` models (docs/model.md §4.1–4.2).

    `viscous_n_s_m` is Jones 2016's c, per screw–roller thread contact. `contact_evaluation`
    selects where the screw–roller slip is evaluated: at the exact tangency point (docs/model.md §3)
    or on the line of centres as the seed's equations (20), (28) do.

    Attributes
    ----------
    viscous_n_s_m : float
        Viscous coefficient c per screw–roller contact, N·s/m.
    contact_evaluation : str
        ``"exact"`` or ``"line_of_centres"``.
    mu_screw_roller : float
        Coulomb coefficient μ_SR at the screw–roller contacts (fu2018), in [0, 1).
    coulomb_regularisation_m_s : float
        ε in f = −μN v/√(|v|² + ε²), m/s.
    screw_roller_law : str
        fu2018's screw–roller law: ``"coulomb"`` or ``"viscous"`` (the Jones limit).
    mu_nut_roller_rolling : float
        Rolling-resistance coefficient μ_NR at the nut–roller contacts (moment μ_NR N r_R).
    mu_pin : float
        Pin friction coefficient (moment μ_pin |F_pin| r_pin).
    lubricant_viscosity_m2_s, lubricant_density_kg_m3 : float
        Kinematic viscosity ν, m²/s, and density ρ, kg/m³, for the carrier drag.
    drag_radius_m, drag_width_m, drag_gap_m : float
        Ring gear–carrier gap radius R (default r_N), width b and gap h, m (Couette drag).
    load_distribution : str
        ζ_T profile over the teeth: ``"uniform"`` or ``"exponential"``.
    load_distribution_decay : float
        Per-tooth decay rate d of the exponential profile, 1/tooth.
    """

    viscous_n_s_m: float = 25.0
    contact_evaluation: str = "exact"
    mu_screw_roller: float = 0.05
    coulomb_regularisation_m_s: float = 1e-4  # ε in f = −μN v/√(|v|²+ε²), docs/model.md §4.2
    screw_roller_law: str = "coulomb"  # fu2018: "coulomb" (Fu 2018) or "viscous" (Jones limit)
    mu_nut_roller_rolling: float = 0.002
    mu_pin: float = 0.05
    lubricant_viscosity_m2_s: float = 55e-6
    lubricant_density_kg_m3: float = 900.0
    drag_radius_m: float | None = None  # ring gear–carrier gap radius; default r_N
    drag_width_m: float = 5e-3
    drag_gap_m: float = 1e-4
    load_distribution: str = "uniform"  # ζ_T profile over the teeth: "uniform" or "exponential"
    load_distribution_decay: float = 0.05  # per-tooth decay rate of the "exponential" profile
    # fu2018: Coulomb friction where the nut–roller contact slides (g ≠ r_N/r_R: roller migration,
    # docs/model.md §2); the standard design rolls there and this does not act
    mu_nut_roller_sliding: float = 0.05

    def __post_init__(self) -> None:
        f = "friction"
        check_non_negative(f, self, "viscous_n_s_m", "mu_screw_roller", "mu_nut_roller_rolling", "mu_pin", "mu_nut_roller_sliding",
                      "lubricant_viscosity_m2_s", "lubricant_density_kg_m3", "load_distribution_decay")
        check_positive(f, self, "coulomb_regularisation_m_s", "drag_width_m", "drag_gap_m")
        if self.drag_radius_m is not None:
            check_positive(f, self, "drag_radius_m")
        check_field(f, "contact_evaluation", self.contact_evaluation, self.contact_evaluation in CONTACT_EVALUATIONS,
               f"must be one of {', '.join(CONTACT_EVALUATIONS)}")
        check_field(f, "screw_roller_law", self.screw_roller_law, self.screw_roller_law in ("coulomb", "viscous"),
               "must be one of coulomb, viscous")
        check_field(f, "load_distribution", self.load_distribution, self.load_distribution in ("uniform", "exponential"),
               "must be one of uniform, exponential")
        check_field(f, "mu_screw_roller", self.mu_screw_roller, self.mu_screw_roller < 1, "must be < 1")
        check_field(f, "mu_nut_roller_sliding", self.mu_nut_roller_sliding, self.mu_nut_roller_sliding < 1, "must be < 1")

    def drag_radius(self, geo: Geometry) -> float:
        """R of the carrier's Couette drag, m: `drag_radius_m` where given, else the nut's pitch radius r_N."""
        return geo.nut_radius_m if self.drag_radius_m is None else self.drag_radius_m


@dataclass(frozen=True)
class IdealLoss:
    """Loss parameters of the `ideal` model: Simscape Leadscrew / Modelica LossyGear set.

    `efficiency_backward <= 0` makes the screw self-locking: a load alone cannot back-drive it.

    Attributes
    ----------
    efficiency_forward : float
        η_f, screw → nut power transfer, in (0, 1].
    efficiency_backward : float
        η_b, nut → screw power transfer, in [−1, η_f]; ≤ 0 is self-locking.
    power_threshold_w : float
        P_th, W: below it the loss fades as tanh(|P|/P_th).
    viscous_nm_s_rad : float
        Screw bearing viscous torque per screw speed, N·m·s/rad.
    """

    efficiency_forward: float = 0.85  # screw → nut power transfer
    efficiency_backward: float = 0.80  # nut → screw power transfer
    power_threshold_w: float = 1.0  # below it the efficiency blends between the two directions
    viscous_nm_s_rad: float = 0.0  # screw bearing viscous torque per rad/s

    def __post_init__(self) -> None:
        g = "ideal"
        ef, eb = self.efficiency_forward, self.efficiency_backward
        check_field(g, "efficiency_forward", ef, is_finite_number(ef) and 0 < ef <= 1, "must lie in (0, 1]")
        check_field(g, "efficiency_backward", eb, is_finite_number(eb) and -1 <= eb <= 1, "must lie in [-1, 1] (<= 0: self-locking)")
        check_field(g, "efficiency_backward", eb, eb <= ef, f"must not exceed efficiency_forward ({ef})")
        check_positive(g, self, "power_threshold_w")
        check_non_negative(g, self, "viscous_nm_s_rad")


@dataclass(frozen=True)
class Loads:
    """Nominal operating point used by presets, scenarios and the steady-state command.

    Attributes
    ----------
    nut_load_n : float
        Nut load force, N, positive when it resists positive nut motion.
    screw_speed_rad_s : float
        Screw speed, rad/s.
    """

    nut_load_n: float = 100.0
    screw_speed_rad_s: float = 1.0

    def __post_init__(self) -> None:
        for n in ("nut_load_n", "screw_speed_rad_s"):
            v = getattr(self, n)
            check_field("loads", n, v, is_finite_number(v), "must be a finite number")


@dataclass(frozen=True)
class Material:
    """Elastic constants of screw, rollers and nut (one steel for all; density is `mass.density_kg_m3`).

    docs/model.md §1 steel default: E = 206 GPa, ν = 0.3.
    """

    youngs_modulus_pa: float = 206e9
    poisson_ratio: float = 0.3

    def __post_init__(self) -> None:
        check_positive("material", self, "youngs_modulus_pa")
        v = self.poisson_ratio
        check_field("material", "poisson_ratio", v, is_finite_number(v) and 0 <= v < 0.5, "must lie in [0, 0.5)")

    @property
    def shear_modulus_pa(self) -> float:
        return self.youngs_modulus_pa / (2 * (1 + self.poisson_ratio))


MOUNTINGS = ("same_end", "opposite_end")
TOOTH_MODELS = ("cantilever", "none")
PRELOAD_KINDS = ("none", "double_nut", "oversize_rollers")


@dataclass(frozen=True)
class ElasticParams:
    """Axial compliance chain of the `elastic` level and the `stiffness`/`modes` commands (docs/model.md §4.3).

    - `mounting`: where the load enters the nut relative to where the screw carries it away:
      "same_end" (screw in tension, nut in compression: the cosh distribution) or "opposite_end"
      (both in tension: the U-shaped one).
    - `bearing_position_m`: nut-coordinate position of the screw's fixed (thrust) bearing; the
      loaded shaft length is ℓ = |x_nut − bearing_position_m|. Default −screw_length_m / 2.
    - `root_diameter_m`: screw shaft section for EA/ℓ; default 2 r_S − 3 P (about 27 mm for `s30`,
      docs/model.md §4.3) [assumed].
    - `nut_outer_diameter_m`: nut body section (annulus to the nut pitch diameter) for its EA;
      default 1.4 × 2 r_N [assumed].
    - `housing_stiffness_n_per_m`: nut flange and housing in series; inf = rigid.
    - `tooth_model`: "cantilever" (bending + shear of screw, roller and nut teeth, docs/model.md §4.3)
      or "none"; `tooth_effective_width_m` the loaded tooth width per contact, default π r_R [assumed].
    - `contact_damping_ratio`: modal damping ratio of the axial contact mode [assumed].
    - `axial_clearance_m`: total axial play (backlash) of an unpreloaded nut, ≥ 0.
    - `preload_n`, `preload_kind`: two opposed flank sets pressed together by P₀ (double nut: two
      halves of N_T/2 teeth; oversize rollers: both flanks of all N_T teeth) or none.
    """

    mounting: str = "same_end"
    bearing_position_m: float | None = None
    root_diameter_m: float | None = None
    nut_outer_diameter_m: float | None = None
    housing_stiffness_n_per_m: float = math.inf
    tooth_model: str = "cantilever"
    tooth_effective_width_m: float | None = None
    contact_damping_ratio: float = 0.02
    axial_clearance_m: float = 0.0
    preload_n: float = 0.0
    preload_kind: str = "none"

    def __post_init__(self) -> None:
        g = "elastic"
        for name, allowed in (("mounting", MOUNTINGS), ("tooth_model", TOOTH_MODELS), ("preload_kind", PRELOAD_KINDS)):
            v = getattr(self, name)
            check_field(g, name, v, v in allowed, f"must be one of {', '.join(allowed)}")
        for n in ("root_diameter_m", "nut_outer_diameter_m", "tooth_effective_width_m"):
            if getattr(self, n) is not None:
                check_positive(g, self, n)
        if self.bearing_position_m is not None:
            v = self.bearing_position_m
            check_field(g, "bearing_position_m", v, is_finite_number(v), "must be a finite number")
        k = self.housing_stiffness_n_per_m
        check_field(g, "housing_stiffness_n_per_m", k, isinstance(k, (int, float)) and not isinstance(k, bool)
               and not math.isnan(k) and k > 0, "must be a number > 0 (inf: rigid)")
        check_non_negative(g, self, "contact_damping_ratio", "axial_clearance_m", "preload_n")
        check_field(g, "contact_damping_ratio", self.contact_damping_ratio, self.contact_damping_ratio < 1,
               "must lie in [0, 1)")
        check_field(g, "preload_kind", self.preload_kind, (self.preload_kind == "none") == (self.preload_n == 0),
               "must be none exactly when preload_n = 0 (double_nut or oversize_rollers need preload_n > 0)")
        check_field(g, "axial_clearance_m", self.axial_clearance_m, self.preload_n == 0 or self.axial_clearance_m == 0,
               "must be 0 for a preloaded nut (preload removes the play)")

    def resolved(self, geo: Geometry) -> ElasticParams:
        """Fill every None from the geometry (the Params constructor calls this)."""
        v = self.values(geo)
        out = replace(self, bearing_position_m=v.bearing_position_m, root_diameter_m=v.root_diameter_m,
                      nut_outer_diameter_m=v.nut_outer_diameter_m, tooth_effective_width_m=v.tooth_effective_width_m)
        check_positive("elastic", out, "root_diameter_m")
        check_field("elastic", "nut_outer_diameter_m", v.nut_outer_diameter_m,
                    v.nut_outer_diameter_m > 2 * geo.nut_radius_m,
                    f"must exceed the nut pitch diameter {2 * geo.nut_radius_m:g} m")
        return out

    def values(self, geo: Geometry) -> ElasticValues:
        """The lengths derived from the geometry where not given, each a float (`Params.resolved_elastic`)."""
        return ElasticValues(
            bearing_position_m=-geo.screw_length_m / 2 if self.bearing_position_m is None else self.bearing_position_m,
            root_diameter_m=2 * geo.screw_radius_m - 3 * geo.pitch_m if self.root_diameter_m is None
            else self.root_diameter_m,
            nut_outer_diameter_m=1.4 * 2 * geo.nut_radius_m if self.nut_outer_diameter_m is None
            else self.nut_outer_diameter_m,
            tooth_effective_width_m=math.pi * geo.roller_radius_m if self.tooth_effective_width_m is None
            else self.tooth_effective_width_m)


def _derived_lengths(e: ElasticParams, geo: Geometry) -> dict[str, None]:
    """The lengths of `e` that were derived from `geo` (not given), as None: a group built on `e` derives them
    again from its own geometry instead of holding the old screw's value (e.g. the nut body's outer diameter
    after a larger nut radius, which would else be refused as smaller than the new nut)."""
    given = e.values(geo)
    derived = replace(e, bearing_position_m=None, root_diameter_m=None, nut_outer_diameter_m=None,
                      tooth_effective_width_m=None).values(geo)
    return {name: None for name in ElasticValues._fields if getattr(given, name) == getattr(derived, name)}


class ElasticValues(NamedTuple):
    """The lengths of the elastic group a built `Params` holds (`Params.resolved_elastic`), each a float, m:
    the fields given, or derived from the geometry."""

    bearing_position_m: float
    root_diameter_m: float
    nut_outer_diameter_m: float
    tooth_effective_width_m: float



Elastic = ElasticParams  # the group's name before `ElasticParams` (the model is `ElasticModel`); an alias for one release

@dataclass(frozen=True)
class Ratings:
    """Basic axial load ratings of the nut (N): static C_0a and dynamic C_a, and the factors they come from.

    Either rating None: derived where Params is built from the geometry's thread form, the material
    and the factors below (`physics.ratings`, docs/model.md "Ratings"): C_0a as the axial load that
    takes the flank-limited thread contacts to the ISO 76 line-contact pressure, C_a by ISO 281's
    thrust roller bearing formula. A number given here is used as it stands (0 for C_a: not
    rated; life estimates need it).

    Attributes
    ----------
    static_load_rating_n, dynamic_load_rating_n : float or None
        The ratings, N; None derives them.
    static_contact_pressure_pa : float, default 4.0e9
        p₀ of the static rating: ISO 76:2006's 4000 MPa for roller (line) contacts.
    static_factor : float, default 1
        f_0, the static profile factor (a datasheet calibrates it).
    dynamic_factor : float
        f_c of ISO 281's thrust roller bearing formula (N, lengths in mm); the default is the value
        that reproduces a catalogue size (docs/model.md "Ratings").
    """

    static_load_rating_n: float | None = None
    dynamic_load_rating_n: float | None = None
    static_contact_pressure_pa: float = ISO76_LINE_CONTACT_PRESSURE_PA
    static_factor: float = 1.0
    dynamic_factor: float = DYNAMIC_FACTOR_DEFAULT

    def __post_init__(self) -> None:
        if self.static_load_rating_n is not None:
            check_positive("ratings", self, "static_load_rating_n")
        if self.dynamic_load_rating_n is not None:
            check_non_negative("ratings", self, "dynamic_load_rating_n")
        check_positive("ratings", self, "static_contact_pressure_pa", "static_factor", "dynamic_factor")

    def resolved(self, geo: Geometry, material: Material) -> Ratings:
        """Fill each None rating from the thread form (the Params constructor calls this)."""
        v = self.values(geo, material)
        return replace(self, static_load_rating_n=v.static_load_rating_n, dynamic_load_rating_n=v.dynamic_load_rating_n)

    def values(self, geo: Geometry, material: Material) -> RatingValues:
        """Both ratings as floats, N: those given, or derived from the thread form (`Params.resolved_ratings`)."""
        return RatingValues(
            static_load_rating_n=static_load_rating_n(geo, material, self) if self.static_load_rating_n is None
            else self.static_load_rating_n,
            dynamic_load_rating_n=dynamic_load_rating_n(geo, material, self) if self.dynamic_load_rating_n is None
            else self.dynamic_load_rating_n)


class RatingValues(NamedTuple):
    """The axial load ratings a built `Params` holds (`Params.resolved_ratings`), each a float, N: static
    C_0a and dynamic C_a (0: not rated), given or derived from the thread form."""

    static_load_rating_n: float
    dynamic_load_rating_n: float


STICTION_LAWS = ("stribeck",)


@dataclass(frozen=True)
class Stiction:
    """Breakaway beyond the running friction (`elastic` level): μ_static = breakaway_ratio · μ.

    Karnopp-type stick (models/elastic.py): below the stick window the screw holds while the torque
    stays inside the breakaway band. `breakaway_ratio` 1 gives `fu2018`'s friction;
    `stribeck_speed_m_s` is the screw–roller slip speed of the stick window [assumed, typical of
    lubricated steel]; law "stribeck" names this breakaway-then-running form.
    """

    law: str = "stribeck"
    breakaway_ratio: float = 1.3
    stribeck_speed_m_s: float = 1e-3

    def __post_init__(self) -> None:
        check_field("stiction", "law", self.law, self.law in STICTION_LAWS, f"must be one of {', '.join(STICTION_LAWS)}")
        check_positive("stiction", self, "stribeck_speed_m_s")
        v = self.breakaway_ratio
        check_field("stiction", "breakaway_ratio", v, is_finite_number(v) and v >= 1, "must be a finite number >= 1")


PIN_BEARINGS = ("journal", "needle")
# constant coefficient of friction of needle roller bearings with a cage, frictional moment M = ½ μ P d at the bore
# d (SKF "Rolling bearings" general catalogue, 2016, "Friction", table 1: 0.0020)
NEEDLE_BEARING_MU = 0.0020


@dataclass(frozen=True)
class DragParams:
    """Load-independent losses of a real screw (`fu2018`, `elastic`; `ideal` as an equivalent torque), and the
    carrier pins' bearing type. docs/model.md §4.5 lists each law and the source of each default.

    `enabled` false: none of the drag acts (the papers' screw, bit for bit). `pin_bearing` acts either way:
    ``"journal"`` is a plain pin with `friction.mu_pin`, ``"needle"`` a needle bearing with μ = 0.0020
    (`NEEDLE_BEARING_MU`) at the same lever, the pin radius.

    Attributes
    ----------
    enabled : bool
        Seals, film traction and the internal preload act.
    seal_friction_n_per_m : float
        Friction force of a seal or wiper lip per metre of its circumference on the screw, N/m: a seal torque
        T_s = n_seals · f′ · 2π r_S · r_S, regularised Coulomb on the screw, held statically at rest.
    n_seals : int
        Seals or wipers on the screw (one at each end of the nut).
    film_thickness_m, film_area_m2 : float
        Lubricant film h and wetted area A of one screw–roller thread contact: a Newtonian shear traction
        f = −(ρ ν A / h) v_s at every contact, present at zero load.
    internal_preload_n : float
        Axial force P_i each flank set carries with no external load (the nut's play class or light preload
        of a rigid nut, N): its contact forces act through the screw–roller Coulomb law on the idle flanks.
    pin_bearing : str
        ``"journal"`` or ``"needle"``.
    """

    enabled: bool = False
    seal_friction_n_per_m: float = 32.0
    n_seals: int = 2
    film_thickness_m: float = 0.5e-6
    film_area_m2: float = 1e-6
    internal_preload_n: float = 800.0
    pin_bearing: str = "journal"

    def __post_init__(self) -> None:
        g = "drag"
        check_field(g, "enabled", self.enabled, isinstance(self.enabled, bool), "must be true or false")
        check_non_negative(g, self, "seal_friction_n_per_m", "film_area_m2", "internal_preload_n")
        check_positive(g, self, "film_thickness_m")
        check_field(g, "n_seals", self.n_seals, isinstance(self.n_seals, int) and not isinstance(self.n_seals, bool)
                    and self.n_seals >= 0, "must be an integer >= 0")
        check_field(g, "pin_bearing", self.pin_bearing, self.pin_bearing in PIN_BEARINGS,
                    f"must be one of {', '.join(PIN_BEARINGS)}")


_GROUPS: dict[str, type] = {
    "geometry": Geometry,
    "mass": MassProperties,
    "friction": Friction,
    "ideal": IdealLoss,
    "loads": Loads,
    "material": Material,
    "elastic": ElasticParams,
    "ratings": Ratings,
    "stiction": Stiction,
    "drag": DragParams,
}


@dataclass(frozen=True)
class Params:
    """A complete, validated parameter set (frozen). `mass` is stored resolved (no None left).

    Build one with `prsm_sim.preset`, `Params.from_dict` (a nested dict, as in a YAML file),
    `with_overrides` (dotted keys, as `--set` takes them) or `dataclasses.replace` on a group;
    each group checks its values where it is built.

    Attributes
    ----------
    geometry : Geometry
        Thread and carrier geometry.
    mass : MassProperties
        Masses and inertias (resolved from geometry and density where left None).
    friction : Friction
        Friction and lubrication of `jones2016`, `fu2018` and `elastic`.
    ideal : IdealLoss
        Loss parameters of `ideal`.
    loads : Loads
        Nominal operating point (presets, scenarios, the steady-state command).
    name : str
        Preset or user label, carried into recordings.
    material : Material
        Elastic constants of the steel.
    elastic : ElasticParams
        Axial compliance chain of `elastic` (clearance, preload, bearing, housing).
    ratings : Ratings
        Axial load ratings of the nut (derived from the thread form where left None).
    stiction : Stiction
        Breakaway beyond the running friction (`elastic`).
    drag : DragParams
        Load-independent losses of a real screw (seals, film traction, internal preload) and the pin bearing.

    Raises
    ------
    ParamError
        A group of the wrong type, or any value its group refuses.

    Examples
    --------
    >>> from dataclasses import replace
    >>> from prsm_sim import preset
    >>> p = preset("s30")
    >>> q = replace(p, friction=replace(p.friction, mu_screw_roller=0.1))
    >>> q == p.with_overrides({"friction.mu_screw_roller": 0.1})
    True
    """

    geometry: Geometry
    mass: MassProperties
    friction: Friction = field(default_factory=Friction)
    ideal: IdealLoss = field(default_factory=IdealLoss)
    loads: Loads = field(default_factory=Loads)
    name: str = "custom"
    material: Material = field(default_factory=Material)
    elastic: ElasticParams = field(default_factory=ElasticParams)
    ratings: Ratings = field(default_factory=Ratings)
    stiction: Stiction = field(default_factory=Stiction)
    drag: DragParams = field(default_factory=DragParams)

    def __post_init__(self) -> None:
        for gname, cls in _GROUPS.items():
            v = getattr(self, gname)
            if not isinstance(v, cls):
                raise ParamError(f"{gname}: expected a {cls.__name__}, got {type(v).__name__}")
        _set(self, "mass", self.mass.resolved(self.geometry))
        if self.friction.drag_radius_m is None:
            _set(self, "friction", replace(self.friction, drag_radius_m=self.friction.drag_radius(self.geometry)))
        _set(self, "elastic", self.elastic.resolved(self.geometry))
        _set(self, "ratings", self.ratings.resolved(self.geometry, self.material))
        c0 = self.resolved_ratings.static_load_rating_n
        check_field("elastic", "preload_n", self.elastic.preload_n, self.elastic.preload_n <= c0,
               f"must not exceed the static load rating ratings.static_load_rating_n = {c0:.6g} N")
        nt = self.geometry.n_teeth
        check_field("elastic", "preload_kind", self.elastic.preload_kind, self.elastic.preload_kind != "double_nut"
               or (nt >= 2 and nt % 2 == 0), f"must not be double_nut for geometry.n_teeth = {nt} (two halves of "
               "N_T/2 rows: an even n_teeth)")

    @cached_property
    def resolved_mass(self) -> MassValues:
        """The mass properties as this set holds them (`mass`, resolved), each a float."""
        return self.mass.values(self.geometry)

    @cached_property
    def resolved_elastic(self) -> ElasticValues:
        """The elastic group's derived lengths as this set holds them (`elastic`, resolved), each a float, m."""
        return self.elastic.values(self.geometry)

    @cached_property
    def resolved_ratings(self) -> RatingValues:
        """The axial load ratings as this set holds them (`ratings`, resolved), each a float, N."""
        return self.ratings.values(self.geometry, self.material)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict of every (resolved) parameter; round-trips through from_dict."""
        out: dict[str, Any] = {"name": self.name}
        for gname in _GROUPS:
            out[gname] = asdict(getattr(self, gname))
        return out

    @classmethod
    def from_dict(cls, data: Any, *, base: Params | None = None) -> Params:
        """Build from a nested dict, refusing unknown keys; values missing fall back to `base`."""
        if not isinstance(data, dict):
            raise ParamError(f"parameters: expected a mapping of groups ({', '.join(_GROUPS)}), got {type(data).__name__}")
        unknown = set(data) - set(_GROUPS) - {"name"}
        if unknown:
            raise ParamError(f"unknown parameter group(s) {', '.join(sorted(map(str, unknown)))}; "
                             f"allowed: name, {', '.join(_GROUPS)}")
        groups = {}
        for gname, gcls in _GROUPS.items():
            section = data.get(gname, {})
            if section is None:
                section = {}
            if not isinstance(section, dict):
                raise ParamError(f"{gname}: expected a mapping, got {type(section).__name__}")
            allowed = {f.name for f in fields(gcls)}
            bad = set(section) - allowed
            if bad:
                raise ParamError(f"unknown parameter {gname}.{sorted(map(str, bad))[0]}; "
                                 f"allowed in {gname}: {', '.join(sorted(allowed))}")
            values = asdict(getattr(base, gname)) if base is not None else {}
            if gname == "elastic" and base is not None:
                values.update(_derived_lengths(base.elastic, base.geometry))
            values.update(section)
            missing = [f.name for f in fields(gcls) if f.name not in values and f.default is MISSING
                       and f.default_factory is MISSING]  # type: ignore[misc]
            if missing:
                raise ParamError(f"{gname}.{missing[0]} is required (no preset to take it from)")
            values = {k: _coerce(gcls, k, v, gname) for k, v in values.items()}
            try:
                groups[gname] = gcls(**values)
            except TypeError as e:  # a wrong type that the checks did not name
                raise ParamError(f"{gname}: {e}") from None
        name = data.get("name", base.name if base is not None else "custom")
        return cls(name=str(name), **groups)

    def with_overrides(self, overrides: dict[str, Any]) -> Params:
        """A new validated Params with dotted-key overrides, e.g. {"friction.mu_screw_roller": 0.1}.

        Ratings the base derived (`Ratings`) are derived again for the new values; ratings given
        as numbers stay as given unless overridden.
        """
        nested: dict[str, Any] = {}
        for key, value in overrides.items():
            parts = key.split(".")
            if len(parts) != 2:
                raise ParamError(f"parameter override {key!r}: expected group.name, e.g. friction.mu_screw_roller")
            nested.setdefault(parts[0], {})[parts[1]] = value
        # a rating the base derived is derived again from the new thread form, material and factors
        r = self.ratings
        for name, law in (("static_load_rating_n", static_load_rating_n), ("dynamic_load_rating_n", dynamic_load_rating_n)):
            if name not in nested.get("ratings", {}) and getattr(r, name) == law(self.geometry, self.material, r):
                nested.setdefault("ratings", {})[name] = None
        return Params.from_dict(nested, base=self)

    @staticmethod
    def override_keys() -> list[str]:
        """Every dotted key `with_overrides` accepts."""
        return [f"{g}.{f.name}" for g, cls in _GROUPS.items() for f in fields(cls)]


_INT_FIELDS = {("geometry", "starts"), ("geometry", "n_rollers"), ("geometry", "n_teeth"), ("drag", "n_seals")}
_BOOL_FIELDS = {("geometry", "thread_ends"), ("drag", "enabled")}
_STR_FIELDS = {("friction", "contact_evaluation"), ("friction", "screw_roller_law"), ("friction", "load_distribution"),
               ("elastic", "mounting"), ("elastic", "tooth_model"), ("elastic", "preload_kind"), ("stiction", "law"),
               ("drag", "pin_bearing")}


def _coerce(gcls: type, key: str, value: Any, gname: str) -> Any:
    """Accept YAML's ints for floats and integral floats for counts; refuse anything else by name."""
    if value is None:
        return None
    if (gname, key) in _BOOL_FIELDS:
        if not isinstance(value, bool):
            raise ParamError(f"{gname}.{key} = {value!r}: must be true or false")
        return value
    if (gname, key) in _STR_FIELDS:
        if not isinstance(value, str):
            raise ParamError(f"{gname}.{key} = {value!r}: must be a string")
        return value
    if isinstance(value, str) and (gname, key) not in _INT_FIELDS:
        value = parse_float(value, f"{gname}.{key}")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamError(f"{gname}.{key} = {value!r}: must be a number")
    if (gname, key) in _INT_FIELDS:
        if not math.isfinite(value) or float(value) != int(value):
            raise ParamError(f"{gname}.{key} = {value!r}: must be a whole number")
        return int(value)
    return float(value)


def parse_float(text: str, name: str) -> float:
    """A float from any spelling Python's float() accepts ("1e-5", "1E-5", "1_000.0", " 2.5 ").

    YAML 1.1 (PyYAML, ROS parameter files) reads "1e-5" as a string because it wants a dot in
    the mantissa; this is the one place such strings become numbers. Raises ParamError naming
    `name` when the text is not a number.
    """
    try:
        return float(text)
    except ValueError:
        raise ParamError(f"{name} = {text!r}: must be a number") from None
