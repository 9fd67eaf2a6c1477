"""3D scene of the PRSM in Rerun: geometry logged once, then poses, force arrows and tooth loads per frame.

Frame and units (REP 103): metres, Z up. `world` is prsm_sim's body frame (`prsm_sim.physics.kinematics`):
z along the screw axis, right-hand threads, angles right-handed about +z. prsm_sim reports the
nut along x_nut = (L/2π) θ_S, which for right-hand threads is the −z direction, so the scene puts
the nut at z = −x_nut: a positive screw rotation drives the nut down the screen. The threads stay
right-handed; only the sign of the reported coordinate differs from z.

Entity tree (static = logged once, per frame = at the scene rate):

    world                                     ViewCoordinates RIGHT_HAND_Z_UP
    world/screw                               per frame: rotation θ_S about z
    world/screw/body, world/screw/thread      Cylinders3D r_S, n right-hand helices of lead L
    world/nut                                 per frame: translation z = −x_nut
    world/nut/body, world/nut/thread          Cylinders3D r_N (wireframe), n helices at r_N
    world/nut/carrier                         per frame: rotation θ_C (the carriers ride in the nut)
    world/nut/carrier/plates                  both carrier rings with an index mark
    world/nut/carrier/roller_<q>              per frame: pin q at angle 2πq/N_R, roller migration along z,
                                              spin angle relative to the carrier −g θ_C
    world/nut/carrier/roller_<q>/body|thread  Cylinders3D r_R, single-start helix of pitch P, a stripe
    world/nut/carrier/forces/<family>         per frame Arrows3D, one per roller, force ON the roller
    world/nut/carrier/tooth_loads/<quantity>  per frame Points3D, one per tooth contact, coloured by load
    loads/<block>/<quantity>                  per frame Tensor roller × tooth (the heat map)
    loads/along_nut/<block>/<quantity>        per frame BarChart: the mean over rollers per tooth, N

Forces come from the model's `InternalLayout`, looked up by name, never assumed. In a block with
dims (roller, quantity), quantities `<prefix>_<radial|tangential|axial>[_force]_n` (at least two
of the three) form a force vector in the roller's carrier frame (roller at angle 0: radial = x,
tangential = y, axial = z), and `<screw|nut>_…normal…_n` is a normal-force magnitude along that
side's contact normal. The prefix says where it is drawn: `screw…` / `nut…` at that contact,
`gear…` at the ring-gear mesh (upper roller end), anything else at the journal (lower end) — a
resultant of both ends drawn at one. Contacts come from `prsm_sim.physics.contact.contact_for` with the
model's contact evaluation, on the flanks the axial load loads (the layout's `load_sign` quantity
when the model reports one, else the sign of nut_force_n; see the `contact` module), rotated by
2πq/N_R for roller q; the carrier transform adds θ_C. A block with dims (roller, tooth, quantity)
gives the heat maps and the tooth points; tooth k sits at z = (k − (N_T − 1)/2) P along the
roller (an assumption: the layout does not say which end is k = 0).

Scale: arrow length = r_R · log10(1 + |F| / 1 N) (1 N → 0.3 r_R, 100 N → 2 r_R, 10 kN → 4 r_R), so
friction of a newton and loads of kilonewtons are both visible; colour = log10 |F| on a blue →
red ramp from 0.1 N to 10 kN. The exact values are in the time series.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import rerun as rr

from prsm_sim import InternalLayout, Params
from prsm_sim.physics.contact import ContactPoint, contact_for, line_of_centres_contact
from prsm_sim.physics.kinematics import roller_migration_velocity, roller_spin

from prsm_ros.viz.columns import ArrowColumn, colors_column, vectors_column
from prsm_ros.viz.series import TIMELINE, sim_time_index

WORLD = "world"
SCREW = f"{WORLD}/screw"
NUT = f"{WORLD}/nut"
CARRIER = f"{NUT}/carrier"
FORCES = f"{CARRIER}/forces"
TOOTH_LOADS = f"{CARRIER}/tooth_loads"
LOADS = "loads"
ABOUT = "about"

FORCE_REF_N = 1.0  # arrow length grows by r_R per decade above this force
COLOR_RANGE_N = (0.1, 1e4)  # colour ramp end points (log scale)
_RAMP = np.array([[40, 80, 220], [0, 190, 220], [60, 200, 60], [240, 215, 40], [220, 40, 30]], dtype=float)
_RAMP_STOPS = np.arange(len(_RAMP), dtype=float)

_COLORS = {"screw": (150, 150, 160, 255), "thread": (90, 90, 100, 255), "nut": (70, 120, 200, 90),
           "nut_thread": (70, 120, 200, 200), "roller": (215, 140, 60, 255), "roller_body": (215, 140, 60, 70),
           "stripe": (40, 40, 40, 255), "carrier": (60, 170, 90, 255)}

_VECTOR = re.compile(r"^(?P<prefix>.+?)_(?P<axis>radial|tangential|axial)(?P<suffix>_force)?_n$")
_AXES = ("radial", "tangential", "axial")
_NORMAL = re.compile(r"^(?P<side>screw|nut)_.*normal.*_n$")


def along_nut_path(block: str, quantity: str) -> str:
    """The bar chart of a per-tooth force along the nut (beside its heat map, not under it: a TensorView
    shows everything under its origin)."""
    return f"{LOADS}/along_nut/{block}/{quantity}"


def heat_map_range(loads: np.ndarray) -> np.ndarray:
    """Colour range (frames × 2) of roller × tooth frames: each frame's own min → max, so the shares
    along the nut read at any load; a frame of equal loads gets [0, 2 × value] (the middle colour:
    equal shares, not the top of the scale) and an unloaded one [0, 1]."""
    lo = loads.min(axis=(1, 2))
    hi = loads.max(axis=(1, 2))
    flat = (hi - lo) <= 1e-9 * np.maximum(np.abs(hi), 1e-300)
    lo = np.where(flat, 0.0, lo)
    hi = np.where(flat, np.where(np.abs(hi) > 0, 2 * np.abs(hi), 1.0), hi)
    return np.stack([lo, hi], axis=-1)


def roller_path(q: int) -> str:
    return f"{CARRIER}/roller_{q}"


def color_by_magnitude(force_n: np.ndarray) -> np.ndarray:
    """RGBA uint8 per force magnitude: log10 |F| from COLOR_RANGE_N mapped onto a blue → red ramp."""
    lo, hi = (math.log10(v) for v in COLOR_RANGE_N)
    f = np.maximum(np.abs(np.asarray(force_n, dtype=float)), COLOR_RANGE_N[0])
    x = np.clip((np.log10(f) - lo) / (hi - lo), 0.0, 1.0) * (len(_RAMP) - 1)
    out = np.empty(x.shape + (4,), dtype=np.uint8)  # each channel written in place: no stack, no copy
    for c in range(3):
        out[..., c] = np.interp(x, _RAMP_STOPS, _RAMP[:, c])  # truncated toward zero, as astype(np.uint8)
    out[..., 3] = 255
    return out


def arrow_length_m(force_n: np.ndarray, roller_radius_m: float) -> np.ndarray:
    """Displayed arrow length for a force magnitude (see the module docstring)."""
    return roller_radius_m * np.log10(1.0 + np.abs(force_n) / FORCE_REF_N)


def z_rotation_quaternions(angle_rad: np.ndarray) -> np.ndarray:
    """xyzw quaternions of rotations about +z (Rerun's order)."""
    h = 0.5 * np.asarray(angle_rad, dtype=float)
    zero = np.zeros_like(h)
    return np.stack([zero, zero, np.sin(h), np.cos(h)], axis=-1)


def _rotate_z(vectors: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Rotate (..., 3) vectors about z by angles broadcast against vectors[..., 0]."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    x, y, z = vectors[..., 0], vectors[..., 1], vectors[..., 2]
    return np.stack(np.broadcast_arrays(c * x - s * y, s * x + c * y, z), axis=-1)


def helix(radius_m: float, lead_m: float, z0_m: float, z1_m: float, phase_rad: float = 0.0,
          points_per_turn: int = 48) -> np.ndarray:
    """Right-hand helix z = (lead/2π)(φ − phase) through z0..z1 (a thread's pitch line)."""
    turns = (z1_m - z0_m) / lead_m
    swept = np.linspace(0.0, 2 * math.pi * turns, max(2, int(math.ceil(turns * points_per_turn)) + 1))
    phi = swept + phase_rad
    z = z0_m + lead_m * swept / (2 * math.pi)
    return np.stack([radius_m * np.cos(phi), radius_m * np.sin(phi), z], axis=-1)


def circle(radius_m: float, z_m: float, n: int = 96) -> np.ndarray:
    phi = np.linspace(0.0, 2 * math.pi, n + 1)
    return np.stack([radius_m * np.cos(phi), radius_m * np.sin(phi), np.full_like(phi, z_m)], axis=-1)


@dataclass(frozen=True)
class ForceFamily:
    """Arrows of one force found in a per-roller block: `columns` are the quantity indices of its
    (radial, tangential, axial) components in the roller's carrier frame (None: component absent,
    zero) or a single index (a normal-force magnitude along the contact normal); `site` says where
    it acts: "screw" / "nut" contact, "gear" (ring-gear mesh) or "axis" (the roller journal)."""

    name: str
    block: str
    site: str
    columns: tuple[int | None, ...]


def _site(prefix: str) -> str:
    return next((s for s in ("screw", "nut", "gear") if prefix.startswith(s)), "axis")


def force_families(layout: InternalLayout) -> list[ForceFamily]:
    """Every force the layout carries per roller, by quantity name and unit (module docstring)."""
    out: list[ForceFamily] = []
    for b in layout.blocks:
        if b.dims != ("roller", "quantity"):
            continue
        vectors: dict[str, dict[str, int]] = {}
        for k, (q, unit) in enumerate(b.quantities):
            if unit != "N":
                continue
            m = _VECTOR.match(q)
            if m:
                vectors.setdefault(m["prefix"] + (m["suffix"] or ""), {})[m["axis"]] = k
            elif (m := _NORMAL.match(q)):
                out.append(ForceFamily(q.removesuffix("_n"), b.name, m["side"], (k,)))
        for name, axes in vectors.items():
            if len(axes) >= 2:  # one component alone is a scalar, not a direction
                out.append(ForceFamily(name, b.name, _site(name), tuple(axes.get(a) for a in _AXES)))
    return out


def tooth_quantities(layout: InternalLayout) -> list[tuple[str, int, str, str | None]]:
    """(block, quantity index, quantity, side) of every per-tooth force: the heat maps and tooth points."""
    out = []
    for b in layout.blocks:
        if b.dims == ("roller", "tooth", "quantity"):
            for k, (q, unit) in enumerate(b.quantities):
                if unit == "N":
                    m = _NORMAL.match(q)
                    out.append((b.name, k, q, m["side"] if m else None))
    return out


def _contact(geo, side: str, evaluation: str, load_sign: int) -> ContactPoint:
    """The model's contact, or the line-of-centres point when the exact solve does not converge for this geometry."""
    try:
        return contact_for(geo, side, evaluation, load_sign)
    except RuntimeError:
        return line_of_centres_contact(geo, side, load_sign)


class Scene:
    """The PRSM scene for one parameter set and internal-load layout.

    `log_static` once, then `send_frames` with batches of (already decimated) steps; both take an
    explicit RecordingStream. Columns are OUTPUT_FIELDS names → 1-D arrays; missing ones are
    skipped (a bag with only joint states moves the screw and the nut and nothing else).
    """

    def __init__(self, params: Params, layout: InternalLayout) -> None:
        geo = params.geometry
        self.params = params
        self.geo = geo
        self.layout = layout
        self.n_rollers = geo.n_rollers
        self.roller_angles_rad = 2 * math.pi * np.arange(geo.n_rollers) / geo.n_rollers
        ev = params.friction.contact_evaluation
        contacts = {(side, s): _contact(geo, side, ev, s) for side in ("screw", "nut") for s in (1, -1)}
        self.contact_points = {k: c.point_m for k, c in contacts.items()}
        self.contact_normals = {k: c.normal_on_roller for k, c in contacts.items()}
        self.families = force_families(layout)
        self.load_sign_at = next(((b.name, k) for b in layout.blocks if b.dims == ("quantity",)
                                  for k, (q, _) in enumerate(b.quantities) if q == "load_sign"), None)
        self.tooth = tooth_quantities(layout)
        self.roller_length_m = geo.roller_length_m
        self.offsets = layout.offsets()

    # -- static geometry -----------------------------------------------------------------
    def log_static(self, rec: rr.RecordingStream) -> None:
        geo, c = self.geo, _COLORS
        r_s, r_r, r_n, a = geo.screw_radius_m, geo.roller_radius_m, geo.nut_radius_m, geo.carrier_radius_m
        lead, pitch, n = geo.lead_m, geo.pitch_m, geo.starts
        line = pitch / 10
        half_screw = geo.screw_length_m / 2
        half_roller = self.roller_length_m / 2
        half_nut = half_roller + pitch
        solid = rr.components.FillMode.Solid
        # nut and rollers are see-through so the contact arrows inside them stay visible
        see_through = rr.components.FillMode.TransparentFillMajorWireframe
        rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(f"{SCREW}/body", rr.Cylinders3D(lengths=[2 * half_screw], radii=[r_s], colors=[c["screw"]],
                                                fill_mode=solid), static=True)
        rec.log(f"{SCREW}/thread", rr.LineStrips3D(
            [helix(r_s * 1.003, lead, -half_screw, half_screw, 2 * math.pi * j / n) for j in range(n)],
            radii=line, colors=[c["thread"]]), static=True)
        rec.log(f"{NUT}/body", rr.Cylinders3D(lengths=[2 * half_nut], radii=[r_n], colors=[c["nut"]],
                                              fill_mode=see_through), static=True)
        rec.log(f"{NUT}/thread", rr.LineStrips3D(
            [helix(r_n, lead, -half_nut, half_nut, 2 * math.pi * j / n) for j in range(n)],
            radii=line, colors=[c["nut_thread"]]), static=True)
        plate_z = half_roller + pitch / 2
        inner, outer = a - 0.6 * r_r, a + 0.6 * r_r
        strips = [circle(r, s * plate_z) for s in (1, -1) for r in (inner, outer)]
        strips += [np.array([[inner, 0.0, s * plate_z], [outer, 0.0, s * plate_z]]) for s in (1, -1)]
        rec.log(f"{CARRIER}/plates", rr.LineStrips3D(strips, radii=line, colors=[c["carrier"]]), static=True)
        for q in range(self.n_rollers):
            p = roller_path(q)
            rec.log(f"{p}/body", rr.Cylinders3D(lengths=[2 * half_roller], radii=[r_r * 0.97],
                                                colors=[c["roller_body"]], fill_mode=see_through), static=True)
            stripe = np.array([[r_r * 1.01, 0.0, -half_roller], [r_r * 1.01, 0.0, half_roller]])
            rec.log(f"{p}/thread", rr.LineStrips3D(
                [helix(r_r, pitch, -half_roller, half_roller), stripe], radii=line,
                colors=[c["roller"], c["stripe"]]), static=True)
        for f in self.families:
            rec.log(f"{FORCES}/{f.name}", rr.Arrows3D.from_fields(radii=[r_r / 8]), static=True)
        for block, _, q, _ in self.tooth:
            rec.log(f"{TOOTH_LOADS}/{q}", rr.Points3D.from_fields(radii=[pitch / 5]), static=True)
            # the bars' x (tooth 1 … N_T) and colour, static; their values come per frame
            rec.log(along_nut_path(block, q), [
                rr.components.TensorDataBatch(np.arange(1, self.geo.n_teeth + 1, dtype=np.float64)).described(
                    rr.BarChart.descriptor_abscissa()),
                rr.components.ColorBatch([(31, 119, 180, 255)]).described(rr.BarChart.descriptor_color())],
                static=True)
        rec.log(ABOUT, rr.TextDocument(self.about(), media_type=rr.MediaType.MARKDOWN), static=True)

    def about(self) -> str:
        g = self.geo
        fams = ", ".join(f"{f.name} ({f.site})" for f in self.families) or "none in this model's layout"
        teeth = ", ".join(q for _, _, q, _ in self.tooth) or "none in this model's layout"
        return (f"# PRSM scene — {self.params.name}\n\n"
                f"Metres, Z up (REP 103), z along the screw axis, right-hand threads. "
                f"The nut is drawn at **z = −x_nut**: positive screw rotation drives it toward −z.\n\n"
                f"- screw r_S = {g.screw_radius_m:g} m, {g.starts} starts, lead {g.lead_m:g} m; "
                f"{g.n_rollers} rollers r_R = {g.roller_radius_m:g} m × {g.n_teeth} teeth; "
                f"nut r_N = {g.nut_radius_m:g} m\n"
                f"- arrows: force on each roller at its contact; length r_R·log10(1 + |F|/1 N), "
                f"colour log10|F| blue (0.1 N) → red (10 kN)\n"
                f"- force arrows: {fams}\n- per-tooth loads (heat maps, tooth points): {teeth}; a heat map's "
                f"colours span that frame's min → max (one middle colour: equal shares), the bars 'along the "
                f"nut' give the values in N (mean over the rollers, tooth 1 … {g.n_teeth})\n"
                f"- timeline `{TIMELINE}`: simulation time\n")

    # -- per frame -----------------------------------------------------------------------
    def send_frames(self, rec: rr.RecordingStream, columns: Mapping[str, np.ndarray],
                    internal: np.ndarray | None) -> int:
        """Poses, arrows, tooth points and heat maps of these steps, one `send_columns` per entity."""
        t = np.asarray(columns["time_s"], dtype=float)
        n = len(t)
        if n == 0:
            return 0
        index = [sim_time_index(t)]
        if "screw_angle_rad" in columns:
            rec.send_columns(SCREW, indexes=index, columns=[vectors_column(
                rr.Transform3D.descriptor_quaternion(), z_rotation_quaternions(columns["screw_angle_rad"]))])
        if "nut_position_m" in columns:
            z = -np.asarray(columns["nut_position_m"], dtype=float)
            rec.send_columns(NUT, indexes=index, columns=[vectors_column(
                rr.Transform3D.descriptor_translation(), np.stack([np.zeros(n), np.zeros(n), z], axis=-1))])
        if "carrier_angle_rad" not in columns:
            return n
        theta_c = np.asarray(columns["carrier_angle_rad"], dtype=float)
        rec.send_columns(CARRIER, indexes=index, columns=[vectors_column(
            rr.Transform3D.descriptor_quaternion(), z_rotation_quaternions(theta_c))])
        # both kinematic relations are linear in the carrier speed, so applied to the carrier angle
        # they give the displacement since θ_C = 0: roller spin angle and axial migration in the nut
        spin = vectors_column(rr.Transform3D.descriptor_quaternion(),
                              z_rotation_quaternions(roller_spin(self.geo, theta_c)))
        z_mig = roller_migration_velocity(self.geo, theta_c)
        a = self.geo.carrier_radius_m
        for q, phi in enumerate(self.roller_angles_rad):
            pos = np.stack([np.full(n, a * math.cos(phi)), np.full(n, a * math.sin(phi)), z_mig], axis=-1)
            rec.send_columns(roller_path(q), indexes=index,
                             columns=[vectors_column(rr.Transform3D.descriptor_translation(), pos), spin])
        if internal is None or not self.layout.size:
            return n
        internal = np.asarray(internal, dtype=float).reshape(n, self.layout.size)
        if self.load_sign_at is not None:
            block, k = self.load_sign_at
            signed = self._block(internal, block)[:, k]
        else:
            signed = np.asarray(columns.get("nut_force_n", np.ones(n)), dtype=float)
        load_sign = np.where(signed >= 0, 1, -1)
        self._send_arrows(rec, index, internal, load_sign, z_mig)
        self._send_teeth(rec, index, internal, load_sign, z_mig)
        return n

    def _block(self, internal: np.ndarray, name: str) -> np.ndarray:
        b = next(b for b in self.layout.blocks if b.name == name)
        at = self.offsets[name]
        return internal[:, at: at + b.size].reshape((internal.shape[0],) + b.shape)

    def _contact_table(self, table: dict, side: str, load_sign: np.ndarray) -> np.ndarray:
        """(frames, 3) contact point or normal of one side for the loaded flank of each frame (roller at angle 0)."""
        return np.where((load_sign > 0)[:, None], table[(side, 1)], table[(side, -1)])

    def _site_points(self, site: str, load_sign: np.ndarray) -> np.ndarray:
        """(frames, 3) where a force family is drawn: its contact, the ring-gear mesh at the upper
        roller end, or the journal at the lower end (the resultant of both ends drawn at one)."""
        if site in ("screw", "nut"):
            return self._contact_table(self.contact_points, site, load_sign)
        end = self.roller_length_m / 2 + self.geo.pitch_m / 2
        a, r = self.geo.carrier_radius_m, self.geo.roller_radius_m
        point = [a + r, 0.0, end] if site == "gear" else [a, 0.0, -end]
        return np.tile(point, (len(load_sign), 1))

    def _send_arrows(self, rec, index, internal, load_sign, z_mig) -> None:
        n, nr = internal.shape[0], self.n_rollers
        phi = self.roller_angles_rad[None, :]
        for f in self.families:
            block = self._block(internal, f.block)  # frames × rollers × quantities
            point = self._site_points(f.site, load_sign)
            if len(f.columns) == 3:
                local = np.stack([block[:, :, k] if k is not None else np.zeros(block.shape[:2])
                                  for k in f.columns], axis=-1)
            else:
                normal = self._contact_table(self.contact_normals, f.site, load_sign)
                local = np.abs(block[:, :, f.columns[0]])[..., None] * normal[:, None, :]
            mag = np.linalg.norm(local, axis=-1)
            with np.errstate(invalid="ignore", divide="ignore"):
                unit = np.where(mag[..., None] > 0, local / mag[..., None], 0.0)
            vectors = _rotate_z(unit * arrow_length_m(mag, self.geo.roller_radius_m)[..., None], phi)
            origin_local = point[:, None, :] + np.stack([np.zeros(n), np.zeros(n), z_mig], axis=-1)[:, None, :]
            origins = _rotate_z(np.broadcast_to(origin_local, (n, nr, 3)), phi)
            rec.send_columns(f"{FORCES}/{f.name}", indexes=index, columns=[
                vectors_column(rr.Arrows3D.descriptor_origins(), origins.reshape(-1, 3), nr),
                vectors_column(rr.Arrows3D.descriptor_vectors(), vectors.reshape(-1, 3), nr),
                colors_column(rr.Arrows3D.descriptor_colors(), color_by_magnitude(mag), nr)])

    def _send_teeth(self, rec, index, internal, load_sign, z_mig) -> None:
        n, nr, nt = internal.shape[0], self.n_rollers, self.geo.n_teeth
        for block_name, k, q, side in self.tooth:
            loads = self._block(internal, block_name)[..., k]  # frames × rollers × teeth
            if side is not None and loads.shape[2] == nt:
                z_k = (np.arange(nt) - (nt - 1) / 2) * self.geo.pitch_m
                point = self._contact_table(self.contact_points, side, load_sign)  # frames × 3
                local = np.broadcast_to(point[:, None, None, :], (n, nr, nt, 3)).copy()
                local[..., 2] += z_mig[:, None, None] + z_k[None, None, :]
                pos = _rotate_z(local, self.roller_angles_rad[None, :, None])
                rec.send_columns(f"{TOOTH_LOADS}/{q}", indexes=index, columns=[
                    vectors_column(rr.Points3D.descriptor_positions(), pos.reshape(-1, 3), nr * nt),
                    colors_column(rr.Points3D.descriptor_colors(), color_by_magnitude(loads), nr * nt)])
            rec.send_columns(f"{LOADS}/{block_name}/{q}", indexes=index,
                             columns=[tensor_column(loads, ("roller", "tooth")),
                                      *rr.Tensor.columns(value_range=heat_map_range(loads))])
            rec.send_columns(along_nut_path(block_name, q), indexes=index,
                             columns=[tensor_column(loads.mean(axis=1), ("tooth",), rr.BarChart.descriptor_values())])


_TENSOR_TYPE = None


def tensor_column(frames: np.ndarray, dim_names: tuple[str, ...], descriptor=None) -> rr.ComponentColumn:
    """`Tensor:data` (or another TensorData component: `descriptor`, e.g. a BarChart's values) for a
    stack of frames (frames × shape), one tensor per row, built in one go.

    Rerun 0.41's Python `Tensor` converts one tensor per call (≈ 0.4 ms each, the largest share of
    live logging) and refuses batches in `Tensor.columns`. The Arrow layout is taken from Rerun's
    own conversion of a tiny tensor, so this follows the installed version; the buffer is the
    F64 variant of its union.
    """
    import pyarrow as pa

    global _TENSOR_TYPE
    if _TENSOR_TYPE is None:
        _TENSOR_TYPE = rr.Tensor(np.zeros((1, 1)), dim_names=["a", "b"]).as_component_batches()[0].as_arrow_array().type
    struct_t = _TENSOR_TYPE
    union_t = struct_t.field("buffer").type
    frames = np.ascontiguousarray(frames, dtype=np.float64)
    n, shape = frames.shape[0], frames.shape[1:]
    size = int(np.prod(shape))

    def lists(values, per_row, list_type):
        offsets = pa.array(np.arange(0, (n + 1) * per_row, per_row, dtype=np.int32))
        return pa.ListArray.from_arrays(offsets, values, type=list_type)

    shape_arr = lists(pa.array(np.tile(np.array(shape, dtype=np.uint64), n)), len(shape), struct_t.field("shape").type)
    names_arr = lists(pa.array(list(dim_names) * n, pa.string()), len(dim_names), struct_t.field("names").type)
    children, code = [], None
    for i, f in enumerate(union_t):
        if f.name == "F64":
            code = union_t.type_codes[i]
            children.append(lists(pa.array(frames.reshape(-1)), size, f.type))
        else:
            children.append(pa.array([], type=f.type))
    buffer = pa.Array.from_buffers(union_t, n, [None, pa.py_buffer(np.full(n, code, dtype=np.int8)),
                                                pa.py_buffer(np.arange(n, dtype=np.int32))], children=children)
    data = pa.StructArray.from_arrays([shape_arr, names_arr, buffer], fields=list(struct_t))
    return rr.ComponentColumn(descriptor if descriptor is not None else rr.Tensor.descriptor_data(), ArrowColumn(data))


def scene_frame_indices(time_s: np.ndarray, rate_hz: float, last_slot: int) -> tuple[np.ndarray, int]:
    """Rows to draw at `rate_hz`: the first step of each 1/rate_hz slot of simulation time.

    Returns the row indices and the slot of the last row (pass it back with the next batch), so a
    stream cut into batches anywhere is decimated exactly like the whole. A step back in time
    (a simulator reset) starts a new slot too.
    """
    t = np.asarray(time_s, dtype=float)
    if len(t) == 0:
        return np.empty(0, dtype=int), last_slot
    slots = np.floor(t * rate_hz + 1e-9).astype(np.int64)
    idx = np.flatnonzero(slots != np.r_[last_slot, slots[:-1]])
    return idx, int(slots[-1])
