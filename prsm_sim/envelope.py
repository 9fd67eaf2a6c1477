"""The operating envelope: closed loops at the plant's edges, drawn at random, and the invariants they must keep.

A case is plain data (a dict that round-trips through YAML/JSON): model, step, how the plant is
driven (bare screw torque, or the actuator's drive in effort, velocity or position), a controller
(PID hold, sine tracking, bang-bang reversals at the torque limit), a load (zero, constant of
either sign, steps, sign changes, pressing into a stop), end stops, thread ends, backlash and
preload (elastic), brake engage/release, bounded injected faults, and a pause and a reset
mid-run. A case runs through `prsm_sim.Session`, the node's own stepping layer (command gate,
brake, pause, reset), so what the envelope checks is what the node runs.
`case_from_seed(seed)` draws one; `run_case(case)` runs it and returns what it broke:

- a valid closed loop never raises; a pause stops time and a state saved while paused
  (`Session.get_state`) continues in a fresh session exactly where it stopped;
- every state is finite; the model's energy guard never trips, and the actuator's ledger
  (energy in = load work + dissipated + Δstored) closes within the guard's limit;
- an impact goes no further past a stop or thread end than the work allows: ½ k δ² ≤ W, W the
  energy stored at first contact plus the work of the drive and the load since;
- at rest against a stop, δ lies within the static deflection of the net force pressing the nut
  (load less what the threads carry) + 2 µm; the nut never leaves its threads;
- with a constant command and the nut held against a stop, the screw does not ring: its speed
  varies by less than 0.5 rad/s peak to peak over the last 0.5 s, or no longer swings both ways
  in the last 0.1 s (an integral action pressing the nut further in, and the decaying ring when
  the torque limit halts it, are the controller's physics).

Pure (no I/O): the envelope command (`prsm-sim envelope`) spreads cases over Ray and writes the
failing ones; tests/test_envelope.py draws them with hypothesis.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

import numpy as np

from prsm_sim.actuator import (ACTUATOR_QUANTITIES, ActuatorParams, BrakeParams, DriveParams, Fault, MotorParams,
                               StopParams)
from prsm_sim.control import PositionController
from prsm_sim.models.ideal import reflected_inertia
from prsm_sim.presets import preset
from prsm_sim.session import Session, SessionConfig
from prsm_sim.stepping.ledger import ENERGY_GUARD_MIN_FLOW_J, ENERGY_GUARD_REL

MODELS = ("ideal", "jones2016", "fu2018", "elastic")
INTERFACES = ("torque", "effort", "velocity", "position")
CONTROLLERS = ("hold", "sine", "bangbang")
LOADS = ("zero", "constant", "steps", "square", "into_stop")
REST_SLACK_M = 2e-6  # rest penetration beyond the static deflection allowed (the invariant's 2 µm)
P2P_LIMIT_RAD_S = 0.5
SETTLE_S = 0.1  # an impact's decay before a hold is judged
TORQUE_LIMIT_NM = 10.0  # the default motor's, also the bare loop's clamp
_Q = {n: i for i, (n, _) in enumerate(ACTUATOR_QUANTITIES)}


def case_from_seed(seed: int) -> dict:
    """One envelope case drawn from `seed` (numpy's generator: the same seed, the same case)."""
    return draw_case(np.random.default_rng(int(seed)), int(seed))


def draw_case(rng, seed: int | None = None) -> dict:
    """One envelope case drawn by `rng`: anything with numpy's Generator methods `choice(n, p=None)`,
    `uniform(lo, hi)`, `random()` and `integers(n)` (a test passes hypothesis' draws through them)."""

    def pick(options, p=None):
        return options[int(rng.choice(len(options), p=p))]

    model = pick(MODELS)
    dt = pick((1e-3, 1e-4), p=(0.8, 0.2))
    interface = pick(INTERFACES)
    controller = pick(CONTROLLERS)
    # long enough for a hold to be judged (0.5 s + settling), short elsewhere: thousands of runs on two cores
    lo, hi = ((0.62, 0.7) if controller == "hold" else (0.2, 0.5)) if dt == 1e-3 else (0.02, 0.05)
    duration = float(np.round(rng.uniform(lo, hi), 3))
    case = {"seed": seed, "preset": "s30", "model": model, "dt_s": dt, "duration_s": duration,
            "interface": interface, "controller": controller, "overrides": {}}
    p = preset("s30")
    half = 0.5 * p.geometry.travel_m
    # where the nut starts and what it is asked: near the middle, near a stop, or near a thread end
    near = pick(("middle", "stop", "end"))
    start = float(np.round(rng.uniform(-0.01, 0.01), 5))
    stops = None
    if near == "stop" and interface != "torque":
        gap = float(np.round(rng.uniform(2e-4, 5e-3), 5))
        sgn = pick((1.0, -1.0))
        stops = {"min_position_m": start - 0.05, "max_position_m": start + gap} if sgn > 0 else \
                {"min_position_m": start - gap, "max_position_m": start + 0.05}
        stops.update(stiffness_n_m=float(pick((1e7, 1e8, 1e9))), damping_n_s_m=float(pick((0.0, 2e4, 2e5))))
    elif near == "end":
        start = float(np.round(pick((1.0, -1.0)) * (half - rng.uniform(2e-4, 5e-3)), 6))
    case["start_m"] = start
    case["stops"] = stops
    case["thread_ends"] = bool(rng.random() < 0.9)
    if not case["thread_ends"]:
        case["overrides"]["geometry.thread_ends"] = False
    amplitude = float(np.round(rng.uniform(5e-4, 8e-3), 5))
    case.update(target_m=float(np.round(start + rng.uniform(-1, 1) * amplitude, 6)), amplitude_m=amplitude,
                frequency_hz=float(np.round(rng.uniform(0.5, 8.0), 2)))
    kind = pick(LOADS)
    f = float(np.round(rng.uniform(50.0, 8000.0), 1)) * pick((1.0, -1.0))
    if kind == "into_stop":
        # a load pushing the nut towards the nearer limit (a negative load pushes +x)
        toward = 1.0 if (stops is not None and stops["max_position_m"] - start < start - stops["min_position_m"]) \
            or (stops is None and start > 0) else -1.0
        f = -toward * abs(f)
    case["load"] = {"kind": kind, "value_n": f if kind != "zero" else 0.0,
                    "period_s": float(np.round(rng.uniform(0.05, 0.4), 3))}
    case["initial_load"] = bool(kind in ("constant", "into_stop") and rng.random() < 0.5)
    if model == "elastic" and rng.random() < 0.5:
        if rng.random() < 0.5:
            case["overrides"]["elastic.axial_clearance_m"] = float(np.round(rng.uniform(1e-6, 5e-5), 7))
        else:
            case["overrides"]["elastic.preload_n"] = float(np.round(rng.uniform(200.0, 3000.0), 1))
            case["overrides"]["elastic.preload_kind"] = pick(("oversize_rollers", "double_nut"))
    case["brake"] = None
    case["faults"] = []
    if interface != "torque":
        if rng.random() < 0.25:
            t1 = float(np.round(rng.uniform(0.1, 0.6) * duration, 4))
            case["brake"] = {"holding_torque_nm": float(np.round(rng.uniform(2.0, 20.0), 2)), "engage_s": t1,
                             "release_s": float(np.round(t1 + rng.uniform(0.05, 0.3) * duration, 4))}
        if rng.random() < 0.35:
            case["faults"] = [_fault(rng, duration, model, case["overrides"])]
    case["reset_at_s"] = float(np.round(rng.uniform(0.3, 0.7) * duration, 4)) if rng.random() < 0.15 else None
    # drawn last, so every other draw of a seed stays what it was before pauses were drawn
    case["pause_at_s"] = float(np.round(rng.uniform(0.1, 0.9) * duration, 4)) if rng.random() < 0.25 else None
    return case


def _fault(rng, duration, model, overrides) -> dict:
    kinds = ["friction_surge", "lubrication_loss", "jam", "sensor_bias", "sensor_noise", "sensor_dropout",
             "sensor_stuck", "torque_limit_drop", "drive_fault"]
    if model == "elastic" and "elastic.preload_n" not in overrides:
        kinds.append("backlash")
    kind = kinds[int(rng.integers(len(kinds)))]
    start = float(np.round(rng.uniform(0.0, 0.6) * duration, 4))
    d = {"kind": kind, "start_s": start, "duration_s": float(np.round(rng.uniform(0.02, 0.5) * duration, 4))}
    value = {"friction_surge": rng.uniform(1.2, 3.0), "lubrication_loss": rng.uniform(1.2, 3.0),
             "jam": rng.uniform(0.1, 3.0), "sensor_bias": rng.uniform(-1e-4, 1e-4),
             "sensor_noise": rng.uniform(0.0, 1e-4), "sensor_dropout": rng.uniform(0.0, 0.5),
             "torque_limit_drop": rng.uniform(0.2, 0.9), "backlash": rng.uniform(1e-5, 2e-4)}.get(kind, 0.0)
    d["value"] = float(np.round(value, 7))
    if kind.startswith("sensor_"):
        d["sensor"] = "motor_encoder"
    return d


@dataclass
class Result:
    """What a case broke (empty: nothing) and a few figures of the run."""

    violations: list[str] = field(default_factory=list)
    steps: int = 0
    max_penetration_m: float = 0.0
    error: str | None = None
    # with run_case(record=True): what was asked of the session, in order (("step", command, load_n),
    # ("brake", engage), ("pause",), ("resume",), ("reset",)), and after each step the true state
    # (screw angle, screw speed, nut position, nut velocity): a replay through another driver (the
    # node in lockstep) must reproduce the states
    actions: list[tuple] | None = None
    states: list[tuple[float, float, float, float]] | None = None

    @property
    def ok(self) -> bool:
        return not self.violations


def session_interface(case: dict) -> str:
    """The Session's command interface of a case (a bare screw takes torque: "effort")."""
    return "effort" if case["interface"] == "torque" else case["interface"]


def initial_load_n(case: dict) -> float | None:
    """The load the case starts pre-deflected at (equilibrium start), or None: at rest, unloaded."""
    return _load(case, 0.0) if case.get("initial_load") else None


def build(case: dict):
    """(Session, the actuator parameters or None, params) for a case; the gate's effort limit is the
    loop's own torque limit, so the gate passes every command the controller gives unchanged."""
    p = preset(case.get("preset", "s30"))
    if case.get("overrides"):
        p = p.with_overrides(case["overrides"])
    act = None
    if case["interface"] != "torque":
        stops = StopParams(**case["stops"]) if case.get("stops") else StopParams()
        b = case.get("brake")
        brake = BrakeParams(holding_torque_nm=b["holding_torque_nm"]) if b else BrakeParams()
        act = ActuatorParams(motor=MotorParams(), drive=DriveParams(mode=case["interface"]), stops=stops, brake=brake,
                             faults=tuple(Fault(**f) for f in case.get("faults", ())))
    session = Session.from_config(SessionConfig(
        params=p, model=case["model"], dt_s=case["dt_s"], actuator=act, nut_position_m=case["start_m"],
        initial_load_n=initial_load_n(case), interface=session_interface(case), max_effort_nm=TORQUE_LIMIT_NM))
    return session, act, p


def _load(case: dict, t: float) -> float:
    ld = case["load"]
    kind, f, period = ld["kind"], ld["value_n"], ld["period_s"]
    if kind in ("zero",):
        return 0.0
    if kind in ("constant", "into_stop"):
        return f
    if kind == "steps":  # 0 → F → F/2 → F …
        k = int(t / period) % 3
        return (0.0, f, 0.5 * f)[k]
    return f if int(t / period) % 2 == 0 else -f  # square: sign changes


class _Controller:
    """The outer loop a case closes, in the active interface's unit."""

    def __init__(self, case: dict, p, dt: float) -> None:
        self.case, self.dt = case, dt
        self.p = p.geometry.lead_per_rad_m
        self.pid = PositionController(inertia_kgm2=reflected_inertia(p), lead_per_rad_m=self.p,
                                      max_torque_nm=TORQUE_LIMIT_NM)
        self.flip = 1.0

    def reference(self, t: float) -> tuple[float, float, float]:
        c = self.case
        if c["controller"] == "sine":
            w = 2 * math.pi * c["frequency_hz"]
            a = c["amplitude_m"]
            return c["start_m"] + a * math.sin(w * t), a * w * math.cos(w * t), -a * w * w * math.sin(w * t)
        return c["target_m"], 0.0, 0.0

    def command(self, t: float, x: float, v: float, load_n: float) -> float:
        c, p = self.case, self.p
        iface = c["interface"]
        if c["controller"] == "bangbang":
            # reversals at full effort between start ± amplitude
            if x > c["start_m"] + c["amplitude_m"]:
                self.flip = -1.0
            elif x < c["start_m"] - c["amplitude_m"]:
                self.flip = 1.0
            if iface in ("torque", "effort"):
                return self.flip * TORQUE_LIMIT_NM
            if iface == "velocity":
                return self.flip * 300.0
            return c["start_m"] + self.flip * c["amplitude_m"] * 1.2
        xr, vr, ar = self.reference(t)
        if iface == "position":
            return xr
        if iface == "velocity":
            return max(-300.0, min(300.0, (vr + 20.0 * (xr - x)) / p))
        self.pid.load_n = load_n
        return self.pid.torque(xr - x, vr - v, ar, self.dt)


def run_case(case: dict, record: bool = False) -> Result:
    """Run one case and check the envelope's invariants (module doc); never raises. `record`:
    keep the session's actions and the states they gave (`Result.actions`, `Result.states`)."""
    res = Result(actions=[] if record else None, states=[] if record else None)
    try:
        _run(case, res)
    except Exception as e:  # a valid closed loop must not raise: that is itself the finding
        res.error = f"{type(e).__name__}: {e}"
        res.violations.append(f"raised {res.error}")
    return res


def _run(case: dict, res: Result) -> None:
    session, act, p = build(case)
    sim = session.simulator
    dt = sim.dt_s
    actions = res.actions if res.actions is not None else _Discard()
    n = int(round(case["duration_s"] / dt))
    ctl = _Controller(case, p, dt)
    geo = p.geometry
    travel = geo.travel_m
    pl = geo.lead_per_rad_m
    limits = sim.model.limits if act is not None else sim._limits
    k_stop = limits[0].stiffness_n_m if limits else 1e8
    brake = case.get("brake")
    reset_at = case.get("reset_at_s")
    pause_at = case.get("pause_at_s")
    elastic = case["model"] == "elastic"
    tail = max(1, int(round(0.5 / dt)))
    hist_w, hist_cmd, hist_contact, hist_load, hist_v = [], [], [], [], []
    # times at which what the plant sees changes besides the command and the load: faults start and end
    events = sorted({t for fd in case.get("faults", ()) for t in (fd["start_s"], fd["start_s"] + fd["duration_s"])})
    last_event = -math.inf

    def nut(out):
        return out.nut_position_m

    def contact_of(x):
        for lim in limits:
            d = lim.sign * (x - lim.position_m)
            if d > 0.0:
                return d
        return 0.0

    def initial():  # nut position and stored energy of the (initial or reset) state
        st = sim.state
        screw = st.screw if act is not None else st
        x0 = screw.nut_axial_m if elastic else pl * screw.screw_angle_rad
        e0 = sim.model.stored_energy(st) if act is not None else sim.model.total_stored_energy_j(st)
        return x0, e0

    out = None
    x_prev, stored_prev = initial()
    stored0 = stored_prev
    v_prev = 0.0
    energy_in_prev = load_work_prev = 0.0
    w_contact = None  # energy available since first contact
    t_offset = 0.0
    engaged = released = did_reset = did_pause = False
    for i in range(n):
        t = sim.time_s + t_offset
        if pause_at is not None and not did_pause and t >= pause_at:
            did_pause = True
            session = _pause_and_continue(case, session, actions, res)
            sim = session.simulator
            if res.violations:
                return
        if reset_at is not None and not did_reset and t >= reset_at:
            did_reset = True
            t_offset = t
            session.reset()
            actions.append(("reset",))
            out, w_contact = None, None
            hist_w.clear(), hist_cmd.clear(), hist_contact.clear(), hist_load.clear(), hist_v.clear()
            x_prev, stored_prev = initial()
            stored0 = stored_prev
            v_prev, energy_in_prev, load_work_prev = 0.0, 0.0, 0.0
            ctl = _Controller(case, p, dt)
            engaged = released = False
            t = t_offset
        if brake and act is not None:
            # a refused request (e.g. release while a drive fault holds the torque off) is the library's answer
            if not engaged and t >= brake["engage_s"]:
                engaged, last_event = True, t
                session.brake(True)
                actions.append(("brake", True))
            elif engaged and not released and t >= brake["release_s"]:
                released, last_event = True, t
                session.brake(False)
                actions.append(("brake", False))
        f = _load(case, t - (t_offset if did_reset else 0.0))
        cmd = ctl.command(t, x_prev, v_prev, f)
        while events and events[0] <= sim.time_s:
            last_event = max(last_event, events.pop(0) + t_offset)
        out = session.step(float(cmd), f)
        actions.append(("step", float(cmd), f))
        res.steps += 1
        x, v = nut(out), out.nut_velocity_m_s
        if res.states is not None:
            res.states.append((out.screw_angle_rad, out.screw_speed_rad_s, x, v))
        scal = (out.screw_angle_rad, out.screw_speed_rad_s, out.carrier_speed_rad_s, x, v, out.nut_force_n,
                out.energy_residual_j)
        if not all(math.isfinite(q) for q in scal):
            res.violations.append(f"non-finite state at t = {t:.4f} s")
            return
        if out.energy_fault:
            res.violations.append(f"energy guard tripped at t = {t:.4f} s (residual {out.energy_residual_j:.3g} J "
                                  f"of {out.energy_flow_j:.3g} J)")
            return
        if act is not None:
            blk = sim.layout.view(out.internal, "actuator")
            e_in, load_work, diss, stored = (float(blk[_Q[q]]) for q in ("energy_in_j", "load_work_j", "dissipated_j",
                                                                         "stored_j"))
            miss = e_in - load_work - diss - (stored - stored0)
            scale = abs(e_in) + abs(load_work) + abs(diss)
            if scale > ENERGY_GUARD_MIN_FLOW_J and abs(miss) > ENERGY_GUARD_REL * scale:  # the guard's own rule
                res.violations.append(f"actuator ledger misses {miss:.3g} J of {scale:.3g} J at t = {t:.4f} s")
                return
            stop_f = float(blk[_Q["stop_force_n"]])
        else:
            stored = out.stored_energy_j
            # work of the screw torque and of the external load over the step
            e_in = energy_in_prev + out.power_in_w * dt
            load_work = load_work_prev + f * (x - x_prev)
            stop_f = session.simulator.thread_end_force_n
        delta = contact_of(x)
        res.max_penetration_m = max(res.max_penetration_m, delta)
        if delta > 0.0:
            if w_contact is None:  # first contact: what was stored just before it
                w_contact = stored_prev - energy_in_prev + load_work_prev
            w = w_contact + e_in - load_work
            if 0.5 * k_stop * delta * delta > w * (1 + 1e-6) + 1e-9:
                res.violations.append(f"impact past the work: ½kδ² = {0.5 * k_stop * delta * delta:.4g} J > W = "
                                      f"{w:.4g} J at t = {t:.4f} s (δ = {delta * 1e6:.2f} µm)")
                return
        else:
            w_contact = None
        if travel is not None and abs(x) > 0.5 * travel + 0.5 * geo.nut_length_m:
            res.violations.append(f"the nut left its threads: x = {x:.5f} m at t = {t:.4f} s")
            return
        hist_w.append(out.screw_speed_rad_s)
        hist_cmd.append(cmd)
        hist_contact.append(delta)
        hist_load.append(f)
        hist_v.append(v)
        x_prev, v_prev, stored_prev = x, v, stored
        energy_in_prev, load_work_prev = e_in, load_work
    if out is None:
        return
    # rest against a stop at the end: δ within the static deflection of the net force + 2 µm
    last = int(round(0.1 / dt))
    # (screw and nut: an elastic nut can still ring on its chain while the screw is held)
    if len(hist_w) >= last and max(abs(w) for w in hist_w[-last:]) < 1e-3 \
            and max(abs(q) for q in hist_v[-last:]) < 1e-6 and hist_contact[-1] > 0.0:
        f = _load(case, sim.time_s)
        net = abs(f - out.nut_force_n)
        if hist_contact[-1] > net / k_stop + REST_SLACK_M:
            res.violations.append(f"at rest {hist_contact[-1] * 1e6:.2f} µm into the stop, the net force "
                                  f"{net:.1f} N deflects it {net / k_stop * 1e6:.2f} µm (stop force {stop_f:.1f} N)")
    # held against a stop under a constant command: no ringing
    # (and nothing else changed: no brake command, fault start or end in that time; the impact that brought
    # it there SETTLE_S or more before the window, so what is judged is a hold, not an impact's decay)
    settle = int(round(SETTLE_S / dt))
    if len(hist_w) >= tail + settle and min(hist_contact[-tail - settle:]) > 0.0 and len(set(hist_cmd[-tail:])) == 1 \
            and len(set(hist_load[-tail:])) == 1 and last_event <= sim.time_s + t_offset - tail * dt - 0.1:
        ptp = max(hist_w[-tail:]) - min(hist_w[-tail:])
        # ringing reverses the screw and lasts: swings of a quarter of the limit either way still there in
        # the window's last 0.1 s. A one-way creep (the speed loop's integral pressing the nut further in)
        # and the decaying ring when the torque limit then halts it are the controller's physics
        last = hist_w[-max(2, int(round(0.1 / dt))):]
        w = [q for q in last if abs(q) >= 0.25 * P2P_LIMIT_RAD_S]
        reversals = sum(1 for a, b in zip(w, w[1:]) if a * b < 0.0)
        if ptp >= P2P_LIMIT_RAD_S and reversals >= 2:
            res.violations.append(f"screw speed rings {ptp:.3f} rad/s peak to peak against a stop "
                                  "under a constant command")


class _Discard(list):
    """The action list of a run that keeps none."""

    def append(self, item) -> None:
        pass


def _pause_and_continue(case: dict, session: Session, actions, res: Result) -> Session:
    """Pause as a node's user does: time stands still, the state is saved and restored into a fresh
    session built from the case (what a paused node's state could be carried to), then resume.
    Returns the session the run goes on with; a pause that moved time or lost state is a violation."""
    session.pause()
    actions.append(("pause",))
    t, k = session.time_s, session.nstep
    saved = session.get_state()
    fresh, _, _ = build(case)
    fresh.set_state(saved)
    same = json.dumps(fresh.get_state(), sort_keys=True) == json.dumps(saved, sort_keys=True)  # NaN == NaN here
    if not (fresh.paused and fresh.time_s == t and fresh.nstep == k and same):
        res.violations.append(f"a pause at t = {t:.4f} s did not keep the state (restored at t = {fresh.time_s:.4f} s, "
                              f"step {fresh.nstep} of {k})")
    fresh.resume()
    actions.append(("resume",))
    return fresh
