"""The default Rerun layout of a PRSM recording: 3D scene, heat maps and time series, no clicking needed.

    ┌──────────────────────────┬──────────────────────────────────────┐
    │                          │ nut position      │ nut force        │
    │   3D: screw, rollers,    ├───────────────────┼──────────────────┤
    │   nut, force arrows      │ screw speed       │ screw torque     │
    │                          ├───────────────────┼──────────────────┤
    ├──────────────────────────┤ ratio, efficiency │ slip             │
    │ heat maps roller × tooth ├──────────────────────────────────────┤
    │ (tabs) · about           │ per-roller forces, carrier, power    │
    └──────────────────────────┴──────────────────────────────────────┘

Views are built only for what the recording holds (a bag with joint states only has no heat map,
no slip and no per-roller tab), so nothing opens empty. The time panel shows `sim_time`, collapsed to
its slider so the views get the height.
"""

from __future__ import annotations

from collections.abc import Iterable

import rerun.blueprint as rrb

from prsm_sim import InternalLayout

from prsm_ros.viz.scene import ABOUT, LOADS, NUT, WORLD, tooth_quantities
from prsm_ros.viz.series import TIMELINE, block_path, input_path, scalar_path, series_blocks

# (title, scalar outputs, recorded inputs) of the scalar plots, in reading order
SCALAR_VIEWS: tuple[tuple[str, tuple[str, ...], tuple[str, ...]], ...] = (
    ("Nut position [m]", ("nut_position_m",), ("nut_position_reference",)),
    ("Nut force [N]", ("nut_force_n", "load_force_n"), ()),
    ("Screw and carrier speed [rad/s]", ("screw_speed_rad_s", "carrier_speed_rad_s"), ()),
    ("Screw torque [N·m]", ("screw_torque_nm",), ("screw_torque",)),
    ("Carrier/screw ratio, efficiency [1]", ("speed_ratio", "efficiency"), ()),
    ("Slip speed [m/s]", ("slip_speed_m_s",), ()),
)
POWER_VIEW = ("Power [W]", ("power_in_w", "power_out_w", "power_dissipated_w"))


def _series_view(title: str, paths: list[str]) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(name=title, origin="/", contents=paths)


def default_blueprint(scalar_names: Iterable[str], layout: InternalLayout, *, scene: bool = True,
                      inputs: Iterable[str] = (), eye_distance_m: float | None = None) -> rrb.Blueprint:
    """The layout for a recording with these scalar series, this internal layout and these inputs.

    `scene=False` leaves out the 3D view (no geometry known).
    """
    have = set(scalar_names)
    have_inputs = set(inputs)
    plots = []
    for title, outs, ins in SCALAR_VIEWS:
        paths = [scalar_path(n) for n in outs if n in have] + [input_path(n) for n in ins if n in have_inputs]
        if paths:
            plots.append(_series_view(title, paths))
    tabs = []
    for b in series_blocks(layout):  # forces per roller; every quantity of a plain (quantity,) block
        for q, unit in b.quantities:
            if len(b.dims) == 2 and unit == "N":
                tabs.append(_series_view(f"{q} per {b.dims[0]} [N]", [block_path(b.name, q)]))
            elif len(b.dims) == 1:
                tabs.append(_series_view(f"{b.name}: {q} [{unit}]", [block_path(b.name, q)]))
    power = [scalar_path(n) for n in POWER_VIEW[1] if n in have]
    if power:
        tabs.append(_series_view(POWER_VIEW[0], power))
    rows = [rrb.Horizontal(*plots[i:i + 2]) for i in range(0, len(plots), 2)]
    if tabs:
        rows.append(rrb.Tabs(*tabs))
    right = rrb.Vertical(*rows) if rows else None

    heat = [rrb.TensorView(name=f"{q} [N] roller × tooth", origin=f"{LOADS}/{block}/{q}",
                           scalar_mapping=rrb.TensorScalarMapping(colormap="turbo"))
            for block, _, q, _ in tooth_quantities(layout)]
    about = rrb.TextDocumentView(name="About", origin=ABOUT)
    left_parts = []
    if scene:
        # the view's origin is the nut, so nut, carrier, rollers and arrows stay in frame over any
        # stroke and the screw is seen turning and sliding through them
        eye = None
        if eye_distance_m:
            d = eye_distance_m
            eye = rrb.EyeControls3D(position=[d, -d, 0.6 * d], look_target=[0.0, 0.0, 0.0], eye_up=[0.0, 0.0, 1.0])
        left_parts.append(rrb.Spatial3DView(name="PRSM", origin=NUT, contents=f"{WORLD}/**", eye_controls=eye))
    left_parts.append(rrb.Tabs(*heat, about) if heat or scene else about)
    left = rrb.Vertical(*left_parts, row_shares=[3, 1] if len(left_parts) == 2 else None)
    root = rrb.Horizontal(left, right, column_shares=[1, 1]) if right is not None else left
    return rrb.Blueprint(root, rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))
