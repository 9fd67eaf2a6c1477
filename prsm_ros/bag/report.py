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
    return [(float(t[a]), float(t[min(b, t.size - 1)])) for a, b in zip(edges[::2], edges[1::2])]


def _runs(mask: np.ndarray) -> int:
    """Number of maximal runs of True in `mask`."""
    m = np.asarray(mask, dtype=np.int8)
    return int(np.sum(np.diff(np.concatenate(([0], m))) == 1))


def energy_efficiency(t: np.ndarray, p_in: np.ndarray, p_out: np.ndarray, p_diss: np.ndarray | None = None,
                      speeds: tuple[np.ndarray, ...] = ()) -> dict:
    """Forward and backward efficiencies from energies (module docstring); None where no such power flowed.

    Sample k stands for the interval from t[k−1] to t[k] (our powers are step averages over it; the
    first sample has none). `p_diss`: the dissipated power, so the stored-energy change is what
    remains of the balance; without it only quasi-steady samples count, judged by `speeds` (each
    a 1-D array over t whose relative change between samples must stay below STEADY_SPEED_CHANGE).
    """
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
    fwd = counted & (p_in > 0) & (p_out > 0)
    bwd = counted & (p_in < 0) & (p_out < 0)
    # flows at round-off level (a speed of 1e-16 rad/s at rest) are no flow
    tiny = NEGLIGIBLE_ENERGY_FRACTION * float(np.sum(np.abs(e_in)) + np.sum(np.abs(e_out)))
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
    """Peak |value| of every mechanism block quantity with `unit` (and `name_has` in its name): value, time, element."""
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
            out[f"{seg['name']}.{quantity['name']}"] = {
                "peak_abs": float(a[idx]), "unit": unit, "time_s": float(series.t_s[idx[0]]),
                "at": {d: int(i) for d, i in zip(dims, idx[1:])},
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
        "model": meta.get("model"), "preset": meta.get("preset"), "dt_s": float(meta["dt_s"]) if "dt_s" in meta else None,
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

    # efficiency
    if internal is not None and "power_in_w" in internal[0].values:
        s = internal[0]
        eff = energy_efficiency(s.t_s, s.values["power_in_w"], s.values["power_out_w"], s.values.get("power_dissipated_w"))
        eff["source"] = f"{roles['internal_loads']} power_in_w, power_out_w, power_dissipated_w"
    else:
        eff = energy_efficiency(t, tau * w, f_nut * v, speeds=(w, v))
        eff["source"] = f"{roles['joint_states']} τ_S·ω_S and F_nut·v_nut, quasi-steady samples"
    result["efficiency"] = eff

    # slip, internal loads, actuator
    result["slip"] = None
    result["peak_loads"] = None
    result["actuator"] = None
    if internal is not None:
        s, labels = internal
        slip = {}
        if "slip_speed_m_s" in s.values:
            sv = s.values["slip_speed_m_s"]
            slip = {"max_slip_speed_m_s": float(np.nanmax(np.abs(sv))), "mean_slip_speed_m_s": float(np.nanmean(np.abs(sv)))}
        slip["peaks"] = _peaks(s, labels, "m/s", name_has="slip")
        result["slip"] = slip
        result["peak_loads"] = _peaks(s, labels, "N")
        result["model"] = result["model"] or labels.get("model")
        result["actuator"] = _actuator(internal)

    # measured against ground truth, paired by stamp
    result["measurement"] = None
    if truth is not None:
        m = {}
        for key in ("nut_position_m", "screw_angle_rad", "nut_force_n"):
            d = joints.values[key] - _match(joints.stamp_ns, truth, key)
            d = d[np.isfinite(d)]
            if d.size:
                m[key.rsplit("_", 1)[0] + "_rms_error_" + key.rsplit("_", 1)[1]] = float(np.sqrt(np.mean(d**2)))
                m[key.rsplit("_", 1)[0] + "_max_error_" + key.rsplit("_", 1)[1]] = float(np.max(np.abs(d)))
        result["measurement"] = m or None

    result["life"] = _life(bag, t, f_nut, w, dynamic_load_rating_n, roles, screw_joint, nut_joint)
    result["events"] = _events(bag)
    if plots:
        out = Path(out_dir) if out_dir is not None else default_output_dir(bag.path)
        result["plots"] = [str(p) for p in _plots(out, joints, truth, internal, ref, err, result["events"])]
    else:
        result["plots"] = []
    return result


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


def _life(bag: Bag, t, f_nut, w, rating_given, roles, screw_joint, nut_joint) -> dict | None:
    """L10 over the samples that carry both an effort and a velocity, with the rating's source."""
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
    return {**life.to_dict(), "rating_source": source,
            "load_source": f"|{nut_joint} effort| on {roles['joint_states']}",
            "speed_source": f"{screw_joint} velocity on {roles['joint_states']}"}


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


LEGEND_ROWS = 7
EVENT_COLOURS = {"error": "tab:red", "warn": "tab:orange", "info": "tab:gray"}


def _marks(internal, events: list[dict]) -> tuple[list[tuple[float, str, str]], list[tuple[float, float, str, str]]]:
    """What every plot marks: event lines (time, label, colour) and shaded spans (start, end, label, colour)."""
    lines = [(float(e["time_s"]), str(e.get("code", "event")), EVENT_COLOURS.get(e.get("severity"), "tab:gray"))
             for e in events if isinstance(e.get("time_s"), (int, float)) and math.isfinite(e["time_s"])]
    spans = []
    if internal is not None:
        t = internal[0].t_s
        for name, label, colour, on in (("brake_level", "brake", "tab:purple", lambda a: a > 0),
                                        ("stop_force_n", "end stop", "tab:brown", lambda a: a != 0),
                                        ("faults_active", "fault", "tab:red", lambda a: a > 0)):
            a = _block_quantity(internal, "actuator", name)
            if a is not None:
                spans += [(a0, a1, label, colour) for a0, a1 in _spans(t, on(np.nan_to_num(a)))]
    return lines, spans


def _plots(out_dir: Path, joints: Series, truth: Series | None, internal, ref, err, events) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch
    from matplotlib.lines import Line2D

    out_dir.mkdir(parents=True, exist_ok=True)
    t = joints.t_s
    files: list[Path] = []
    lines, spans = _marks(internal, events)

    def legend(a, x: float = 1.01) -> None:
        """Outside the axes on the right (beyond a right-hand axis: x), so it never covers a curve or
        spills over the next panel."""
        handles, labels = a.get_legend_handles_labels()
        if handles:  # columns of at most LEGEND_ROWS entries: the height of a panel
            a.legend(handles, labels, loc="upper left", bbox_to_anchor=(x, 1.0), fontsize="small",
                     borderaxespad=0.0, frameon=False, ncol=-(-len(handles) // LEGEND_ROWS))

    def mark(axes) -> None:
        for a in axes:
            for t0, t1, _, colour in spans:
                a.axvspan(t0, t1, color=colour, alpha=0.12, linewidth=0)
            for te, _, colour in lines:
                a.axvline(te, color=colour, linestyle=":", linewidth=1.0)
        if lines or spans:  # one key for the marks, under the top panel's legend
            keys = {}
            for _, label, colour in lines:
                keys.setdefault(f"event {label}", Line2D([], [], color=colour, linestyle=":"))
            for _, _, label, colour in spans:
                keys.setdefault(label, Patch(color=colour, alpha=0.25))
            curves = axes[-1].get_legend()  # a second legend replaces the first: keep it as an artist
            axes[-1].legend(list(keys.values()), list(keys), loc="lower left", bbox_to_anchor=(1.01, 0.0),
                            fontsize="small", frameon=False, borderaxespad=0.0)
            if curves is not None:
                axes[-1].add_artist(curves)

    def save(fig, axes, name: str) -> None:
        axes[-1].set_xlabel("time [s]")
        mark(axes)
        fig.tight_layout()
        path = out_dir / name
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
        files.append(path)

    def truth_of(key):
        return None if truth is None else _match(joints.stamp_ns, truth, key)

    width = 9.5
    n = 3 if err is not None else 2
    fig, ax = plt.subplots(n, 1, sharex=True, figsize=(width, 2.4 * n))
    ax[0].plot(t, joints.values["nut_position_m"] * 1e3, label="nut position" + (" (measured)" if truth else ""))
    if truth is not None:
        ax[0].plot(t, truth_of("nut_position_m") * 1e3, label="ground truth", linestyle="-.", linewidth=1.0)
    if ref is not None:
        ax[0].plot(t, ref * 1e3, label="reference", linestyle="--")
    ax[0].set_ylabel("x_nut [mm]")
    legend(ax[0])
    ax[1].plot(t, joints.values["screw_speed_rad_s"], label="screw speed" + (" (measured)" if truth else ""))
    if truth is not None:
        ax[1].plot(t, truth_of("screw_speed_rad_s"), label="ground truth", linestyle="-.", linewidth=1.0)
        legend(ax[1])
    ax[1].set_ylabel("ω_S [rad/s]")
    if err is not None:
        ax[2].plot(t, err * 1e6, label="reference − nut position")
        ax[2].set_ylabel("error [µm]")
    save(fig, ax, "motion.png")

    fig, ax = plt.subplots(2, 1, sharex=True, figsize=(width, 4.8))
    ax[0].plot(t, joints.values["screw_torque_nm"], label="screw torque")
    ax[0].set_ylabel("torque [N·m]")
    legend(ax[0])
    ax[1].plot(t, joints.values["nut_force_n"], label="nut force" + (" (load cell)" if truth else " (thread)"))
    if truth is not None:
        ax[1].plot(t, truth_of("nut_force_n"), label="ground truth", linestyle="-.", linewidth=1.0)
    if internal is not None and "load_force_n" in internal[0].values:
        ax[1].plot(internal[0].t_s, internal[0].values["load_force_n"], label="load force", linestyle="--")
    ax[1].set_ylabel("force [N]")
    legend(ax[1])
    save(fig, ax, "loads.png")

    if internal is None:
        return files
    s, labels = internal
    if "power_in_w" in s.values:
        fig, ax = plt.subplots(2, 1, sharex=True, figsize=(width, 4.8))
        for k in ("power_in_w", "power_out_w", "power_dissipated_w"):
            ax[0].plot(s.t_s, s.values[k], label=k.removesuffix("_w").replace("_", " "))
        ax[0].set_ylabel("power [W]")
        legend(ax[0])
        ax[1].plot(s.t_s, s.values["efficiency"], label="instantaneous efficiency")
        ax[1].set_ylabel("efficiency [1]")
        if "slip_speed_m_s" in s.values:
            ax[1].plot([], [], color="tab:red", alpha=0.6, label="slip speed (right axis)")
            ax2 = ax[1].twinx()
            ax2.plot(s.t_s, s.values["slip_speed_m_s"] * 1e3, color="tab:red", alpha=0.6)
            ax2.set_ylabel("slip [mm/s]", color="tab:red")
        legend(ax[1], x=1.12 if "slip_speed_m_s" in s.values else 1.01)
        save(fig, ax, "power.png")

    panels = _force_panels(s, labels)
    if panels:
        fig, ax = plt.subplots(len(panels), 1, sharex=True, figsize=(width, 2.6 * len(panels)), squeeze=False)
        for a, (name, curves) in zip(ax[:, 0], panels):
            for label, values in curves:
                a.plot(s.t_s, values, label=label)
            a.set_ylabel(f"{name}\nmax |F| [N]")
            legend(a)
        save(fig, list(ax[:, 0]), "internal_loads.png")

    act = [(label, unit, a) for label, unit, a in (
        (name, unit, _block_quantity(internal, "actuator", name)) for name, unit in
        (("motor_current_a", "A"), ("motor_torque_nm", "N·m"), ("brake_torque_nm", "N·m"), ("stop_force_n", "N")))
        if a is not None and np.any(np.nan_to_num(a) != 0)]
    if act:
        fig, ax = plt.subplots(len(act), 1, sharex=True, figsize=(width, max(3.4, 2.2 * len(act))), squeeze=False)
        for a, (label, unit, values) in zip(ax[:, 0], act):
            a.plot(s.t_s, values, label=label.rsplit("_", 1)[0].replace("_", " "))
            a.set_ylabel(f"[{unit}]")
            legend(a)
        save(fig, list(ax[:, 0]), "actuator.png")
    return files


def _force_panels(s: Series, labels: dict) -> list[tuple[str, list[tuple[str, np.ndarray]]]]:
    """One panel per mechanism block with a force quantity that is not zero throughout: (block, curves)."""
    panels = []
    for seg in labels["segments"]:
        if "quantities" not in seg or seg["name"] in ACTUATOR_BLOCKS:
            continue
        arr = s.values[seg["name"]]
        names = [q["name"] for q in seg["quantities"]]
        curves = []
        for q in seg["quantities"]:
            if q["unit"] != "N":
                continue
            vals = np.abs(arr[..., names.index(q["name"])]).reshape(arr.shape[0], -1)
            peak = np.nanmax(vals, axis=1) if vals.shape[1] else np.zeros(arr.shape[0])
            if np.any(np.nan_to_num(peak) != 0):
                curves.append((q["name"].removesuffix("_n").replace("_", " "), peak))
        if curves:
            panels.append((seg["name"], curves))
    return panels


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
    life = r["life"]
    if life is None:
        lines.append("L10 life: n/a (the joint states carry no nut effort and screw velocity)")
    else:
        lines.append(f"L10 life (C_a = {_fmt(life['dynamic_load_rating_n'], 'N')} from {life['rating_source']}, "
                     f"F_m = {_fmt(life['mean_load_n'], 'N')}): {_fmt(life['l10_revolutions'], 'revolutions')} = "
                     f"{_fmt(life['l10_hours'], 'h')} at the recorded cycle ({_fmt(life['l10_cycles'], 'cycles')} of "
                     f"{_fmt(life['cycle_duration_s'], 's')})")
    for ev in r.get("events", []):
        lines.append(f"event t = {_fmt(ev.get('time_s'), 's')} [{ev.get('severity', '?')}] {ev.get('source', '?')}/"
                     f"{ev.get('code', '?')}: {ev.get('message', '')}")
    if r["plots"]:
        lines.append("plots: " + ", ".join(r["plots"]))
    return "\n".join(lines)
