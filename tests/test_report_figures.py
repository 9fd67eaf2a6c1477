"""What `prsm-bag report`'s figures and text say, read back from the figures themselves (titles, labels,
lines, limits), never from pixels.

Oracles: the elastic model's thread loads sum to the axial force (a force balance over the threads),
so the load per thread and roller averages F / (N_R N_T); the lead of the s30 preset (5 starts × 1 mm)
turns L10 revolutions into km of travel; the efficiency the text prints is the energies' ratio, so the
running curve ends on it.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from prsm_sim import Simulator, preset
from prsm_ros.bag.reader import open_bag
from prsm_ros.bag.report import report, summary_text
from prsm_ros.mcap.offline import write_trajectory_mcap

# the figures of a report share one module-scoped run of several seconds: the whole file is in the slow tier
pytestmark = pytest.mark.slow

pytest.importorskip("mcap")
DT = 1e-3


def _bag(tmp_path, model, steps, torque_nm, load_n):
    p = preset("s30")
    traj = Simulator(p, model, DT).run(np.full(steps, torque_nm), load_n)
    return write_trajectory_mcap(tmp_path / f"{model}.mcap", traj, p, model, preset_name="s30", progress=False), p


def _reported(path: Path, out: Path) -> tuple[dict, dict]:
    """The report of `path` with plots into `out`, and every figure it saved, by file name, still open."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from prsm_ros.bag import figures as f
    kept: dict[str, object] = {}
    real_save = f.save

    def keep(fig, axes, path, *args, **kwargs):
        kept[Path(path).name] = fig
        return real_save(fig, axes, path, *args, **kwargs)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(f, "save", keep)
        mp.setattr(plt, "close", lambda *a, **k: None)
        r = report(open_bag(path), out, progress=False)
    return r, kept


def _reported_run(tmp_path_factory, model: str, steps: int, torque_nm: float, load_n: float):
    tmp = tmp_path_factory.mktemp(model)
    path, p = _bag(tmp, model, steps, torque_nm, load_n)
    yield (path, p, tmp / "rep", *_reported(path, tmp / "rep"))
    import matplotlib.pyplot as plt
    plt.close("all")


@pytest.fixture(scope="module")
def elastic(tmp_path_factory):
    """A loaded elastic run: its thread loads are the solved, non-uniform distribution."""
    yield from _reported_run(tmp_path_factory, "elastic", 60, 20.0, 20_000.0)


@pytest.fixture(scope="module")
def fu(tmp_path_factory):
    yield from _reported_run(tmp_path_factory, "fu2018", 80, 6.0, 5_000.0)


def test_load_distribution_of_an_elastic_run_is_not_uniform_and_balances_the_force(elastic):
    path, p, out, r, figures = elastic
    assert (out / "load_distribution.png").is_file() and str(out / "load_distribution.png") in r["plots"]
    d = r["load_distribution"]
    n_r, n_t = p.geometry.n_rollers, p.geometry.n_teeth
    assert (d["rollers"], d["threads"]) == (n_r, n_t) and "per_thread" in d["source"]
    assert d["max_over_uniform_at_peak"] > 1.05  # the elastic nut loads its first threads more
    fig = figures["load_distribution.png"]
    top, share = fig.axes[:2]
    uniform = d["peak_axial_force_n"] / (n_r * n_t)
    dashed = [ln for ln in top.get_lines() if ln.get_linestyle() == "--"]
    assert len(dashed) == 1 and dashed[0].get_ydata()[0] == pytest.approx(uniform, rel=1e-12)
    # the mean-per-roller curve at the peak, summed over the threads and rollers, is the axial force
    peak_curve = next(ln for ln in top.get_lines() if ln.get_label().startswith("at the peak"))
    assert peak_curve.get_xdata().size == n_t
    assert np.sum(peak_curve.get_ydata()) * n_r == pytest.approx(d["peak_axial_force_n"], rel=1e-9)
    assert np.ptp(peak_curve.get_ydata()) > 0.05 * uniform
    assert top.get_ylim()[0] == 0.0 and share.get_ylim()[0] == 0.0
    assert "N" in top.get_ylabel() and "thread" in share.get_xlabel()
    assert "elastic.mcap" in fig._suptitle.get_text() and "× the uniform share" in fig._suptitle.get_text()


def test_every_figure_is_titled_gridded_and_flat_quantities_read_flat(fu):
    path, _, _, r, figures = fu
    names = {Path(f).name for f in r["plots"]}
    assert {"motion.png", "loads.png", "power.png", "internal_loads.png", "load_distribution.png"} <= names
    assert set(figures) == names
    for name, fig in figures.items():
        title = fig._suptitle.get_text()
        for part in ("fu2018.mcap", "model fu2018", "preset s30", "load 5 kN", "controller:"):
            assert part in title, (name, title)
        for a in fig.axes:
            if a.get_visible() and a.get_lines():
                assert any(g.get_visible() for g in a.get_xgridlines()), (name, a.get_ylabel())
                assert a.get_ylabel() and "[" in a.get_ylabel(), (name, a.get_ylabel())
    # efficiency on [0, 1.05]; the running curve ends on the text's figure
    eff = next(a for a in figures["power.png"].axes if a.get_ylabel().startswith("efficiency"))
    assert eff.get_ylim() == pytest.approx((0.0, 1.05))
    fwd = next(ln for ln in eff.get_lines() if ln.get_label().startswith("forward"))
    y = np.asarray(fwd.get_ydata(), dtype=float)
    assert y[np.isfinite(y)][-1] == pytest.approx(r["efficiency"]["forward"], rel=1e-12)
    # fu2018 shares the load equally: the distribution says so
    assert r["load_distribution"]["max_over_uniform_at_peak"] == pytest.approx(1.0, rel=1e-9)
    assert "uniform" in figures["load_distribution.png"]._suptitle.get_text()


def test_internal_loads_are_small_multiples_one_colour_per_panel(fu):
    r, figures = fu[3], fu[4]
    fig = figures["internal_loads.png"]
    panels = [a for a in fig.axes if a.get_visible()]
    moving = [n for n, pk in r["peak_loads"].items() if pk["peak_abs"] > 0]
    assert len(panels) == len(moving)  # one panel per force quantity that is not zero throughout
    for a in panels:
        lines, bands = a.get_lines(), a.collections
        assert len(lines) == 1 and len(bands) == 1  # the mean and the min–max band across rollers
        assert lines[0].get_color() == "tab:blue" and a.get_ylim()[0] <= 0.0 <= a.get_ylim()[1]
        assert a.get_title()


def test_text_lists_only_peaks_that_moved_and_life_in_km_and_hours(fu):
    _, p, _, r, _ = fu
    text = summary_text(r)
    # a peak of exactly zero is not listed (a number ending in 0, such as 5080 N, is)
    assert not re.search(r"(?<![\d.])0 N at t", text) and " 0 mm/s" not in text
    zero = [n for n, pk in r["peak_loads"].items() if pk["peak_abs"] == 0]
    if zero:
        assert "zero throughout: " + ", ".join(zero) in text
    life = r["life"]
    lead = p.geometry.starts * p.geometry.pitch_m  # 5 starts × 1 mm
    assert life["nut_travel_per_revolution_m"] == pytest.approx(lead, rel=1e-6)
    assert life["l10_travel_km"] == pytest.approx(life["l10_revolutions"] * lead / 1e3, rel=1e-6)
    line = next(ln for ln in text.splitlines() if ln.startswith("L10"))
    assert "km of nut travel" in line and " h " in line and "recorded duty cycle" in line and "e+" not in line


def test_long_run_adds_a_zoom_on_its_busiest_window(tmp_path):
    from test_bag_report import write_joint_state_bag
    # 14 s at 100 Hz: still, then a 1 s burst of motion at 9 s
    msgs = []
    for k in range(1400):
        t = k * 0.01
        w = 50.0 * np.sin(2 * np.pi * 3 * t) if 9.0 <= t < 10.0 else 0.0
        msgs.append((1_000_000_000 + k * 10_000_000, ["screw_joint", "nut_joint"], [0.0, 0.0], [w, w * 8e-4],
                     [0.1, 300.0 if t < 5 else 900.0]))
    path = write_joint_state_bag(tmp_path / "bag", {"/joint_states": msgs})
    r, figures = _reported(path, tmp_path / "rep")
    assert {"motion_zoom.png", "loads_zoom.png"} <= {Path(f).name for f in r["plots"]}
    zoom = figures["motion_zoom.png"].axes[1]
    t = np.asarray(zoom.get_lines()[0].get_xdata())
    assert t.min() >= 8.0 and t.max() <= 11.0 and 1.0 <= t.max() - t.min() <= 1.5
    assert "busiest window" in figures["motion_zoom.png"]._suptitle.get_text()


def test_load_steps_are_marked_with_the_new_load():
    from prsm_ros.bag.figures import load_steps
    t = np.arange(1000) * 1e-3
    f = np.where(t < 0.5, 100.0, 2000.0)
    assert load_steps(t, f) == [(0.5, "load → 2 kN", "black")]
    assert load_steps(t, np.full(t.size, 300.0)) == []  # constant: nothing to mark
    assert load_steps(t, 1000.0 * t) == []  # a ramp varies continuously: no step


def test_marks_at_mode_switches_thread_end_contact_and_events():
    from prsm_sim.actuator import ACTUATOR_QUANTITIES
    from prsm_ros.bag.report import Series, _marks
    t = np.arange(1, 101) * 1e-3
    names = [n for n, _ in ACTUATOR_QUANTITIES]
    block = np.zeros((t.size, len(names)))
    block[50:, names.index("mode")] = 1.0  # effort → velocity at t = 0.051 s
    block[70:80, names.index("thread_end")] = 1.0  # pressing on a thread end for 10 steps
    labels = {"segments": [{"name": "actuator", "dims": ["quantity"],
                            "quantities": [{"name": n, "unit": u} for n, u in ACTUATOR_QUANTITIES]}]}
    internal = (Series(t, {"actuator": block}), labels)
    marks = _marks(internal, [{"time_s": 0.02, "code": "thread_end_reached", "severity": "warn"}])
    assert (0.02, "thread_end_reached", "darkorange") in marks.lines
    assert (pytest.approx(0.051), "mode → velocity", "dimgray") in [(a, b, c) for a, b, c in marks.lines]
    assert [(a, b, label) for a, b, label, _ in marks.spans] == [(pytest.approx(0.071), pytest.approx(0.081),
                                                                  "thread end")]
