"""`prsm-bag report`: metrics and plots from a recorded run.

Works on any ROS 2 MCAP file with a JointState topic carrying the screw and nut joints; uses more
when our topics are there:

- tracking error (reference − nut position), when a reference was recorded on
  `.../nut_position_reference`, the reference held from each message to the next, evaluated while
  the reference is live (from its first message to one message interval after its last);
- efficiency as energy ratios: forward Σ P_out Δt / Σ P_in Δt over the samples where the screw
  drives the load, backward Σ |P_in| Δt / Σ |P_out| Δt where the load drives the screw; powers from
  `~/internal_loads` (power_in_w, power_out_w) when recorded, else from the joint states
  (τ_S ω_S and F_nut v_nut: the power into the nut, which includes its acceleration);
- slip: the scalar slip speed and the peak of every per-roller slip quantity;
- peak roller and tooth loads: every force quantity (unit N) of each internal-load block, with
  where and when it peaked;
- L10 life (`prsm_sim.life`, docs/model.md §5 item 10) from the axial load |nut force| and the screw
  speed, the recorded cycle repeated, for a dynamic load rating C_a
  (`DEFAULT_DYNAMIC_LOAD_RATING_N` unless given).

Times are the messages' log times (simulation time for our bags).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prsm_sim.life import life_from_samples

from prsm_ros.bag.reader import Bag, BagError, resolve_topics
from prsm_ros.interface import NUT_JOINT, SCREW_JOINT, parse_labels, unpack_internal

# C_a of a catalogue planetary roller screw of about 30 mm diameter and 5 mm lead, the size of the
# `s30` preset: vendor catalogues list roughly 50–90 kN for that size. Give your screw's own
# catalogue value with --dynamic-load-rating-n; the life scales with its cube.
DEFAULT_DYNAMIC_LOAD_RATING_N = 60_000.0
NEGLIGIBLE_ENERGY_FRACTION = 1e-9


@dataclass
class Series:
    """Time-aligned recorded quantities (SI), each a 1-D array over `t_s`."""

    t_s: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)

    def get(self, name: str) -> np.ndarray | None:
        return self.values.get(name)


def _joint_series(bag: Bag, topic: str, screw: str, nut: str, progress: bool) -> Series:
    t, rows = [], []
    for m in bag.messages([topic], progress=progress, desc=topic):
        js = m.msg
        if js is None:
            raise BagError(f"{bag.path.name}: {topic} cannot be decoded (needs a ros2msg schema and cdr encoding)")
        names = list(js.name)
        if screw not in names or nut not in names:
            raise BagError(f"{bag.path.name}: {topic} has joints {names}; the report needs {screw!r} and {nut!r} "
                           f"(name them with --screw-joint / --nut-joint)")
        i, j = names.index(screw), names.index(nut)

        def at(arr, k):
            return float(arr[k]) if k < len(arr) else math.nan

        t.append(m.log_time_ns * 1e-9)
        rows.append((at(js.position, i), at(js.velocity, i), at(js.effort, i),
                     at(js.position, j), at(js.velocity, j), at(js.effort, j)))
    data = np.array(rows, dtype=float).reshape(-1, 6)
    keys = ("screw_angle_rad", "screw_speed_rad_s", "screw_torque_nm", "nut_position_m", "nut_velocity_m_s", "nut_force_n")
    return Series(np.array(t), {k: data[:, n] for n, k in enumerate(keys)})


def _float_series(bag: Bag, topic: str, progress: bool) -> Series:
    t, v = [], []
    for m in bag.messages([topic], progress=progress, desc=topic):
        t.append(m.log_time_ns * 1e-9)
        v.append(float(m.msg.data))
    return Series(np.array(t), {"value": np.array(v)})


def _internal_series(bag: Bag, roles: dict, progress: bool) -> tuple[Series, dict] | None:
    """~/internal_loads unpacked by its labels: scalars by name and blocks by name (rows first)."""
    if not roles.get("internal_loads") or not roles.get("labels"):
        return None
    labels = None
    for m in bag.messages([roles["labels"]]):
        try:
            labels = parse_labels(m.msg.data)
        except ValueError:
            return None
    if labels is None:
        return None
    t, rows = [], []
    width = sum(s["size"] for s in labels["segments"])
    for m in bag.messages([roles["internal_loads"]], progress=progress, desc=roles["internal_loads"]):
        if len(m.msg.data) != width:
            continue  # a row of another layout (should not happen within one run)
        t.append(m.log_time_ns * 1e-9)
        rows.append(m.msg.data)
    if not rows:
        return None
    unpacked = unpack_internal(np.array(rows, dtype=float), labels)
    return Series(np.array(t), unpacked), labels


def _finite_max(a: np.ndarray) -> float:
    """Largest finite value; NaN when there is none (a field the recorder left empty)."""
    a = a[np.isfinite(a)]
    return float(a.max()) if a.size else math.nan


def _held(t_query: np.ndarray, t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v held from each sample time to the next, read at t_query (NaN before the first sample)."""
    k = np.searchsorted(t, t_query, side="right") - 1
    out = np.full(t_query.shape, np.nan)
    ok = k >= 0
    out[ok] = v[k[ok]]
    return out


def _intervals(t: np.ndarray) -> np.ndarray:
    """Duration each sample holds for (to the next sample; the last holds for none)."""
    dt = np.zeros_like(t)
    dt[:-1] = np.diff(t)
    return dt


def energy_efficiency(t: np.ndarray, p_in: np.ndarray, p_out: np.ndarray) -> dict[str, float | None]:
    """Forward and backward energy efficiencies (module docstring); None where no such power flowed."""
    dt = _intervals(t)
    fwd = (p_in > 0) & (p_out > 0)
    bwd = (p_in < 0) & (p_out < 0)
    e_in_f, e_out_f = float(np.sum(p_in[fwd] * dt[fwd])), float(np.sum(p_out[fwd] * dt[fwd]))
    e_in_b, e_out_b = float(np.sum(-p_in[bwd] * dt[bwd])), float(np.sum(-p_out[bwd] * dt[bwd]))
    # flows at round-off level (a speed of 1e-16 rad/s at rest) are no flow
    tiny = NEGLIGIBLE_ENERGY_FRACTION * float(np.sum(np.abs(p_in) * dt) + np.sum(np.abs(p_out) * dt))
    return {
        "forward": e_out_f / e_in_f if e_in_f > tiny else None,
        "backward": e_in_b / e_out_b if e_out_b > tiny else None,
        "forward_input_energy_j": e_in_f,
        "backward_output_energy_j": e_out_b,
    }


def _peaks(series: Series, labels: dict, unit: str) -> dict[str, dict]:
    """Peak |value| of every block quantity with `unit`: value, time, element index."""
    out: dict[str, dict] = {}
    for seg in labels["segments"]:
        if "quantities" not in seg:
            continue
        arr = series.values[seg["name"]]  # rows × shape
        for q, quantity in enumerate(seg["quantities"]):
            if quantity["unit"] != unit:
                continue
            a = np.abs(arr[..., q])
            if a.size == 0 or not np.any(np.isfinite(a)):
                continue
            flat = int(np.nanargmax(a))
            idx = np.unravel_index(flat, a.shape)
            dims = [d for d in seg["dims"] if d != "quantity"]
            out[f"{seg['name']}.{quantity['name']}"] = {
                "peak_abs": float(a[idx]), "unit": unit, "time_s": float(series.t_s[idx[0]]),
                "at": {d: int(i) for d, i in zip(dims, idx[1:])},
            }
    return out


def report(bag: Bag, out_dir, *, dynamic_load_rating_n: float = DEFAULT_DYNAMIC_LOAD_RATING_N,
           screw_joint: str = SCREW_JOINT, nut_joint: str = NUT_JOINT, topics: dict | None = None,
           plots: bool = True, progress: bool = True) -> dict:
    """Metrics (a JSON-able dict) and PNG plots written to `out_dir` (listed under "plots")."""
    if not (math.isfinite(dynamic_load_rating_n) and dynamic_load_rating_n > 0):
        raise BagError(f"--dynamic-load-rating-n {dynamic_load_rating_n!r}: must be a force in N > 0")
    roles = resolve_topics(bag, topics)
    if roles["joint_states"] is None:
        js = bag.topics_of_type("sensor_msgs/msg/JointState")
        raise BagError(f"{bag.path.name}: no joint states to report on (a sensor_msgs/msg/JointState topic named "
                       f"/joint_states{'; JointState topics here: ' + ', '.join(js) + ', choose with --joint-states-topic' if js else ''})")
    joints = _joint_series(bag, roles["joint_states"], screw_joint, nut_joint, progress)
    if joints.t_s.size < 2:
        raise BagError(f"{bag.path.name}: {roles['joint_states']} has {joints.t_s.size} message(s); the report needs at least 2")
    internal = _internal_series(bag, roles, progress)
    t = joints.t_s
    meta = bag.run_metadata
    result: dict = {
        "bag": str(bag.path), "complete": bag.complete, "note": bag.note,
        "model": meta.get("model"), "preset": meta.get("preset"), "dt_s": float(meta["dt_s"]) if "dt_s" in meta else None,
        "topics": {k: v for k, v in roles.items() if v},
        "duration_s": float(t[-1] - t[0]), "samples": int(t.size),
    }
    x, v = joints.values["nut_position_m"], joints.values["nut_velocity_m_s"]
    tau, w = joints.values["screw_torque_nm"], joints.values["screw_speed_rad_s"]
    f_nut = joints.values["nut_force_n"]
    result["kinematics"] = {
        "nut_travel_m": _finite_max(x) - (-_finite_max(-x)),
        "max_abs_nut_velocity_m_s": _finite_max(np.abs(v)),
        "max_abs_screw_speed_rad_s": _finite_max(np.abs(w)),
        "peak_abs_screw_torque_nm": _finite_max(np.abs(tau)),
        "peak_abs_nut_force_n": _finite_max(np.abs(f_nut)),
    }

    # tracking
    ref_t = ref_v = err = None
    if roles["reference"]:
        ref = _float_series(bag, roles["reference"], progress)
        if ref.t_s.size:
            ref_t, ref_v = ref.t_s, ref.values["value"]
            r = _held(t, ref_t, ref_v)
            # the reference is live from its first message to one message interval after its last
            period = float(np.median(np.diff(ref_t))) if ref_t.size > 1 else 0.0
            r[t > ref_t[-1] + period * (1 + 1e-6)] = np.nan
            err = r - x
            ok = np.isfinite(err)
            t_ok = t[ok]
            tail = ok & (t >= t_ok[0] + 0.9 * (t_ok[-1] - t_ok[0])) if ok.any() else ok
            result["tracking"] = {
                "reference_topic": roles["reference"],
                "rms_error_m": float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else None,
                "max_abs_error_m": float(np.max(np.abs(err[ok]))) if ok.any() else None,
                "final_rms_error_m": float(np.sqrt(np.mean(err[tail] ** 2))) if tail.any() else None,
                "reference_span_m": float(np.ptp(ref_v)),
            }
    result.setdefault("tracking", None)

    # efficiency
    if internal is not None and "power_in_w" in internal[0].values:
        s = internal[0]
        eff = energy_efficiency(s.t_s, s.values["power_in_w"], s.values["power_out_w"])
        eff["source"] = f"{roles['internal_loads']} power_in_w, power_out_w"
        inst = s.values.get("efficiency")
        if inst is not None and np.any(np.isfinite(inst)):
            eff["median_instantaneous"] = float(np.nanmedian(inst))
    else:
        eff = energy_efficiency(t, tau * w, f_nut * v)
        eff["source"] = f"{roles['joint_states']} τ_S·ω_S and F_nut·v_nut"
    result["efficiency"] = eff

    # slip and internal loads
    result["slip"] = None
    result["peak_loads"] = None
    if internal is not None:
        s, labels = internal
        slip = {}
        if "slip_speed_m_s" in s.values:
            sv = s.values["slip_speed_m_s"]
            slip = {"max_slip_speed_m_s": float(np.nanmax(np.abs(sv))), "mean_slip_speed_m_s": float(np.nanmean(np.abs(sv)))}
        slip["peaks"] = _peaks(s, labels, "m/s")
        result["slip"] = slip
        result["peak_loads"] = _peaks(s, labels, "N")
        result["model"] = result["model"] or labels.get("model")

    # life, over the samples that carry both an effort and a velocity
    usable = np.isfinite(f_nut) & np.isfinite(w)
    if usable.sum() >= 2:
        life = life_from_samples(t[usable], f_nut[usable], w[usable], dynamic_load_rating_n)
        result["life"] = {**life.to_dict(), "load_source": f"|{nut_joint} effort| on {roles['joint_states']}",
                          "speed_source": f"{screw_joint} velocity on {roles['joint_states']}"}
    else:
        result["life"] = None
    result["events"] = _events(bag)
    result["plots"] = [str(p) for p in _plots(Path(out_dir), joints, internal, ref_t, ref_v, err)] if plots else []
    return result


def _events(bag: Bag) -> list[dict]:
    """Every ~/events entry (std_msgs/String, one JSON object each; prsm_ros.messages.event_message)."""
    out = []
    for topic in (t for t in bag.topics_of_type("std_msgs/msg/String") if t.endswith("/events")):
        for m in bag.messages([topic]):
            try:
                doc = json.loads(m.msg.data)
            except (ValueError, AttributeError):
                doc = {"message": str(getattr(m.msg, "data", m.msg)), "code": "unparsed"}
            out.append({"topic": topic, **doc} if isinstance(doc, dict) else {"topic": topic, "message": str(doc)})
    return out


def _plots(out_dir: Path, joints: Series, internal, ref_t, ref_v, err) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    t = joints.t_s
    files: list[Path] = []

    def save(fig, name: str) -> None:
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)

    n = 3 if err is not None else 2
    fig, ax = plt.subplots(n, 1, sharex=True, figsize=(8, 2.4 * n))
    ax[0].plot(t, joints.values["nut_position_m"] * 1e3, label="nut position")
    if ref_t is not None:
        ax[0].step(ref_t, ref_v * 1e3, where="post", label="reference", linestyle="--")
    ax[0].set_ylabel("x_nut [mm]")
    ax[0].legend(loc="best")
    ax[1].plot(t, joints.values["screw_speed_rad_s"])
    ax[1].set_ylabel("ω_S [rad/s]")
    if err is not None:
        ax[2].plot(t, err * 1e6)
        ax[2].set_ylabel("error [µm]")
    ax[-1].set_xlabel("time [s]")
    save(fig, "motion.png")

    fig, ax = plt.subplots(2, 1, sharex=True, figsize=(8, 4.8))
    ax[0].plot(t, joints.values["screw_torque_nm"])
    ax[0].set_ylabel("screw torque [N·m]")
    ax[1].plot(t, joints.values["nut_force_n"], label="nut (thread) force")
    if internal is not None and "load_force_n" in internal[0].values:
        ax[1].plot(internal[0].t_s, internal[0].values["load_force_n"], label="load force", linestyle="--")
    ax[1].set_ylabel("force [N]")
    ax[1].legend(loc="best")
    ax[-1].set_xlabel("time [s]")
    save(fig, "loads.png")

    if internal is None:
        return files
    s, labels = internal
    if "power_in_w" in s.values:
        fig, ax = plt.subplots(2, 1, sharex=True, figsize=(8, 4.8))
        for k in ("power_in_w", "power_out_w", "power_dissipated_w"):
            ax[0].plot(s.t_s, s.values[k], label=k.removesuffix("_w").replace("_", " "))
        ax[0].set_ylabel("power [W]")
        ax[0].legend(loc="best")
        ax[1].plot(s.t_s, s.values["efficiency"], label="efficiency")
        if "slip_speed_m_s" in s.values:
            ax2 = ax[1].twinx()
            ax2.plot(s.t_s, s.values["slip_speed_m_s"] * 1e3, color="tab:red", alpha=0.6)
            ax2.set_ylabel("slip [mm/s]", color="tab:red")
        ax[1].set_ylabel("efficiency [1]")
        ax[-1].set_xlabel("time [s]")
        save(fig, "power.png")

    force_blocks = [(seg, [q for q in seg["quantities"] if q["unit"] == "N"])
                    for seg in labels["segments"] if "quantities" in seg]
    force_blocks = [(seg, qs) for seg, qs in force_blocks if qs]
    if force_blocks:
        fig, ax = plt.subplots(len(force_blocks), 1, sharex=True, figsize=(8, 2.6 * len(force_blocks)), squeeze=False)
        for a, (seg, qs) in zip(ax[:, 0], force_blocks):
            arr = s.values[seg["name"]]
            names = [q["name"] for q in seg["quantities"]]
            for q in qs:
                vals = np.abs(arr[..., names.index(q["name"])]).reshape(arr.shape[0], -1)
                a.plot(s.t_s, np.nanmax(vals, axis=1), label=q["name"])
            a.set_ylabel(f"{seg['name']}\nmax |F| [N]")
            a.legend(loc="best", fontsize="small")
        ax[-1, 0].set_xlabel("time [s]")
        save(fig, "internal_loads.png")
    return files


def _fmt(v, unit: str = "", scale: float = 1.0, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if isinstance(v, float) and math.isinf(v):
        return "infinite"
    return f"{v * scale:.{digits}g}{(' ' + unit) if unit else ''}"


def summary_text(r: dict) -> str:
    """The report as a few readable lines (stdout)."""
    lines = [f"bag: {r['bag']}" + ("" if r["complete"] else "  (unfinished file)")]
    if r.get("note"):
        lines.append(f"note: {r['note']}")
    lines.append(f"model: {r.get('model') or 'unknown'}   preset: {r.get('preset') or 'unknown'}   "
                 f"duration: {_fmt(r['duration_s'], 's')}   samples: {r['samples']}")
    k = r["kinematics"]
    lines.append(f"nut travel {_fmt(k['nut_travel_m'], 'mm', 1e3)}, max |v_nut| {_fmt(k['max_abs_nut_velocity_m_s'], 'm/s')}, "
                 f"max |ω_S| {_fmt(k['max_abs_screw_speed_rad_s'], 'rad/s')}, peak |τ_S| {_fmt(k['peak_abs_screw_torque_nm'], 'N·m')}, "
                 f"peak |F_nut| {_fmt(k['peak_abs_nut_force_n'], 'N')}")
    tr = r.get("tracking")
    if tr:
        lines.append(f"tracking ({tr['reference_topic']}): RMS error {_fmt(tr['rms_error_m'], 'µm', 1e6)}, "
                     f"max |error| {_fmt(tr['max_abs_error_m'], 'µm', 1e6)}, last 10 % RMS {_fmt(tr['final_rms_error_m'], 'µm', 1e6)}")
    else:
        lines.append("tracking: no reference recorded (publish it on ~/nut_position_reference)")
    e = r["efficiency"]
    line = f"efficiency ({e['source']}): forward {_fmt(e['forward'])}, backward {_fmt(e['backward'])}"
    if "median_instantaneous" in e:
        line += f", median instantaneous {_fmt(e['median_instantaneous'])}"
    lines.append(line)
    s = r.get("slip")
    if s:
        parts = []
        if "max_slip_speed_m_s" in s:
            parts.append(f"max {_fmt(s['max_slip_speed_m_s'], 'mm/s', 1e3)}, mean {_fmt(s['mean_slip_speed_m_s'], 'mm/s', 1e3)}")
        parts += [f"{name} peak {_fmt(p['peak_abs'], 'mm/s', 1e3)}" for name, p in s["peaks"].items()]
        lines.append("slip: " + "; ".join(parts))
    else:
        lines.append("slip: not recorded (needs ~/internal_loads with its labels)")
    if r.get("peak_loads"):
        lines.append("peak internal loads:")
        for name, p in r["peak_loads"].items():
            where = ", ".join(f"{d} {i}" for d, i in p["at"].items())
            lines.append(f"  {name}: {_fmt(p['peak_abs'], 'N')} at t = {_fmt(p['time_s'], 's')}" + (f" ({where})" if where else ""))
    else:
        lines.append("peak internal loads: not recorded")
    life = r["life"]
    if life is None:
        lines.append("L10 life: n/a (the joint states carry no nut effort and screw velocity)")
    else:
        lines.append(f"L10 life (C_a = {_fmt(life['dynamic_load_rating_n'], 'N')}, F_m = {_fmt(life['mean_load_n'], 'N')}): "
                     f"{_fmt(life['l10_revolutions'], 'revolutions')} = {_fmt(life['l10_hours'], 'h')} at the recorded "
                     f"cycle ({_fmt(life['l10_cycles'], 'cycles')} of {_fmt(life['cycle_duration_s'], 's')})")
    for ev in r.get("events", []):
        lines.append(f"event t = {_fmt(ev.get('time_s'), 's')} [{ev.get('severity', '?')}] {ev.get('source', '?')}/"
                     f"{ev.get('code', '?')}: {ev.get('message', '')}")
    if r["plots"]:
        lines.append("plots: " + ", ".join(r["plots"]))
    return "\n".join(lines)
