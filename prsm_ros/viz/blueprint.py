"""The default Rerun layout of a PRSM recording: 3D scene, heat maps and time series, no clicking needed.

    ┌──────────────────────────┬──────────────────────────────────────┐
    │                          │ nut position      │ nut force        │
    │   3D: screw, rollers,    ├───────────────────┼──────────────────┤
    │   nut, force arrows      │ screw speed       │ screw torque     │
    │                          ├───────────────────┼──────────────────┤
    ├──────────────────────────┤ ratio, efficiency │ slip             │
    │ heat maps roller × tooth,├──────────────────────────────────────┤
    │ bars along the nut·about │ per-roller forces, carrier, power    │
    └──────────────────────────┴──────────────────────────────────────┘

Views are built only for what the recording holds (a bag with joint states only has no heat map,
no slip and no per-roller tab), so nothing opens empty. The time panel shows `sim_time`, collapsed to
its slider so the views get the height.
"""

from __future__ import annotations

from collections.abc import Iterable

import rerun.blueprint as rrb

from prsm_sim import InternalLayout

from prsm_ros.viz.scene import ABOUT, LOADS, NUT, WORLD, along_nut_path, tooth_quantities
from prsm_ros.viz.series import TIMELINE, block_path, input_path, scalar_path, series_blocks, shown

# (title, scalar outputs, recorded inputs) of the scalar plots, in reading order; one series per
# quantity: the recorded torque command is not drawn beside the applied screw torque it equals
SCALAR_VIEWS: tuple[tuple[str, tuple[str, ...], tuple[str, ...]], ...] = (
    ("Nut position [mm]", ("nut_position_m",), ("nut_position_reference",)),
    ("Nut force [N]", ("nut_force_n", "load_force_n"), ()),
    ("Screw and carrier speed [rad/s]", ("screw_speed_rad_s", "carrier_speed_rad_s"), ()),
    ("Screw torque [N·m]", ("screw_torque_nm",), ()),
    ("Carrier/screw ratio, efficiency [1]", ("speed_ratio", "efficiency"), ()),
    ("Slip speed [mm/s]", ("slip_speed_m_s",), ()),
)
POWER_VIEW = ("Power [W]", ("power_in_w", "power_out_w", "power_dissipated_w"))


def _series_view(title: str, paths: list[str]) -> rrb.TimeSeriesView:
    return rrb.TimeSeriesView(name=title, origin="/", contents=paths)


def _scalar_plots(have: set[str], have_inputs: set[str]) -> list[rrb.TimeSeriesView]:
    plots = []
    for title, outs, ins in SCALAR_VIEWS:
        paths = [scalar_path(n) for n in outs if n in have] + [input_path(n) for n in ins if n in have_inputs]
        if paths:
            plots.append(_series_view(title, paths))
    return plots


def _block_tabs(have: set[str], layout: InternalLayout) -> list[rrb.TimeSeriesView]:
    """Forces per roller; every quantity of a plain (quantity,) block; the powers."""
    tabs = []
    for b in series_blocks(layout):
        for q, unit in b.quantities:
            name, shown_unit, _ = shown(q, unit)
            if len(b.dims) == 2 and unit == "N":
                tabs.append(_series_view(f"{q} per {b.dims[0]} [N]", [block_path(b.name, q, unit)]))
            elif len(b.dims) == 1:
                tabs.append(_series_view(f"{b.name}: {name} [{shown_unit}]", [block_path(b.name, q, unit)]))
    power = [scalar_path(n) for n in POWER_VIEW[1] if n in have]
    if power:
        tabs.append(_series_view(POWER_VIEW[0], power))
    return tabs


def _tooth_views(layout: InternalLayout) -> list:
    """Per tooth force: the roller × tooth heat map and the bars of the load along the nut (the scale in N)."""
    views: list = []
    for block, _, q, _ in tooth_quantities(layout):
        views.append(rrb.TensorView(name=f"{q} [N] roller × tooth (colours: this frame's min → max)",
                                    origin=f"{LOADS}/{block}/{q}",
                                    scalar_mapping=rrb.TensorScalarMapping(colormap="turbo")))
        views.append(rrb.BarChartView(name=f"{q} [N] along the nut (mean over rollers, per tooth)",
                                      origin=along_nut_path(block, q)))
    return views


def _scene_view(eye_distance_m: float | None) -> rrb.Spatial3DView:
    # the view's origin is the nut, so nut, carrier, rollers and arrows stay in frame over any
    # stroke and the screw is seen turning and sliding through them
    eye = None
    if eye_distance_m:
        d = eye_distance_m
        eye = rrb.EyeControls3D(position=[d, -d, 0.6 * d], look_target=[0.0, 0.0, 0.0], eye_up=[0.0, 0.0, 1.0])
    return rrb.Spatial3DView(name="PRSM", origin=NUT, contents=f"{WORLD}/**", eye_controls=eye)


def default_blueprint(scalar_names: Iterable[str], layout: InternalLayout, *, scene: bool = True,
                      inputs: Iterable[str] = (), eye_distance_m: float | None = None) -> rrb.Blueprint:
    """The layout for a recording with these scalar series, this internal layout and these inputs.

    `scene=False` leaves out the 3D view (no geometry known).
    """
    have = set(scalar_names)
    plots = _scalar_plots(have, set(inputs))
    tabs = _block_tabs(have, layout)
    rows = [rrb.Horizontal(*plots[i:i + 2]) for i in range(0, len(plots), 2)]
    if tabs:
        rows.append(rrb.Tabs(*tabs))
    right = rrb.Vertical(*rows) if rows else None
    teeth = _tooth_views(layout)
    about = rrb.TextDocumentView(name="About", origin=ABOUT)
    left_parts = [_scene_view(eye_distance_m)] if scene else []
    left_parts.append(rrb.Tabs(*teeth, about) if teeth or scene else about)
    left = rrb.Vertical(*left_parts, row_shares=[3, 1] if len(left_parts) == 2 else None)
    root = rrb.Horizontal(left, right, column_shares=[1, 1]) if right is not None else left
    return rrb.Blueprint(root, rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"))
