"""`prsm-sweep report`'s figures: titled, with units on both axes and ticks that do not overlap (read
back from the figures), at the report's size. Units follow the names: an output's own unit
(prsm_sim.OUTPUT_FIELDS), else the SI suffix of the field (`_kg` kg, `_n` N), friction coefficients 1."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pd = pytest.importorskip("pandas")
pytest.importorskip("scipy")


def test_units_come_from_the_names():
    from prsm_ros.sweep.report import axis_label, unit_of
    assert unit_of("efficiency") == "1" and unit_of("nut_position_m@max") == "m"
    assert unit_of("friction.mu_screw_roller") == "1" and unit_of("mass.moved_mass_kg") == "kg"
    assert unit_of("peak_tooth_normal_force_n") == "N" and unit_of("friction.viscous_n_s_m") == "N·s/m"
    assert unit_of("l10_hours") == "h" and axis_label("screw_speed_rad_s@rms") == "screw_speed_rad_s@rms [rad/s]"


def test_sweep_figures_are_titled_labelled_and_legible(tmp_path, monkeypatch):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from prsm_ros.sweep import report as sweep_report
    rng = np.random.default_rng(3)
    n = 24
    mu = np.repeat([0.02, 0.05, 0.08, 0.11], 6)
    mass = rng.uniform(30.0, 70.0, n)
    df = pd.DataFrame({"status": ["ok"] * (n - 1) + ["failed"], "friction.mu_screw_roller": mu,
                       "mass.moved_mass_kg": mass, "efficiency": (1 - mu) / (1 + mu) + rng.normal(0, 1e-3, n)})
    inputs, metrics = ["friction.mu_screw_roller", "mass.moved_mass_kg"], ["efficiency"]
    sens = sweep_report.sensitivities(df, inputs, metrics)
    kept = []
    real_close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    paths = sweep_report.plots(df, inputs, metrics, sens, tmp_path, "model fu2018, preset s30, scenario heavy")
    assert [Path(p).name for p in paths] == ["hist_efficiency.png", "scatter_friction.mu_screw_roller__efficiency.png",
                                             "scatter_mass.moved_mass_kg__efficiency.png", "tornado_efficiency.png"]
    for fig, path in zip(kept, paths, strict=True):
        ax = fig.axes[0]
        title = ax.get_title(loc="left")
        assert "23 runs" in title and "model fu2018, preset s30, scenario heavy" in title, path
        assert "[" in ax.get_xlabel(), (path, ax.get_xlabel())
        w, h = fig.get_size_inches() * fig.dpi
        assert w >= 600, path  # the report's figures are at least this wide, not 400 px
        # tick labels of the x axis do not overlap one another
        fig.canvas.draw()
        boxes = [t.get_window_extent() for t in ax.get_xticklabels() if t.get_text()]
        assert len(boxes) >= 3 and all(not a.overlaps(b) for a, b in zip(boxes, boxes[1:], strict=False)), path
        assert Path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    scatter = kept[1].axes[0]
    assert scatter.get_ylabel() == "efficiency [1]" and scatter.get_xlabel() == "friction.mu_screw_roller [1]"
    rho = next(r["spearman_rho"] for r in sens["efficiency"] if r["input"] == "friction.mu_screw_roller")
    assert rho < -0.9 and f"Spearman ρ = {rho:+.2f}" in scatter.get_title(loc="left")  # falls with μ
    assert kept[2].axes[0].get_xlabel() == "mass.moved_mass_kg [kg]"
    for fig in kept:
        real_close(fig)
