"""`prsm-bag report`: metrics and plots from a recorded run.

Works on any ROS 2 MCAP file with a JointState topic carrying the screw and nut joints; uses more
when our topics are there. Each figure sits in its own category:

- **tracking** (reference − nut position): with a stamped reference (sensor_msgs/JointState on
  `.../nut_position_reference`, its header stamp = the stamp of the state it answers) each
  reference is paired with that very state, which is how the controller itself saw its error; a
  plain Float64 reference (older bags, other recorders) is held from each message to the next and
  read at the state times while it is live.
- **efficiency** from energies, never from instantaneous ratios: the run is cut into segments of
  one power-flow direction (forward: the screw drives the load, P_in > 0 and P_out > 0; backward:
  the load drives the screw, both < 0). Over them the energy that went through the mechanism is
  the input minus what went into stored (kinetic) energy, so forward = E_out / (E_in − ΔT) =
  E_out / (E_out + E_diss) and backward = |E_in| / (|E_out| + ΔT_released) = |E_in| / (|E_in| +
  E_diss): never above 1, and undefined (None) where no such power flowed. E_diss comes from
  `~/internal_loads` (power_dissipated_w) when recorded; with joint states alone (τ_S ω_S and
  F_nut v_nut, stored energy unknown) only the quasi-steady samples count (speeds changing by less
  than `STEADY_SPEED_CHANGE` from one sample to the next), where ΔT ≈ 0.
- **slip**: the scalar slip speed and the peak of every per-roller slip quantity.
- **peak internal loads**: every force quantity (unit N) of the mechanism's internal-load
  blocks (rollers, teeth, carrier), with where and when it peaked. The actuator's stop force and
  the load cell reading are not internal loads: they are under **actuator**.
- **measurement**: measured (`/joint_states` with an actuator) against ground truth
  (`~/ground_truth/joint_states`), paired by stamp.
- **L10 life** (`prsm_sim.life`, docs/model.md §5 item 10) from |nut force| and the screw speed,
  the recorded cycle repeated, for the dynamic load rating C_a: the one given, else the one the
  bag's parameter set records (`ratings.dynamic_load_rating_n`), else
  `DEFAULT_DYNAMIC_LOAD_RATING_N` (the report says which).
- **events** (`~/events`: faults, energy guard, ownership) are listed and marked on every plot,
  with brake engagement and end-stop contact shaded where the actuator block records them.

Times are the messages' log times (simulation time for our bags). Plots go to `out_dir`, by
default a folder beside the bag (`default_output_dir`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from prsm_ros.bag.figures import (
    LONG_RUN_S, MARK_COLOURS, SPAN_COLOURS, Context, Marks, RunData, actuator_figure, busiest_window, force_text,
    internal_loads_figure, load_distribution_figure, load_distribution_summary, load_steps, loads_figure,
    motion_figure, power_figure)
from prsm_sim.life import life_from_samples

from prsm_ros.bag.reader import MAX_WINDOW_S, Bag, BagError, resolve_topics
from prsm_ros.interface import NUT_JOINT, SCREW_JOINT, TOPIC_DEFS, parse_labels, unpack_internal
from prsm_ros.limits import load_json

# C_a of a catalogue planetary roller screw of about 30 mm diameter and 5 mm lead, for bags that do
# not record a rating: vendor catalogues list roughly 50–90 kN for that size.
DEFAULT_DYNAMIC_LOAD_RATING_N = 60_000.0
NEGLIGIBLE_ENERGY_FRACTION = 1e-9
# joint states only: a sample is quasi-steady when neither speed changed by more than this fraction
STEADY_SPEED_CHANGE = 0.01
# internal-load blocks that belong to the actuator around the screw, not to the mechanism
ACTUATOR_BLOCKS = ("actuator", "measured")


@dataclass
class Series:
    """Time-aligned recorded quantities (SI), each a 1-D array over `t_s`."""

    t_s: np.ndarray
    values: dict[str, np.ndarray] = field(default_factory=dict)
    stamp_ns: np.ndarray | None = None  # header stamps, where the messages have them

    def get(self, name: str) -> np.ndarray | None:
        return self.values.get(name)


# Recorded values beyond this magnitude are read as missing: no physical quantity of a run comes
# near it, and at ±1e308 differences, sums of squares and plot ranges overflow.
MAX_ABS_VALUE = 1e100


def _bounded(bag: Bag, topic: str, data: np.ndarray) -> np.ndarray:
    """`data` with values beyond ±MAX_ABS_VALUE made NaN (missing), noted on the bag."""
    data = np.asarray(data, dtype=float)
    bad = np.isfinite(data) & (np.abs(data) > MAX_ABS_VALUE)
    if bad.any():
        bag.notes.append(f"{bag.path.name}: {int(bad.sum())} value(s) on {topic} beyond ±{MAX_ABS_VALUE:g} "
                         "read as missing")
        data = np.where(bad, np.nan, data)
    return data


def _in_order(bag: Bag, topic: str, t: np.ndarray) -> None:
    """BagError naming the bag when the log times of `topic` decrease (a file read in its own order)."""
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        k = int(back[0]) + 1
        raise BagError(f"{bag.path.name}: the log times of {topic} decrease at message {k} "
                       f"({t[k - 1]:.9g} s, then {t[k]:.9g} s); the report needs them in order "
                       "(prsm-bag repair writes them sorted)")


def default_output_dir(bag_path) -> Path:
    """Where a report goes when no folder is given: `<bag stem>_report/` beside the bag."""
    p = Path(bag_path)
    return p.with_name(p.stem + "_report")


def _stamp_ns(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _joint_series(bag: Bag, topic: str, screw: str, nut: str, progress: bool) -> Series:
    t, stamps, rows = [], [], []
    for m in bag.messages([topic], progress=progress, desc=topic):
        js = m.msg
        if js is None:
            raise BagError(f"{topic} cannot be decoded (needs a ros2msg schema and cdr encoding)")
        names = list(js.name)
        if screw not in names or nut not in names:
            raise BagError(f"{topic} has joints {names}; the report needs {screw!r} and {nut!r} "
                           f"(name them with --screw-joint / --nut-joint)")
        i, j = names.index(screw), names.index(nut)

        def at(arr, k):
            return float(arr[k]) if k < len(arr) else math.nan

        t.append(m.log_time_ns * 1e-9)
        stamps.append(_stamp_ns(js))
        rows.append((at(js.position, i), at(js.velocity, i), at(js.effort, i),
                     at(js.position, j), at(js.velocity, j), at(js.effort, j)))
    data = _bounded(bag, topic, np.array(rows, dtype=float).reshape(-1, 6))
    _in_order(bag, topic, np.array(t))
    keys = ("screw_angle_rad", "screw_speed_rad_s", "screw_torque_nm", "nut_position_m", "nut_velocity_m_s", "nut_force_n")
    return Series(np.array(t), {k: data[:, n] for n, k in enumerate(keys)}, np.array(stamps, dtype=np.int64))


def _reference_series(bag: Bag, topic: str, nut: str, progress: bool) -> Series:
    """The nut position reference: stamped (JointState: header stamp, the nut joint's position) or Float64."""
    t, stamps, v = [], [], []
    for m in bag.messages([topic], progress=progress, desc=topic):
        t.append(m.log_time_ns * 1e-9)
        if hasattr(m.msg, "header"):
            names = list(m.msg.name)
            k = names.index(nut) if nut in names else 0
            stamps.append(_stamp_ns(m.msg))
            v.append(float(m.msg.position[k]) if len(m.msg.position) > k else math.nan)
        else:
            v.append(float(m.msg.data))
    _in_order(bag, topic, np.array(t))
    return Series(np.array(t), {"value": _bounded(bag, topic, np.array(v, dtype=float))},
                  np.array(stamps, dtype=np.int64) if stamps else None)


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
    _in_order(bag, roles["internal_loads"], np.array(t))
    unpacked = unpack_internal(_bounded(bag, roles["internal_loads"], np.array(rows, dtype=float)), labels)
    return Series(np.array(t), unpacked), labels


def _block_quantity(internal, block: str, quantity: str) -> np.ndarray | None:
    """One quantity of a one-dimensional internal block (the actuator's), over time; None when absent."""
    if internal is None:
        return None
    s, labels = internal
    for seg in labels["segments"]:
        if seg["name"] == block and "quantities" in seg:
            names = [q["name"] for q in seg["quantities"]]
            if quantity in names:
                return s.values[block][..., names.index(quantity)].reshape(len(s.t_s), -1)[:, 0]
    return None


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


def _paired(stamps: np.ndarray, ref_stamps: np.ndarray, ref_v: np.ndarray) -> np.ndarray:
    """The reference answering each state (same stamp), NaN for states no reference answered."""
    out = np.full(stamps.shape, np.nan)
    if ref_stamps.size == 0:
        return out
    order = np.argsort(ref_stamps, kind="stable")
    rs, rv = ref_stamps[order], ref_v[order]
    k = np.clip(np.searchsorted(rs, stamps), 0, rs.size - 1)
    hit = rs[k] == stamps
    out[hit] = rv[k[hit]]
    return out


def _spans(t: np.ndarray, on: np.ndarray) -> list[tuple[float, float]]:
    """(start, end) time of each run of samples where `on` holds."""
    on = np.asarray(on, dtype=bool)
    if not on.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], on.astype(np.int8), [0]))))
    return [(float(t[a]), float(t[min(b, t.size - 1)])) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _runs(mask: np.ndarray) -> int:
    """Number of maximal runs of True in `mask`."""
    m = np.asarray(mask, dtype=np.int8)
    return int(np.sum(np.diff(np.concatenate(([0], m))) == 1))


def energy_terms(t: np.ndarray, p_in: np.ndarray, p_out: np.ndarray, p_diss: np.ndarray | None = None,
                 speeds: tuple[np.ndarray, ...] = ()) -> dict:
    """Per-sample energies (J) of `energy_efficiency`: e_in, e_out, e_diss (0 where a sample does not
    count), the forward and backward masks, and `tiny`, the flow below which nothing flowed."""
    t = np.asarray(t, dtype=float)
    p_in, p_out = np.asarray(p_in, dtype=float), np.asarray(p_out, dtype=float)
    dt = np.zeros_like(t)
    dt[1:] = np.diff(t)
    counted = np.isfinite(p_in) & np.isfinite(p_out) & (dt > 0)
    if p_diss is not None:
        p_diss = np.asarray(p_diss, dtype=float)
        counted &= np.isfinite(p_diss)
        e_diss = np.where(counted, p_diss, 0.0) * dt
    else:
        for w in speeds:
            w = np.asarray(w, dtype=float)
            change = np.full(t.shape, np.inf)
            change[1:] = np.abs(np.diff(w)) / np.maximum(np.maximum(np.abs(w[1:]), np.abs(w[:-1])), 1e-300)
            counted &= change < STEADY_SPEED_CHANGE
        e_diss = np.where(counted, p_in - p_out, 0.0) * dt  # ΔT ≈ 0 over a quasi-steady sample
    e_in, e_out = np.where(counted, p_in * dt, 0.0), np.where(counted, p_out * dt, 0.0)
    # flows at round-off level (a speed of 1e-16 rad/s at rest) are no flow
    tiny = NEGLIGIBLE_ENERGY_FRACTION * float(np.sum(np.abs(e_in)) + np.sum(np.abs(e_out)))
    return {"e_in": e_in, "e_out": e_out, "e_diss": e_diss, "tiny": tiny,
            "forward": counted & (p_in > 0) & (p_out > 0), "backward": counted & (p_in < 0) & (p_out < 0)}


def energy_efficiency(t: np.ndarray, p_in: np.ndarray, p_out: np.ndarray, p_diss: np.ndarray | None = None,
                      speeds: tuple[np.ndarray, ...] = ()) -> dict:
    """Forward and backward efficiencies from energies (module docstring); None where no such power flowed.

    Sample k stands for the interval from t[k−1] to t[k] (our powers are step averages over it; the
    first sample has none). `p_diss`: the dissipated power, so the stored-energy change is what
    remains of the balance; without it only quasi-steady samples count, judged by `speeds` (each
    a 1-D array over t whose relative change between samples must stay below STEADY_SPEED_CHANGE).
    """
    e = energy_terms(t, p_in, p_out, p_diss, speeds)
    fwd, bwd, tiny, e_in, e_out, e_diss = e["forward"], e["backward"], e["tiny"], e["e_in"], e["e_out"], e["e_diss"]
    out_f, diss_f, in_f = float(e_out[fwd].sum()), float(e_diss[fwd].sum()), float(e_in[fwd].sum())
    in_b, diss_b, out_b = float(-e_in[bwd].sum()), float(e_diss[bwd].sum()), float(-e_out[bwd].sum())
    return {
        "forward": out_f / (out_f + diss_f) if out_f + diss_f > tiny and out_f > tiny else None,
        "backward": in_b / (in_b + diss_b) if in_b + diss_b > tiny and in_b > tiny else None,
        "forward_segments": _runs(fwd), "backward_segments": _runs(bwd),
        "forward_input_energy_j": in_f, "forward_output_energy_j": out_f,
        "forward_stored_energy_change_j": in_f - out_f - diss_f,
        "backward_input_energy_j": out_b, "backward_output_energy_j": in_b,
        "backward_stored_energy_released_j": in_b + diss_b - out_b,
    }


def _peaks(series: Series, labels: dict, unit: str, *, blocks_excluded=ACTUATOR_BLOCKS,
           name_has: str | None = None) -> dict[str, dict]:
    """Peak |value| of every mechanism block quantity with `unit` (and `name_has` in its name): value, time
    (None for a quantity constant over the run), element."""
    out: dict[str, dict] = {}
    for seg in labels["segments"]:
        if "quantities" not in seg or seg["name"] in blocks_excluded:
            continue
        arr = series.values[seg["name"]]  # rows × shape
        for q, quantity in enumerate(seg["quantities"]):
            if quantity["unit"] != unit or (name_has is not None and name_has not in quantity["name"]):
                continue
            a = np.abs(arr[..., q])
            if a.size == 0 or not np.any(np.isfinite(a)):
                continue
            flat = int(np.nanargmax(a))
            idx = np.unravel_index(flat, a.shape)
            dims = [d for d in seg["dims"] if d != "quantity"]
            over_time = a.reshape(a.shape[0], -1)
            with np.errstate(invalid="ignore"):
                moved = float(np.nanmax(np.nanmax(over_time, axis=0) - np.nanmin(over_time, axis=0)))
            out[f"{seg['name']}.{quantity['name']}"] = {
                # a quantity that never changed has no instant of its peak: time None
                "peak_abs": float(a[idx]), "unit": unit,
                "time_s": float(series.t_s[idx[0]]) if moved > 1e-9 * float(a[idx]) else None,
                "at": {d: int(i) for d, i in zip(dims, idx[1:], strict=True)},
            }
    return out


def recorded_rating_n(bag: Bag) -> float | None:
    """The dynamic load rating C_a in the bag's recorded parameter set; None when it records none (or 0)."""
    text = bag.run_metadata.get("parameters_yaml")
    if not text:
        return None
    from prsm_ros.limits import load_yaml
    try:
        doc = load_yaml(text, source="parameters_yaml")
        c = float(doc["ratings"]["dynamic_load_rating_n"])
    except (KeyError, TypeError, ValueError, OverflowError):
        return None
    return c if math.isfinite(c) and c > 0 else None


def _metadata_number(meta: dict, key: str) -> float | None:
    """A number of the bag's run metadata; None where it records none or a value that is no finite number
    (a damaged metadata record leaves the report of the messages intact)."""
    try:
        value = float(meta[key])
    except (KeyError, TypeError, ValueError, OverflowError):
        return None
    return value if math.isfinite(value) else None


def _ground_truth_topic(bag: Bag) -> str | None:
    name = TOPIC_DEFS["ground_truth"].resolved()
    suffix = "/" + TOPIC_DEFS["ground_truth"].name.removeprefix("~/")
    found = [t for t in bag.topics_of_type("sensor_msgs/msg/JointState") if t == name or t.endswith(suffix)]
    return name if name in found else (found[0] if len(found) == 1 else None)


def _match(stamps: np.ndarray, other: Series, key: str) -> np.ndarray:
    """`other`'s `key` at the samples of the same stamp, NaN where it has none."""
    return _paired(stamps, other.stamp_ns, other.values[key])


def report(bag: Bag, out_dir=None, *, dynamic_load_rating_n: float | None = None,
           screw_joint: str = SCREW_JOINT, nut_joint: str = NUT_JOINT, topics: dict | None = None,
           plots: bool = True, progress: bool = True) -> dict:
    """Metrics (a JSON-able dict) and PNG plots written to `out_dir` (listed under "plots").

    `out_dir` None: `default_output_dir(bag.path)`. `dynamic_load_rating_n` None: the bag's own.
    """
    if dynamic_load_rating_n is not None and not (math.isfinite(dynamic_load_rating_n) and dynamic_load_rating_n > 0):
        raise BagError(f"--dynamic-load-rating-n {dynamic_load_rating_n!r}: must be a force in N > 0")
    roles = resolve_topics(bag, topics)
    if roles["joint_states"] is None:
        js = bag.topics_of_type("sensor_msgs/msg/JointState")
        raise BagError(f"no joint states to report on (a sensor_msgs/msg/JointState topic named "
                       f"/joint_states{'; JointState topics here: ' + ', '.join(js) + ', choose with --joint-states-topic' if js else ''})")
    joints = _joint_series(bag, roles["joint_states"], screw_joint, nut_joint, progress)
    if joints.t_s.size < 2:
        raise BagError(f"{roles['joint_states']} has {joints.t_s.size} message(s); the report needs at least 2")
    internal = _internal_series(bag, roles, progress)
    truth_topic = _ground_truth_topic(bag)
    truth = _joint_series(bag, truth_topic, screw_joint, nut_joint, progress) if truth_topic else None
    if truth is not None and truth.t_s.size == 0:
        truth = None
    t = joints.t_s
    meta = bag.run_metadata
    result: dict = {
        "bag": str(bag.path), "complete": bag.complete, "note": bag.note,
        "model": meta.get("model"), "preset": meta.get("preset"), "dt_s": _metadata_number(meta, "dt_s"),
        "topics": {k: v for k, v in roles.items() if v} | ({"ground_truth": truth_topic} if truth is not None else {}),
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

    result["tracking"], ref = _tracking(bag, roles, joints, nut_joint, progress)
    err = ref - x if ref is not None else None

    eff, terms = _efficiency(internal, roles, t, tau, w, f_nut, v)
    result["efficiency"] = eff
    result.update(_internal_blocks(internal))
    result["model"] = result["model"] or (internal[1].get("model") if internal is not None else None)
    result["measurement"] = _measurement(joints, truth)
    result["life"] = _life(bag, t, f_nut, w, dynamic_load_rating_n, roles, screw_joint, nut_joint, joints)
    result["events"] = _events(bag)
    result["load_distribution"] = load_distribution_summary(*internal) if internal is not None else None
    result["plots"] = []
    if plots:
        out = Path(out_dir) if out_dir is not None else default_output_dir(bag.path)
        data = RunData(t=t, joints=joints.values, reference_m=ref, error_m=err, internal=internal, efficiency=eff,
                       truth=None if truth is None else {k: _match(joints.stamp_ns, truth, k) for k in
                                                         ("nut_position_m", "screw_speed_rad_s", "nut_force_n")})
        result["plots"] = [str(p) for p in _plots(out, data, terms, _context(bag, result, joints, internal, roles),
                                                  result["events"])]
    return result


def _efficiency(internal, roles: dict, t, tau, w, f_nut, v) -> tuple[dict, dict]:
    """The efficiency block (from ~/internal_loads' powers when recorded) and its per-sample energy terms."""
    if internal is not None and "power_in_w" in internal[0].values:
        s = internal[0]
        args = (s.t_s, s.values["power_in_w"], s.values["power_out_w"], s.values.get("power_dissipated_w"))
        eff = energy_efficiency(*args)
        eff["source"] = f"{roles['internal_loads']} power_in_w, power_out_w, power_dissipated_w"
        return eff, energy_terms(*args)
    eff = energy_efficiency(t, tau * w, f_nut * v, speeds=(w, v))
    eff["source"] = f"{roles['joint_states']} τ_S·ω_S and F_nut·v_nut, quasi-steady samples"
    return eff, energy_terms(t, tau * w, f_nut * v, speeds=(w, v))


def _internal_blocks(internal) -> dict:
    """slip, peak_loads and actuator from ~/internal_loads (None each when it is not recorded)."""
    if internal is None:
        return {"slip": None, "peak_loads": None, "actuator": None}
    s, labels = internal
    slip = {}
    if "slip_speed_m_s" in s.values:
        sv = s.values["slip_speed_m_s"]
        slip = {"max_slip_speed_m_s": float(np.nanmax(np.abs(sv))), "mean_slip_speed_m_s": float(np.nanmean(np.abs(sv)))}
    slip["peaks"] = _peaks(s, labels, "m/s", name_has="slip")
    return {"slip": slip, "peak_loads": _peaks(s, labels, "N"), "actuator": _actuator(internal)}


def _measurement(joints: Series, truth: Series | None) -> dict | None:
    """Measured against ground truth, paired by stamp: RMS and max error of position, angle and force."""
    if truth is None:
        return None
    m = {}
    for key in ("nut_position_m", "screw_angle_rad", "nut_force_n"):
        d = joints.values[key] - _match(joints.stamp_ns, truth, key)
        d = d[np.isfinite(d)]
        if d.size:
            m[key.rsplit("_", 1)[0] + "_rms_error_" + key.rsplit("_", 1)[1]] = float(np.sqrt(np.mean(d**2)))
            m[key.rsplit("_", 1)[0] + "_max_error_" + key.rsplit("_", 1)[1]] = float(np.max(np.abs(d)))
    return m or None


def _tracking(bag: Bag, roles: dict, joints: Series, nut_joint: str, progress: bool):
    """The tracking block and the reference at each state (NaN where none applies)."""
    if not roles["reference"]:
        return None, None
    r = _reference_series(bag, roles["reference"], nut_joint, progress)
    if not r.t_s.size:
        return None, None
    t, x = joints.t_s, joints.values["nut_position_m"]
    if r.stamp_ns is not None:
        ref = _paired(joints.stamp_ns, r.stamp_ns, r.values["value"])
        pairing = "stamp: each reference with the state it answers"
    else:
        ref = _held(t, r.t_s, r.values["value"])
        # the reference is live from its first message to one message interval after its last
        period = float(np.median(np.diff(r.t_s))) if r.t_s.size > 1 else 0.0
        ref[t > r.t_s[-1] + period * (1 + 1e-6)] = np.nan
        pairing = "held: the latest reference at each state time"
    err = ref - x
    ok = np.isfinite(err)
    if not ok.any():
        return {"reference_topic": roles["reference"], "pairing": pairing, "pairs": 0, "rms_error_m": None,
                "max_error_m": None, "final_rms_error_m": None, "reference_span_m": float(np.ptp(r.values["value"]))}, ref
    t_ok = t[ok]
    tail = ok & (t >= t_ok[0] + 0.9 * (t_ok[-1] - t_ok[0]))
    return {
        "reference_topic": roles["reference"], "pairing": pairing, "pairs": int(ok.sum()),
        "rms_error_m": float(np.sqrt(np.mean(err[ok] ** 2))),
        "max_error_m": float(np.max(np.abs(err[ok]))),
        "final_rms_error_m": float(np.sqrt(np.mean(err[tail] ** 2))),
        "reference_span_m": float(np.ptp(r.values["value"][np.isfinite(r.values["value"])])),
    }, ref


def _actuator(internal) -> dict | None:
    """The actuator's own figures (end stops, brake, motor, faults, load cell) when its block is recorded."""
    s, _ = internal
    t = s.t_s
    q = {name: _block_quantity(internal, "actuator", name) for name in
         ("stop_force_n", "stop_absorbed_j", "brake_level", "motor_current_a", "motor_torque_nm", "faults_active",
          "torque_limited")}
    if all(a is None for a in q.values()):
        return None
    dt = np.zeros_like(t)
    dt[1:] = np.diff(t)

    def peak(a):
        return None if a is None else _finite_max(np.abs(a))

    def time_on(a):
        return None if a is None else float(np.sum(dt[np.nan_to_num(a) > 0]))

    load_cell = _block_quantity(internal, "measured", "nut_force_n")
    return {
        "peak_abs_stop_force_n": peak(q["stop_force_n"]),
        "stop_contact_s": None if q["stop_force_n"] is None else float(np.sum(dt[np.nan_to_num(q["stop_force_n"]) != 0])),
        "stop_absorbed_j": None if q["stop_absorbed_j"] is None else _finite_max(q["stop_absorbed_j"]),
        "brake_engaged_s": time_on(q["brake_level"]),
        "peak_abs_motor_current_a": peak(q["motor_current_a"]),
        "peak_abs_motor_torque_nm": peak(q["motor_torque_nm"]),
        "torque_limited_s": time_on(q["torque_limited"]),
        "fault_active_s": time_on(q["faults_active"]),
        "peak_abs_load_cell_n": peak(load_cell),
    }


def _life(bag: Bag, t, f_nut, w, rating_given, roles, screw_joint, nut_joint, joints: Series) -> dict | None:
    """L10 over the samples that carry both an effort and a velocity, with the rating's source, and the
    nut travel it stands for (L10 revolutions × the recorded nut path per screw revolution)."""
    usable = np.isfinite(f_nut) & np.isfinite(w)
    if usable.sum() < 2:
        return None
    recorded = recorded_rating_n(bag)
    if rating_given is not None:
        rating, source = float(rating_given), "given (--dynamic-load-rating-n)"
    elif recorded is not None:
        rating, source = recorded, "the bag's parameter set (ratings.dynamic_load_rating_n)"
    else:
        rating, source = DEFAULT_DYNAMIC_LOAD_RATING_N, "default (the bag records no rating; give --dynamic-load-rating-n)"
    life = life_from_samples(t[usable], f_nut[usable], w[usable], rating)
    # the lead as the run shows it: nut path over screw turns (both summed as |steps|)
    x, theta = joints.values["nut_position_m"], joints.values["screw_angle_rad"]
    turns = float(np.nansum(np.abs(np.diff(theta)))) / (2 * math.pi)
    per_rev = float(np.nansum(np.abs(np.diff(x)))) / turns if turns > 0 else math.nan
    out = {**life.to_dict(), "rating_source": source,
           "load_source": f"|{nut_joint} effort| on {roles['joint_states']}",
           "speed_source": f"{screw_joint} velocity on {roles['joint_states']}",
           "nut_travel_per_revolution_m": per_rev}
    rev = out.get("l10_revolutions")
    out["l10_travel_km"] = rev * per_rev / 1e3 if rev is not None and math.isfinite(per_rev) else None
    return out


def _events(bag: Bag) -> list[dict]:
    """Every ~/events entry (std_msgs/String, one JSON object each; prsm_ros.messages.event_message)."""
    out = []
    for topic in (t for t in bag.topics_of_type("std_msgs/msg/String") if t.endswith("/events")):
        for m in bag.messages([topic]):
            try:
                doc = load_json(m.msg.data, source=topic)
            except ValueError:
                doc = {"message": str(getattr(m.msg, "data", m.msg))[:200], "code": "unparsed"}
            if not isinstance(doc, dict):
                doc = {"message": str(doc)[:200]}
            t = doc.get("time_s")
            if not (isinstance(t, (int, float)) and not isinstance(t, bool) and abs(t) <= MAX_WINDOW_S):
                doc["time_s"] = m.log_time_ns * 1e-9  # its own time when it carries none that fits a bag
            out.append({"topic": topic, **doc})
    return out


COMMAND_MODES = {0: "effort", 1: "velocity", 2: "position"}  # the actuator block's `mode`


def _marks(internal, events: list[dict]) -> Marks:
    """What every plot marks: event lines (`~/events`: faults, thread ends, parameter changes…), load
    steps and command-mode switches (time, label, colour), and shaded spans (start, end, label, colour)
    where the actuator block records the brake, an end stop, a thread end or a fault."""
    lines = [(float(e["time_s"]), str(e.get("code", "event")), MARK_COLOURS.get(e.get("severity"), "dimgray"))
             for e in events if isinstance(e.get("time_s"), (int, float)) and math.isfinite(e["time_s"])]
    spans = []
    if internal is not None:
        t = internal[0].t_s
        lines += load_steps(t, internal[0].values.get("load_force_n"))
        mode = _block_quantity(internal, "actuator", "mode")
        if mode is not None:  # a switch of the command interface (effort, velocity, position)
            switched = np.flatnonzero(np.diff(np.nan_to_num(mode)) != 0) + 1
            lines += [(float(t[k]), f"mode → {COMMAND_MODES.get(int(mode[k]), int(mode[k]))}", MARK_COLOURS["info"])
                      for k in switched]
        for name, label, on in (("brake_level", "brake", lambda a: a > 0), ("stop_force_n", "end stop", lambda a: a != 0),
                                ("thread_end", "thread end", lambda a: a > 0), ("faults_active", "fault", lambda a: a > 0)):
            a = _block_quantity(internal, "actuator", name)
            if a is not None:
                spans += [(a0, a1, label, SPAN_COLOURS[label]) for a0, a1 in _spans(t, on(np.nan_to_num(a)))]
    return Marks(lines=tuple(sorted(lines)), spans=tuple(spans))


def _context(bag: Bag, r: dict, joints: Series, internal, roles: dict) -> Context:
    """The run as every figure's title names it: bag, model, preset, load and controller."""
    import yaml
    meta = bag.run_metadata
    try:
        node = yaml.safe_load(meta.get("node_parameters_yaml") or "") or {}
    except yaml.YAMLError:
        node = {}
    node = node if isinstance(node, dict) else {}
    load = internal[0].values.get("load_force_n") if internal is not None else None
    if load is None:
        load, what = joints.values["nut_force_n"], "nut force"
    else:
        what = "applied"
    finite = load[np.isfinite(load)]
    if not finite.size:
        load_text = "not recorded"
    elif np.ptp(finite) <= 1e-6 * max(1.0, float(np.max(np.abs(finite)))):
        load_text = force_text(float(finite[0]))
    else:
        load_text = f"{force_text(float(finite.min()))} … {force_text(float(finite.max()))} ({what})"
    torque = roles.get("screw_torque")
    if node.get("command_interface"):
        controller = f"{node['command_interface']} commands to the node"
    elif torque and bag.topics.get(torque) is not None and bag.topics[torque].count:
        controller = f"screw torque commands on {torque}"
    else:
        controller = "not recorded"
    if roles.get("reference") and r.get("tracking"):
        controller += " (position reference recorded)"
    example = bag.metadata.get("prsm_example", {}).get("description", "")
    return Context(bag=bag.path.name, model=r.get("model") or "unknown", preset=r.get("preset") or "unknown",
                   load=load_text, controller=controller, description=example)


def _window(d: RunData, t0: float, t1: float) -> RunData:
    """The run's data over [t0, t1] (the zoom figures)."""
    k = (d.t >= t0) & (d.t <= t1)

    def cut(v):
        return None if v is None else v[k]
    internal = None
    if d.internal is not None:
        s, labels = d.internal
        ki = (s.t_s >= t0) & (s.t_s <= t1)
        internal = (Series(s.t_s[ki], {n: a[ki] for n, a in s.values.items()}), labels)
    return RunData(t=d.t[k], joints={n: a[k] for n, a in d.joints.items()}, reference_m=cut(d.reference_m),
                   error_m=cut(d.error_m), internal=internal, efficiency=d.efficiency,
                   truth=None if d.truth is None else {n: a[k] for n, a in d.truth.items()})


def _plots(out_dir: Path, d: RunData, terms: dict, ctx: Context, events: list[dict]) -> list[Path]:
    """Every figure of the run, written to `out_dir` (module docstring of prsm_ros.bag.figures)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    marks = _marks(d.internal, events)
    files = [motion_figure(out_dir / "motion.png", d, ctx, marks), loads_figure(out_dir / "loads.png", d, ctx, marks)]
    if d.t[-1] - d.t[0] > LONG_RUN_S:
        t0, t1 = busiest_window(d.t, d.joints["screw_speed_rad_s"], d.joints["nut_force_n"])
        zoom = _window(d, t0, t1)
        files += [motion_figure(out_dir / "motion_zoom.png", zoom, ctx, marks, t_range=(t0, t1)),
                  loads_figure(out_dir / "loads_zoom.png", zoom, ctx, marks, t_range=(t0, t1))]
    if d.internal is None:
        return files
    s, labels = d.internal
    if "power_in_w" in s.values:
        files.append(power_figure(out_dir / "power.png", d, ctx, marks, terms))
    files.append(internal_loads_figure(out_dir / "internal_loads.png", d, ctx, marks, ACTUATOR_BLOCKS))
    act = [(name, unit, a) for name, unit, a in (
        (name, unit, _block_quantity(d.internal, "actuator", name)) for name, unit in
        (("motor_current_a", "A"), ("motor_torque_nm", "N·m"), ("brake_torque_nm", "N·m"), ("stop_force_n", "N")))
        if a is not None and np.any(np.nan_to_num(a) != 0)]
    files.append(actuator_figure(out_dir / "actuator.png", d, ctx, marks, act))
    files.append(load_distribution_figure(out_dir / "load_distribution.png", s, labels, ctx))
    return [f for f in files if f is not None]


def _fmt(v, unit: str = "", scale: float = 1.0, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "n/a"
    if isinstance(v, float) and math.isinf(v):
        return "infinite"
    return f"{v * scale:.{digits}g}{(' ' + unit) if unit else ''}"


def _peak_lines(peaks: dict | None) -> list[str]:
    """Peaks of the internal loads that moved; constant ones by value, the ones zero throughout in one line."""
    if not peaks:
        return ["peak internal loads: not recorded"]
    lines, zero = ["peak internal loads:"], []
    for name, p in peaks.items():
        where = ", ".join(f"{d} {i}" for d, i in p["at"].items())
        if p["peak_abs"] == 0:
            zero.append(name)
        elif p["time_s"] is None:
            lines.append(f"  {name}: {_fmt(p['peak_abs'], 'N')} throughout")
        else:
            lines.append(f"  {name}: {_fmt(p['peak_abs'], 'N')} at t = {_fmt(p['time_s'], 's')}"
                         + (f" ({where})" if where else ""))
    if zero:
        lines.append(f"  zero throughout: {', '.join(zero)}")
    return lines


def readable(v: float | None, unit: str) -> str:
    """A large count for people: grouped digits below a million, else a mantissa and a power of ten."""
    if v is None or not math.isfinite(v):
        return "n/a" if v is None or math.isnan(v) else "infinite"
    if abs(v) < 1e6:
        return f"{v:,.0f} {unit}" if abs(v) >= 100 else f"{v:.3g} {unit}"
    exp = int(math.floor(math.log10(abs(v))))
    sup = str(exp).translate(str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹"))
    return f"{v / 10 ** exp:.3g}·10{sup} {unit}"


def _life_line(life: dict | None) -> str:
    if life is None:
        return "L10 life: n/a (the joint states carry no nut effort and screw velocity)"
    hours = life["l10_hours"]
    years = f" ≈ {readable(hours / 8766.0, 'years')} running" if hours is not None and hours > 2 * 8766 else ""
    return (f"L10 life (C_a = {force_text(life['dynamic_load_rating_n'])} from {life['rating_source']}, "
            f"F_m = {force_text(life['mean_load_n'])}): {readable(life['l10_travel_km'], 'km')} of nut travel "
            f"({readable(life['l10_revolutions'], 'screw revolutions')}), {readable(hours, 'h')}{years} at the "
            f"recorded duty cycle (the {_fmt(life['cycle_duration_s'], 's')} record repeated "
            f"{readable(life['l10_cycles'], 'times')})")


def _distribution_line(d: dict) -> str:
    return (f"load along the nut ({d['rollers']} rollers × {d['threads']} threads, {d['source']}): largest thread "
            f"{d['max_over_uniform_at_peak']:.3g}× the uniform share at the peak ({force_text(d['peak_axial_force_n'])} "
            f"at t = {_fmt(d['peak_time_s'], 's')}), {d['max_over_uniform_averaged']:.3g}× averaged over the run")


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
        lines.append(f"tracking ({tr['reference_topic']}, {tr['pairs']} pairs, {tr['pairing'].split(':')[0]}): "
                     f"RMS error {_fmt(tr['rms_error_m'], 'µm', 1e6)}, max |error| {_fmt(tr['max_error_m'], 'µm', 1e6)}, "
                     f"last 10 % RMS {_fmt(tr['final_rms_error_m'], 'µm', 1e6)}")
    else:
        lines.append("tracking: no reference recorded (publish it on ~/nut_position_reference)")
    e = r["efficiency"]
    lines.append(f"efficiency from energies ({e['source']}): forward {_fmt(e['forward'])} over {e['forward_segments']} "
                 f"segment(s), backward {_fmt(e['backward'])} over {e['backward_segments']} segment(s)")
    s = r.get("slip")
    if s:
        parts = []
        if "max_slip_speed_m_s" in s:
            parts.append(f"max {_fmt(s['max_slip_speed_m_s'], 'mm/s', 1e3)}, mean {_fmt(s['mean_slip_speed_m_s'], 'mm/s', 1e3)}")
        parts += [f"{name} peak {_fmt(p['peak_abs'], 'mm/s', 1e3)}" for name, p in s["peaks"].items() if p["peak_abs"]]
        lines.append("slip: " + "; ".join(parts))
    else:
        lines.append("slip: not recorded (needs ~/internal_loads with its labels)")
    lines += _peak_lines(r.get("peak_loads"))
    a = r.get("actuator")
    if a:
        lines.append(f"actuator: peak |stop force| {_fmt(a['peak_abs_stop_force_n'], 'N')} ({_fmt(a['stop_contact_s'], 's')} "
                     f"in contact), brake engaged {_fmt(a['brake_engaged_s'], 's')}, peak |motor current| "
                     f"{_fmt(a['peak_abs_motor_current_a'], 'A')}, faults active {_fmt(a['fault_active_s'], 's')}, "
                     f"peak |load cell| {_fmt(a['peak_abs_load_cell_n'], 'N')}")
    m = r.get("measurement")
    if m:
        lines.append(f"measured vs ground truth: nut position RMS {_fmt(m.get('nut_position_rms_error_m'), 'µm', 1e6)} "
                     f"(max {_fmt(m.get('nut_position_max_error_m'), 'µm', 1e6)}), nut force RMS "
                     f"{_fmt(m.get('nut_force_rms_error_n'), 'N')}")
    lines.append(_life_line(r["life"]))
    if r.get("load_distribution"):
        lines.append(_distribution_line(r["load_distribution"]))
    for ev in r.get("events", []):
        lines.append(f"event t = {_fmt(ev.get('time_s'), 's')} [{ev.get('severity', '?')}] {ev.get('source', '?')}/"
                     f"{ev.get('code', '?')}: {ev.get('message', '')}")
    if r["plots"]:
        lines.append("plots: " + ", ".join(r["plots"]))
    return "\n".join(lines)
