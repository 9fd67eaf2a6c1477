"""The figures of `prsm-bag report`: what an engineer prints from a recorded run.

Every figure carries a title naming the bag, the model, the preset, the load and the controller
(`Context`), a grid, and the run's marks: a labelled vertical line at each event (`~/events`:
faults, thread ends, ownership, parameter changes) and at each step of the applied load, shaded
spans where the actuator block records the brake engaged, an end stop in contact or a fault active.
Each quantity keeps one colour within a figure and no colour means two things: the rollers of a
per-roller quantity are one min–max band (across rollers) around their mean, and the internal loads
are small multiples, one panel per quantity. Magnitudes are drawn from zero and the efficiency on
[0, 1.05], so a flat quantity reads flat. A run longer than `LONG_RUN_S` adds `zoom.png`: the
motion and loads over its busiest window (the largest total variation of screw speed and nut force).

`load_distribution.png`: the axial load each thread (tooth row) along the nut carries, per roller,
at the instant of the largest axial force and averaged over the run, against the uniform share
F / (N_R N_T). A model that reports the thread loads (`per_thread.thread_load_n`: the elastic model's
solved distribution) gives their total; the split over rollers and teeth follows the tooth normal
forces of the `per_tooth` block, scaled so that they sum to the axial force (each tooth's contact
normal makes the same angle with the axis, so the axial components are in the normal forces' ratio).
"""

from __future__ import annotations

import math
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# a run longer than this gets a zoom on its busiest window beside the whole-run figures
LONG_RUN_S = 10.0
ZOOM_FRACTION = 0.1  # the zoom window's share of the run (at least ZOOM_MIN_S)
ZOOM_MIN_S = 1.0
MAX_LABELLED_MARKS = 12
LABEL_GAP_FRACTION = 0.02  # a mark closer than this share of the time axis to a labelled one goes unlabelled  # more events than this: only the first of each kind carries its label
LOAD_STEP_FRACTION = 0.05  # a load change of more than this share of the load's span is a load step
MAX_LOAD_STEPS = 20  # more steps than this: the load varies continuously, none is marked
WIDTH_IN = 10.0
DPI = 110

# data colours (one per quantity within a figure); the marks use colours outside this set
C_MAIN, C_SECOND, C_THIRD, C_FOURTH = "tab:blue", "tab:orange", "tab:green", "tab:purple"
MARK_COLOURS = {"error": "darkred", "warn": "darkorange", "info": "dimgray", "load": "black"}
SPAN_COLOURS = {"brake": "gold", "end stop": "sienna", "thread end": "tan", "fault": "salmon"}


@dataclass(frozen=True)
class Context:
    """What every figure's title says about the run."""

    bag: str
    model: str
    preset: str
    load: str
    controller: str
    description: str = ""

    def title(self, what: str) -> str:
        head = (f"{what} — {self.bag}\nmodel {self.model}, preset {self.preset}, load {self.load}, "
                f"controller: {self.controller}")
        return head + ("\n" + "\n".join(textwrap.wrap(self.description, 120)) if self.description else "")


@dataclass(frozen=True)
class Marks:
    """Event lines (time, label, colour) and shaded spans (start, end, label, colour) of a run."""

    lines: tuple[tuple[float, str, str], ...] = ()
    spans: tuple[tuple[float, float, str, str], ...] = ()


def load_steps(t: np.ndarray, load_n: np.ndarray | None) -> list[tuple[float, str, str]]:
    """A mark at each step of the applied load (a change of more than LOAD_STEP_FRACTION of its span
    from one sample to the next); none when the load never steps or varies continuously."""
    if load_n is None or load_n.size < 2:
        return []
    f = np.asarray(load_n, dtype=float)
    ok = np.isfinite(f)
    if ok.sum() < 2:
        return []
    span = float(np.ptp(f[ok]))
    if span <= 0:
        return []
    jump = np.flatnonzero(np.abs(np.diff(f)) > LOAD_STEP_FRACTION * span) + 1
    if jump.size == 0 or jump.size > MAX_LOAD_STEPS:
        return []
    return [(float(t[k]), f"load → {force_text(f[k])}", MARK_COLOURS["load"]) for k in jump]


def force_text(f: float) -> str:
    return f"{f / 1e3:.3g} kN" if abs(f) >= 1e3 else f"{f:.3g} N"


# -- drawing helpers -------------------------------------------------------------------------
def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def new_figure(rows: int, cols: int = 1, *, height_in: float = 2.4, sharex: bool = True, width_in: float = WIDTH_IN):
    plt = _pyplot()
    fig, ax = plt.subplots(rows, cols, sharex=sharex, figsize=(width_in, height_in * rows + 0.9), squeeze=False)
    for a in ax.ravel():
        a.grid(True, which="major", alpha=0.4, linewidth=0.6)
    return fig, ax


def legend(a) -> None:
    """Outside the axes on the right, so it never covers a curve."""
    handles, labels = a.get_legend_handles_labels()
    if handles:
        a.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small",
                 borderaxespad=0.0, frameon=False)


def from_zero(a, values: np.ndarray, *, margin: float = 1.1) -> None:
    """y from 0 (or the negative end) to above the largest value: a flat magnitude reads flat."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return
    lo, hi = min(0.0, float(v.min())), max(0.0, float(v.max()))
    if hi == lo:
        hi = lo + 1.0
    a.set_ylim(lo * margin, hi * margin)


def band(a, t: np.ndarray, per_element: np.ndarray, colour: str, label: str) -> None:
    """Mean line and min–max band across the elements (columns) of `per_element` (samples × elements)."""
    with np.errstate(invalid="ignore"):
        lo, hi, mean = (np.nanmin(per_element, axis=1), np.nanmax(per_element, axis=1),
                        np.nanmean(per_element, axis=1))
    a.fill_between(t, lo, hi, color=colour, alpha=0.25, linewidth=0,
                   label=f"{label}: min–max of {per_element.shape[1]}" if per_element.shape[1] > 1 else None)
    a.plot(t, mean, color=colour, linewidth=1.2, label=f"{label}: mean" if per_element.shape[1] > 1 else label)


def mark(axes, marks: Marks, *, t_range: tuple[float, float] | None = None) -> None:
    """Event lines (labelled at the top panel) and shaded spans on every panel, one key for them."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    lines = [m for m in marks.lines if t_range is None or t_range[0] <= m[0] <= t_range[1]]
    spans = [s for s in marks.spans if t_range is None or (s[1] >= t_range[0] and s[0] <= t_range[1])]
    for a in axes:
        for t0, t1, _, colour in spans:
            a.axvspan(t0, t1, color=colour, alpha=0.25, linewidth=0)
        for te, _, colour in lines:
            a.axvline(te, color=colour, linestyle=":", linewidth=1.1)
    top = axes[0]
    lo, hi = top.get_xlim() if t_range is None else t_range
    gap = LABEL_GAP_FRACTION * (hi - lo)
    labelled: set[str] = set()
    last = -math.inf
    for te, label, colour in lines:
        kind = label.split(" ")[0]
        # crowded marks: label the first of a cluster, and only the first of each kind when there are many
        if te - last < gap or (len(lines) > MAX_LABELLED_MARKS and kind in labelled):
            continue
        labelled.add(kind)
        last = te
        top.annotate(label, xy=(te, 1.0), xycoords=("data", "axes fraction"), xytext=(2, -2),
                     textcoords="offset points", rotation=90, va="top", ha="left", fontsize="x-small", color=colour)
    keys: dict[str, object] = {}
    for _, label, colour in lines:
        keys.setdefault("load step" if label.startswith("load") else "mode switch" if label.startswith("mode")
                        else f"event {label}",
                        Line2D([], [], color=colour, linestyle=":"))
    for _, _, label, colour in spans:
        keys.setdefault(label, Patch(color=colour, alpha=0.4))
    if keys:
        bottom = axes[-1]
        curves = bottom.get_legend()  # a second legend replaces the first: keep it as an artist
        bottom.legend(list(keys.values()), list(keys)[:], loc="lower left", bbox_to_anchor=(1.01, 0.0),
                      fontsize="x-small", frameon=False, borderaxespad=0.0)
        if curves is not None:
            bottom.add_artist(curves)


def save(fig, axes, path: Path, title: str, marks: Marks | None = None, *, xlabel: str = "time [s]",
         t_range: tuple[float, float] | None = None) -> Path:
    axes[-1].set_xlabel(xlabel)
    if marks is not None:
        mark(axes, marks, t_range=t_range)
    fig.suptitle(title, fontsize="medium", x=0.02, ha="left")
    fig.tight_layout()
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    _pyplot().close(fig)
    return path


def busiest_window(t: np.ndarray, *signals: np.ndarray) -> tuple[float, float]:
    """The window (ZOOM_FRACTION of the run, at least ZOOM_MIN_S) where the signals, each scaled by
    its span, vary the most (total variation)."""
    width = max(ZOOM_MIN_S, ZOOM_FRACTION * float(t[-1] - t[0]))
    activity = np.zeros(t.size)
    for s in signals:
        s = np.nan_to_num(np.asarray(s, dtype=float))
        span = float(np.ptp(s))
        if span > 0:
            activity[1:] += np.abs(np.diff(s)) / span
    c = np.concatenate(([0.0], np.cumsum(activity)))
    end = np.searchsorted(t, t + width, side="right")
    k = int(np.argmax(c[end] - c[np.arange(t.size)]))
    t0 = float(t[k])
    return t0, min(t0 + width, float(t[-1]))


# -- the load along the nut ------------------------------------------------------------------
def _quantity(s, labels: dict, block: str, name: str) -> np.ndarray | None:
    for seg in labels["segments"]:
        if seg["name"] == block and "quantities" in seg:
            names = [q["name"] for q in seg["quantities"]]
            if name in names:
                return s.values[block][..., names.index(name)]
    return None


def _tooth_normals(s, labels: dict) -> np.ndarray | None:
    """time × roller × tooth: the screw-side tooth normal force (else the first normal force per tooth)."""
    for seg in labels["segments"]:
        if seg["name"] == "per_tooth" and seg.get("dims") == ["roller", "tooth", "quantity"]:
            names = [q["name"] for q in seg["quantities"]]
            pick = next((n for n in names if n.startswith("screw") and "normal" in n),
                        next((n for n in names if "normal" in n), None))
            if pick is not None:
                return np.abs(s.values["per_tooth"][..., names.index(pick)])
    return None


def thread_loads(s, labels: dict) -> dict | None:
    """Axial load per thread along the nut, per roller (time × roller × tooth, N), and where it comes from.

    None when the model reports no per-tooth forces (the ideal and jones2016 models).
    """
    normals = _tooth_normals(s, labels)
    if normals is None:
        return None
    per_thread = _quantity(s, labels, "per_thread", "thread_load_n")
    if per_thread is not None:
        axial, source = np.abs(per_thread).sum(axis=-1), "per_thread.thread_load_n (the model's solved distribution)"
    else:
        carrier = _quantity(s, labels, "carrier", "axial_force_n")
        if carrier is not None:
            axial, source = np.abs(carrier), "carrier.axial_force_n"
        elif "nut_force_n" in s.values:
            axial, source = np.abs(s.values["nut_force_n"]), "nut_force_n"
        else:
            return None
    total = normals.sum(axis=(1, 2))
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(total > 0, axial / total, 0.0)
    if per_thread is not None:  # the thread loads themselves, split over the rollers by their normal forces
        roller_part = np.where(normals.sum(axis=1, keepdims=True) > 0,
                               normals / np.maximum(normals.sum(axis=1, keepdims=True), 1e-300), 1.0 / normals.shape[1])
        loads = roller_part * np.abs(per_thread)[:, None, :]
    else:
        loads = normals * scale[:, None, None]
    return {"loads_n": loads, "axial_n": np.nan_to_num(axial), "source": source}


def _distribution(s, labels: dict) -> dict | None:
    """`thread_loads` at the peak instant and averaged over the loaded samples, with the uniform shares."""
    d = thread_loads(s, labels)
    if d is None or not np.any(d["axial_n"] > 0):
        return None
    loads, axial = d["loads_n"], d["axial_n"]
    k = int(np.argmax(axial))
    n_r, n_t = loads.shape[1:]
    loaded = axial > 0
    return {**d, "k": k, "rollers": int(n_r), "threads": int(n_t),
            "average_n": loads[loaded].mean(axis=0),  # roller × tooth
            "uniform_peak_n": axial[k] / (n_r * n_t), "uniform_average_n": axial[loaded].mean() / (n_r * n_t)}


def load_distribution_summary(s, labels: dict) -> dict | None:
    """Peak instant, the largest thread load over the uniform share (at the peak and averaged), source."""
    d = _distribution(s, labels)
    if d is None:
        return None
    k = d["k"]
    return {"peak_time_s": float(s.t_s[k]), "peak_axial_force_n": float(d["axial_n"][k]),
            "max_over_uniform_at_peak": float(d["loads_n"][k].max() / d["uniform_peak_n"]),
            "max_over_uniform_averaged": float(d["average_n"].max() / d["uniform_average_n"]),
            "rollers": d["rollers"], "threads": d["threads"], "source": d["source"]}


def load_distribution_figure(path: Path, s, labels: dict, ctx: Context) -> Path | None:
    """`load_distribution.png`: load per thread along the nut (rollers as a band) against the uniform share."""
    d = _distribution(s, labels)
    if d is None:
        return None
    loads, axial, avg, k = d["loads_n"], d["axial_n"], d["average_n"], d["k"]
    n_r, n_t = d["rollers"], d["threads"]
    uniform_peak, uniform_avg = d["uniform_peak_n"], d["uniform_average_n"]
    x = np.arange(1, n_t + 1)
    fig, ax = new_figure(2, height_in=2.9, sharex=True)
    top, share = ax[0, 0], ax[1, 0]
    # the uniform share drawn first and thicker, so curves that sit on it stay visible over it
    top.axhline(uniform_peak, color="black", linestyle="--", linewidth=1.6, zorder=1,
                label="uniform share F/(N_R N_T) at the peak")
    top.axhline(uniform_avg, color="dimgray", linestyle=":", linewidth=1.6, zorder=1,
                label="uniform share, run average")
    share.axhline(1.0, color="black", linestyle="--", linewidth=1.6, zorder=1, label="uniform share")
    for a, values in ((top, (loads[k], avg)), (share, (loads[k] / uniform_peak, avg / uniform_avg))):
        for v, colour, what in zip(values, (C_MAIN, C_SECOND), (f"at the peak, t = {s.t_s[k]:.3f} s", "run average"), strict=True):
            band(a, x, v.T, colour, what)
        from_zero(a, np.concatenate([values[0].ravel(), values[1].ravel(), [a.get_lines()[0].get_ydata()[0]]]))
    legend(top)
    top.set_ylabel("axial load per thread\nand roller [N]")
    share.set_ylabel("load / uniform share [1]")
    ratio = loads[k].max() / uniform_peak
    note = ("uniform: this run's model shares the load equally among the threads" if abs(ratio - 1.0) < 1e-6
            else f"largest thread {ratio:.2f}× the uniform share at the peak")
    what = (f"Load per thread along the nut: {n_r} rollers × {n_t} threads, peak axial force "
            f"{force_text(axial[k])}\n{note}")
    fig.text(0.01, -0.01, f"source: {d['source']}; thread 1 is the first tooth row of the layout",
             fontsize="x-small", color="dimgray")
    return save(fig, [top, share], path, ctx.title(what), xlabel="thread along the nut [tooth row]")


# -- the run's figures -----------------------------------------------------------------------
@dataclass(frozen=True)
class RunData:
    """What the run's figures plot (SI; NaN where a sample has no value)."""

    t: np.ndarray
    joints: dict
    truth: dict | None = None
    reference_m: np.ndarray | None = None
    error_m: np.ndarray | None = None
    internal: tuple | None = None  # (Series, labels)
    efficiency: dict | None = None  # the report's efficiency block (the text's figures)


def motion_figure(path: Path, d: RunData, ctx: Context, marks: Marks, t_range=None) -> Path:
    n = 3 if d.error_m is not None else 2
    fig, ax = new_figure(n)
    a = ax[:, 0]
    suffix = " (measured)" if d.truth is not None else ""
    a[0].plot(d.t, d.joints["nut_position_m"] * 1e3, color=C_MAIN, label="nut position" + suffix)
    if d.truth is not None:
        a[0].plot(d.t, d.truth["nut_position_m"] * 1e3, color=C_THIRD, linestyle="-.", linewidth=1.0,
                  label="ground truth")
    if d.reference_m is not None:
        a[0].plot(d.t, d.reference_m * 1e3, color="black", linestyle="--", linewidth=1.0, label="reference")
    a[0].set_ylabel("nut position x_nut [mm]")
    a[1].plot(d.t, d.joints["screw_speed_rad_s"], color=C_SECOND, label="screw speed" + suffix)
    if d.truth is not None:
        a[1].plot(d.t, d.truth["screw_speed_rad_s"], color=C_THIRD, linestyle="-.", linewidth=1.0,
                  label="ground truth")
    a[1].set_ylabel("screw speed ω_S [rad/s]")
    if d.error_m is not None:
        a[2].plot(d.t, d.error_m * 1e6, color=C_FOURTH, label="reference − nut position")
        a[2].axhline(0.0, color="black", linewidth=0.6)
        a[2].set_ylabel("tracking error [µm]")
    return _save_timed(fig, list(a), path, ctx, "Motion", marks, t_range)


def loads_figure(path: Path, d: RunData, ctx: Context, marks: Marks, t_range=None) -> Path:
    fig, ax = new_figure(2)
    a = ax[:, 0]
    a[0].plot(d.t, d.joints["screw_torque_nm"], color=C_FOURTH, label="screw torque τ_S")
    a[0].set_ylabel("screw torque [N·m]")
    label = "nut force" + (" (load cell)" if d.truth is not None else " (thread)")
    a[1].plot(d.t, d.joints["nut_force_n"], color=C_MAIN, label=label)
    if d.truth is not None:
        a[1].plot(d.t, d.truth["nut_force_n"], color=C_THIRD, linestyle="-.", linewidth=1.0, label="ground truth")
    if d.internal is not None and "load_force_n" in d.internal[0].values:
        a[1].plot(d.internal[0].t_s, d.internal[0].values["load_force_n"], color=C_SECOND, linestyle="--",
                  label="applied load")
    a[1].set_ylabel("force [N]")
    return _save_timed(fig, list(a), path, ctx, "Torque and force", marks, t_range)


def _save_timed(fig, axes, path: Path, ctx: Context, what: str, marks: Marks, t_range) -> Path:
    """Legends, the zoom window (when given) and the title of a time figure, then `save`."""
    for a in axes:
        legend(a)
    if t_range is not None:
        axes[0].set_xlim(*t_range)
        what = f"{what}, zoom on the busiest window {t_range[0]:.4g}–{t_range[1]:.4g} s"
    return save(fig, axes, path, ctx.title(what), marks, t_range=t_range)


def running_efficiency(terms: dict) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward efficiency of the run so far at each sample (the text's figure at the
    last sample), from the per-sample energy terms of `report.energy_terms`; NaN until power flowed."""
    out_f = np.cumsum(np.where(terms["forward"], terms["e_out"], 0.0))
    diss_f = np.cumsum(np.where(terms["forward"], terms["e_diss"], 0.0))
    in_b = np.cumsum(np.where(terms["backward"], -terms["e_in"], 0.0))
    diss_b = np.cumsum(np.where(terms["backward"], terms["e_diss"], 0.0))
    tiny = terms["tiny"]
    with np.errstate(invalid="ignore", divide="ignore"):
        fwd = np.where((out_f + diss_f > tiny) & (out_f > tiny), out_f / (out_f + diss_f), np.nan)
        bwd = np.where((in_b + diss_b > tiny) & (in_b > tiny), in_b / (in_b + diss_b), np.nan)
    return fwd, bwd


def power_figure(path: Path, d: RunData, ctx: Context, marks: Marks, terms: dict) -> Path:
    s = d.internal[0]
    slip = "slip_speed_m_s" in s.values
    fig, ax = new_figure(3 if slip else 2)
    a = ax[:, 0]
    for key, colour in (("power_in_w", C_MAIN), ("power_out_w", C_SECOND), ("power_dissipated_w", "tab:red")):
        a[0].plot(s.t_s, s.values[key], color=colour, label=key.removesuffix("_w").replace("_", " "))
    a[0].axhline(0.0, color="black", linewidth=0.6)
    a[0].set_ylabel("power [W]")
    inst = s.values.get("efficiency")
    if inst is not None:
        a[1].plot(s.t_s, inst, linestyle="none", marker=".", markersize=2, color="dimgray",
                  label=f"per step, quasi-steady only (defined at {int(np.isfinite(inst).sum())} of {inst.size} steps)")
    fwd, bwd = running_efficiency(terms)
    e = d.efficiency or {}
    for run, colour, what in ((fwd, C_THIRD, "forward"), (bwd, C_FOURTH, "backward")):
        if np.any(np.isfinite(run)):
            final = e.get(what)
            a[1].plot(s.t_s, run, color=colour, label=f"{what}, energies so far (report: {final:.3f})"
                      if final is not None else f"{what}, energies so far")
    a[1].set_ylim(0.0, 1.05)
    a[1].set_ylabel("efficiency [1]")
    a[1].text(0.01, 0.04, "per-step values are undefined at start-up, reversals, standstill and while the\n"
              "kinetic energy changes; the run's figure comes from its energies", transform=a[1].transAxes,
              fontsize="x-small", color="dimgray")
    if slip:
        a[2].plot(s.t_s, np.abs(s.values["slip_speed_m_s"]) * 1e3, color="tab:brown", label="slip speed")
        from_zero(a[2], np.abs(s.values["slip_speed_m_s"]) * 1e3)
        a[2].set_ylabel("slip [mm/s]")
    for x in a:
        legend(x)
    return save(fig, list(a), path, ctx.title("Power, efficiency and slip"), marks)


def force_panels(s, labels: dict, exclude: tuple[str, ...]) -> list[tuple[str, str, np.ndarray]]:
    """(block, quantity, samples × elements of |F|) of every mechanism force quantity that is not zero throughout."""
    panels = []
    for seg in labels["segments"]:
        if "quantities" not in seg or seg["name"] in exclude:
            continue
        arr = s.values[seg["name"]]
        for i, q in enumerate(seg["quantities"]):
            if q["unit"] != "N":
                continue
            vals = np.abs(arr[..., i]).reshape(arr.shape[0], -1)
            if vals.shape[1] and np.any(np.nan_to_num(vals) != 0):
                panels.append((seg["name"], q["name"], vals))
    return panels


def internal_loads_figure(path: Path, d: RunData, ctx: Context, marks: Marks, exclude) -> Path | None:
    s, labels = d.internal
    panels = force_panels(s, labels, exclude)
    if not panels:
        return None
    cols = 1 if len(panels) <= 3 else 3
    rows = -(-len(panels) // cols)
    fig, ax = new_figure(rows, cols, height_in=2.0, width_in=WIDTH_IN if cols == 1 else 15.0)
    flat = ax.ravel()
    for a, (block, name, vals) in zip(flat, panels, strict=False):
        label = {"per_roller": "rollers", "per_tooth": "teeth of all rollers"}.get(block, block)
        band(a, s.t_s, vals, C_MAIN, label)
        from_zero(a, vals)
        a.set_title(f"{block}: {name.removesuffix('_n').replace('_', ' ')}", fontsize="small")
        a.set_ylabel("|F| [N]")
        a.tick_params(labelsize="small")
    for a in flat[len(panels):]:
        a.set_visible(False)
    for c in range(cols):  # the lowest visible panel of each column carries the time axis
        low = ax[min(rows - 1, (len(panels) - 1 - c) // cols), c]
        low.xaxis.set_tick_params(labelbottom=True)
        low.set_xlabel("time [s]")
    flat[0].legend(loc="lower right", fontsize="x-small", frameon=True)
    used = list(flat[:len(panels)])
    alike = all(np.nanmax(np.nanmax(v, axis=1) - np.nanmin(v, axis=1)) <= 1e-9 * np.nanmax(v) for _, _, v in panels)
    what = "Internal loads (blue: mean, band: min–max across the rollers or teeth" + (
        "; every roller and tooth carries the same: the band has no width)" if alike else ")")
    mark(used, marks)
    return save(fig, used, path, ctx.title(what))


def actuator_figure(path: Path, d: RunData, ctx: Context, marks: Marks,
                    curves: list[tuple[str, str, np.ndarray]]) -> Path | None:
    if not curves:
        return None
    fig, ax = new_figure(len(curves), height_in=2.0)
    colours = (C_MAIN, C_SECOND, C_THIRD, C_FOURTH)
    for a, (name, unit, values), colour in zip(ax[:, 0], curves, colours * 2, strict=False):
        a.plot(d.internal[0].t_s, values, color=colour, label=name.rsplit("_", 1)[0].replace("_", " "))
        a.set_ylabel(f"[{unit}]")
        legend(a)
    return save(fig, list(ax[:, 0]), path, ctx.title("Actuator"), marks)
