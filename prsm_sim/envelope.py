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
- the second law, step by step: what friction, contacts and the scheme have dissipated never falls
  (by more than SECOND_LAW_TOL of the energy that has flowed, and SECOND_LAW_FLOOR_J): a books-closing step
  can still create energy by booking it as negative dissipation;
- an impact goes no further past a stop or thread end than the work allows: ½ k δ² ≤ W, W the
  energy stored at first contact plus the work of the drive and the load since;
- at rest against a stop, δ lies within the static deflection of the net force pressing the nut
  (load less what the threads carry) + 2 µm; the nut never leaves its threads;
- with a constant command and the nut held against a stop, the screw does not ring: its speed
  varies by less than 0.5 rad/s peak to peak over the last 0.5 s, or no longer swings both ways
  in the last 0.1 s (an integral action pressing the nut further in, and the decaying ring when
  the torque limit halts it, are the controller's physics), or decays at least at half the rate
  c/(2m) the stop's damping gives the nut's reflected mass (the contact's own mode), or is the closed
  loop's own: the drive's sampled loop does not settle even on the free inertia (its poles on or
  outside the unit circle), or the same case at a step ten times shorter, the drive's loop rate
  kept, rings alike.

Pure (no I/O): the envelope command (`prsm-sim envelope`) spreads cases over Ray and writes the
failing ones; tests/test_envelope.py draws them with hypothesis.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from prsm_sim.actuator import (
    ACTUATOR_QUANTITIES,
    ActuatorParams,
    BrakeParams,
    DriveParams,
    Fault,
    MotorParams,
    StopParams,
)
from prsm_sim.actuator.stops import stop_stored_j
from prsm_sim.control import PositionController
from prsm_sim.errors import DriveLoopWarning
from prsm_sim.models.registry import MODELS as REGISTERED_MODELS
from prsm_sim.models.registry import model_class
from prsm_sim.physics.inertia import reflected_inertia
from prsm_sim.presets import preset
from prsm_sim.session import Session, SessionConfig
from prsm_sim.stepping.ledger import ENERGY_GUARD_MIN_FLOW_J, ENERGY_GUARD_REL
from prsm_sim.stepping.records import Outputs

MODELS = tuple(REGISTERED_MODELS)  # drawn in the registry's order
INTERFACES = ("torque", "effort", "velocity", "position")
CONTROLLERS = ("hold", "sine", "bangbang", "impact")
LOADS = ("zero", "constant", "steps", "square", "into_stop", "step")
REST_SLACK_M = 2e-6  # rest penetration beyond the static deflection allowed (the invariant's 2 µm)
P2P_LIMIT_RAD_S = 0.5
SETTLE_S = 0.1  # an impact's decay before a hold is judged
# a ring held at a step this many times shorter (the drive's loop rate kept) with a peak to peak within this share
# of the case's is the closed loop's own (`_Run._rings_alike_when_resolved`): a limit cycle of the loop changed by
# 4 % over that decade of steps (seed 46302, 5.7 to 0.57 ms), the step's own rings by all of it (seeds 1602, 4574,
# 5563 on the exact contact step: 36-268 rad/s at 14-33 ms, none at a tenth of it)
RESOLVE_FACTOR = 10
RING_AGREEMENT = 0.25
TORQUE_LIMIT_NM = 10.0  # the default motor's, also the bare loop's clamp
MOTOR_SPEED_RAD_S = 500.0  # the default motor's speed limit: the fastest a free impact is driven to
# step rates drawn log-uniform, whole hertz (the node's update_rate): dt_s from 1e-5 s to 0.1 s, the largest
# step a model accepts (`Model.__init__`)
RATE_HZ = (10.0, 1e5)
MAX_STEPS = 2000  # screw-model steps per case (drive sub-steps counted): small steps mean shorter runs
MAX_CLEARANCE_M = 2.5e-4  # clearances drawn log-uniform up to this (the 200 µm and past it)
LOAD_MIN_N = 50.0  # loads drawn log-uniform from this to the screw's static rating C₀a
# a step's dissipation may fall by rounding only: sums of ~1e4 terms of the flow's size carry ~1e-12 of it
SECOND_LAW_TOL = 1e-9
SECOND_LAW_FLOOR_J = 1e-9
DATASHEET_SHARE = 0.25  # cases on a datasheet-built screw instead of the s30 preset
_Q = {n: i for i, (n, _) in enumerate(ACTUATOR_QUANTITIES)}
_BOOKS_AT = tuple(_Q[q] for q in ("energy_in_j", "load_work_j", "dissipated_j", "stored_j"))  # what `_books` reads


def case_from_seed(seed: int) -> dict:
    """One envelope case drawn from `seed` (numpy's generator: the same seed, the same case)."""
    return draw_case(np.random.default_rng(int(seed)), int(seed))


def draw_case(rng, seed: int | None = None) -> dict:
    """One envelope case drawn by `rng`: anything with numpy's Generator methods `choice(n, p=None)`,
    `uniform(lo, hi)`, `random()` and `integers(n)` (a test passes hypothesis' draws through them).

    The draws come in a fixed order (plant, step and loop, the screw, start and stops, load, elastic
    preload or clearance, the drive's loop rate, then brake, faults, reset and pause), so a seed keeps
    its case."""
    model = _pick(rng, MODELS)
    rate_hz = float(round(math.exp(rng.uniform(math.log(RATE_HZ[0]), math.log(RATE_HZ[1])))))
    dt = 1.0 / rate_hz
    interface = _pick(rng, INTERFACES)
    controller = _pick(rng, CONTROLLERS)
    # long enough for a hold to be judged (0.5 s + settling), short elsewhere; at most MAX_STEPS steps
    lo, hi = (0.62, 0.7) if controller in ("hold", "impact") else (0.2, 0.5)
    duration = float(np.round(rng.uniform(lo, hi), 3))
    case = {"seed": seed, "preset": "s30", "model": model, "dt_s": dt, "duration_s": duration,
            "interface": interface, "controller": controller, "overrides": {}}
    _draw_screw(rng, case)
    _draw_start(rng, case)
    _draw_load(rng, case)
    _draw_chain(rng, case)
    _draw_drive(rng, case)
    case["duration_s"] = _bounded_duration(case)
    _draw_events(rng, case)
    return case


def _pick(rng, options, p=None):
    return options[int(rng.choice(len(options), p=p))]


def _log_uniform(rng, lo: float, hi: float) -> float:
    return math.exp(rng.uniform(math.log(lo), math.log(hi)))


def case_params(case: dict):
    """The parameter set of a case: its preset with its overrides."""
    p = preset(case.get("preset", "s30"))
    return p.with_overrides(case["overrides"]) if case.get("overrides") else p


def _draw_screw(rng, case: dict) -> None:
    """The s30 preset, or (DATASHEET_SHARE of cases) a screw built from a drawn catalogue row
    (`prsm_sim.datasheet`: another diameter, lead and start count) on it, written into the case as the
    overrides that make it (what the node takes as `physics.*` parameters)."""
    if rng.random() >= DATASHEET_SHARE:
        return
    from prsm_sim.datasheet import Datasheet, params_from_datasheet
    starts = int(_pick(rng, (3, 4, 5, 6)))
    pitch = float(_pick(rng, (5e-4, 1e-3, 1.5e-3, 2e-3, 3e-3)))
    row = Datasheet(nominal_diameter_m=float(np.round(rng.uniform(0.012, 0.08), 3)), lead_m=round(starts * pitch, 6),
                    starts=starts)
    base = preset(case["preset"])
    built, _ = params_from_datasheet(row, base)
    mine, theirs = built.to_dict(), base.to_dict()
    case["datasheet"] = row.to_dict()
    case["overrides"].update({f"{g}.{k}": v for g, group in mine.items() if isinstance(group, dict)
                              for k, v in group.items() if theirs[g].get(k) != v})


def _draw_start(rng, case: dict) -> None:
    """Where the nut starts and what it is asked: near the middle, near a stop (with the stops), or near a
    thread end; whether the thread ends are fitted; the target, amplitude and frequency of the loop; for an
    impact, the limit it is driven at and the screw speed it coasts (effort) or is driven (velocity) on at."""
    g = case_params(case).geometry
    half = 0.5 * (g.screw_length_m - g.nut_length_m)  # the travel on the threads
    impact = case["controller"] == "impact"
    near = _pick(rng, ("stop", "end")) if impact else _pick(rng, ("middle", "stop", "end"))
    start = float(np.round(rng.uniform(-0.01, 0.01), 5))
    stops = None
    # an impact's run-up: up to a fifth of the travel (a back-driven nut, a coasting one)
    run_up = float(np.round(_log_uniform(rng, 2e-4, 0.2 * half), 6)) if impact else 0.0
    if near == "stop" and case["interface"] != "torque":
        gap = run_up if impact else float(np.round(rng.uniform(2e-4, 5e-3), 5))
        sgn = _pick(rng, (1.0, -1.0))
        stops = {"min_position_m": start - 0.05, "max_position_m": start + gap} if sgn > 0 else \
                {"min_position_m": start - gap, "max_position_m": start + 0.05}
        stops.update(stiffness_n_m=float(_pick(rng, (1e7, 1e8, 1e9))), damping_n_s_m=float(_pick(rng, (0.0, 2e4, 2e5))))
        toward = sgn
    else:
        toward = _pick(rng, (1.0, -1.0))
        start = float(np.round(toward * (half - (run_up if impact else rng.uniform(2e-4, 5e-3))), 6)) \
            if near == "end" or impact else start
    case["start_m"] = start
    case["stops"] = stops
    case["thread_ends"] = bool(impact or rng.random() < 0.9)
    if not case["thread_ends"]:
        case["overrides"]["geometry.thread_ends"] = False
    amplitude = float(np.round(rng.uniform(5e-4, 8e-3), 5))
    case.update(target_m=float(np.round(start + rng.uniform(-1, 1) * amplitude, 6)), amplitude_m=amplitude,
                frequency_hz=float(np.round(rng.uniform(0.5, 8.0), 2)))
    if impact:
        limit = (stops["max_position_m"] if toward > 0 else stops["min_position_m"]) if stops else toward * half
        case["impact"] = {"direction": toward, "speed_rad_s": float(np.round(rng.uniform(0.05, 1.0)
                                                                             * MOTOR_SPEED_RAD_S, 2))}
        case["target_m"] = float(np.round(limit + toward * 1e-3, 6))  # the position loop asked past the limit


def _draw_load(rng, case: dict) -> None:
    """The load's kind, value (log-uniform up to the screw's static rating) and period, and whether the
    start is in equilibrium under it."""
    kind = _pick(rng, LOADS)
    c0 = case_params(case).ratings.static_load_rating_n
    f = float(np.round(_log_uniform(rng, LOAD_MIN_N, c0), 1)) * _pick(rng, (1.0, -1.0))
    if kind == "into_stop":
        # a load pushing the nut towards the nearer limit (a negative load pushes +x)
        start, stops = case["start_m"], case["stops"]
        toward = 1.0 if (stops is not None and stops["max_position_m"] - start < start - stops["min_position_m"]) \
            or (stops is None and start > 0) else -1.0
        f = -toward * abs(f)
    case["load"] = {"kind": kind, "value_n": f if kind != "zero" else 0.0,
                    "period_s": float(np.round(rng.uniform(0.05, 0.4), 3))}
    case["initial_load"] = bool(kind in ("constant", "into_stop") and rng.random() < 0.5)


def _draw_chain(rng, case: dict) -> None:
    """On an axial chain: a clearance (log-uniform to MAX_CLEARANCE_M) or a preload, the preload's load
    drawn anew about it half the time (from half to six times the preload: past about 2.8 times a flank
    unloads)."""
    if not (model_class(case["model"]).has_axial_chain and rng.random() < 0.5):
        return
    ov = case["overrides"]
    if rng.random() < 0.5:
        ov["elastic.axial_clearance_m"] = float(np.round(_log_uniform(rng, 1e-6, MAX_CLEARANCE_M), 7))
        return
    p = case_params(case)
    c0 = p.ratings.static_load_rating_n
    preload = float(np.round(_log_uniform(rng, 200.0, 0.1 * c0), 1))
    ov["elastic.preload_n"] = preload
    kind = _pick(rng, ("oversize_rollers", "double_nut"))
    # two halves of N_T/2 rows: a double nut needs an even n_teeth (a datasheet screw may have an odd one)
    ov["elastic.preload_kind"] = kind if kind != "double_nut" or p.geometry.n_teeth % 2 == 0 else "oversize_rollers"
    if rng.random() < 0.5 and case["load"]["kind"] != "zero":
        ld = case["load"]
        ld["value_n"] = float(np.round(math.copysign(preload * rng.uniform(0.5, 6.0), ld["value_n"]), 1))


def _draw_drive(rng, case: dict) -> None:
    """The drive's loop rate (an actuator, a third of the cases): a whole ratio of the step rate, up to five
    updates a step or one every five steps (`drive.loop_schedule` sub-steps or holds by it)."""
    case["loop_rate_hz"] = None
    if case["interface"] == "torque" or rng.random() >= 1 / 3:
        return
    k = int(_pick(rng, (2, 3, 4, 5)))
    rate = 1.0 / case["dt_s"]
    case["loop_rate_hz"] = rate * k if rng.random() < 0.5 else rate / k


def _bounded_duration(case: dict) -> float:
    """The drawn duration, cut to MAX_STEPS screw-model steps (drive sub-steps counted)."""
    dt, lr = case["dt_s"], case.get("loop_rate_hz")
    n_sub = max(1, round(lr * dt)) if lr else 1
    steps = min(int(round(case["duration_s"] / dt)), max(1, MAX_STEPS // n_sub))
    return float(steps * dt)


def _draw_events(rng, case: dict) -> None:
    """Brake engage/release and a fault (with an actuator), a reset and a pause mid-run."""
    duration = case["duration_s"]
    case["brake"] = None
    case["faults"] = []
    if case["interface"] != "torque":
        if rng.random() < 0.25:
            t1 = float(np.round(rng.uniform(0.1, 0.6) * duration, 6))
            case["brake"] = {"holding_torque_nm": float(np.round(rng.uniform(2.0, 20.0), 2)), "engage_s": t1,
                             "release_s": float(np.round(t1 + rng.uniform(0.05, 0.3) * duration, 6))}
        if rng.random() < 0.35:
            case["faults"] = [_fault(rng, duration, case["model"], case["overrides"])]
    case["reset_at_s"] = float(np.round(rng.uniform(0.3, 0.7) * duration, 6)) if rng.random() < 0.15 else None
    # drawn last, so every other draw of a seed stays what it was before pauses were drawn
    case["pause_at_s"] = float(np.round(rng.uniform(0.1, 0.9) * duration, 6)) if rng.random() < 0.25 else None


def _fault(rng, duration, model, overrides) -> dict:
    kinds = ["friction_surge", "lubrication_loss", "jam", "sensor_bias", "sensor_noise", "sensor_dropout",
             "sensor_stuck", "torque_limit_drop", "drive_fault"]
    if model_class(model).has_axial_chain and "elastic.preload_n" not in overrides:
        kinds.append("backlash")
    kind = kinds[int(rng.integers(len(kinds)))]
    start = float(np.round(rng.uniform(0.0, 0.6) * duration, 6))
    d = {"kind": kind, "start_s": start, "duration_s": float(np.round(rng.uniform(0.02, 0.5) * duration, 6))}
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


def resolved_case(case: dict) -> dict:
    """The case at a step RESOLVE_FACTOR or more times shorter that keeps the drive's loop period T (the step's
    own where the case sets none) a whole number of steps, T / ⌈RESOLVE_FACTOR T / dt⌉; times (duration,
    events) are kept, so the resolved run has that many more steps."""
    dt, rate = case["dt_s"], case.get("loop_rate_hz")
    period = 1.0 / rate if rate else dt
    n = math.ceil(RESOLVE_FACTOR * period / dt - 1e-9)
    return dict(case, dt_s=period / n, loop_rate_hz=1.0 / period)


def session_interface(case: dict) -> str:
    """The Session's command interface of a case (a bare screw takes torque: "effort")."""
    return "effort" if case["interface"] == "torque" else case["interface"]


def initial_load_n(case: dict) -> float | None:
    """The load the case starts pre-deflected at (equilibrium start), or None: at rest, unloaded."""
    return _load(case, 0.0) if case.get("initial_load") else None


def build(case: dict):
    """(Session, the actuator parameters or None, params) for a case; the gate's effort limit is the
    loop's own torque limit, so the gate passes every command the controller gives unchanged."""
    p = case_params(case)
    act = None
    if case["interface"] != "torque":
        stops = StopParams(**case["stops"]) if case.get("stops") else StopParams()
        b = case.get("brake")
        brake = BrakeParams(holding_torque_nm=b["holding_torque_nm"]) if b else BrakeParams()
        drive = DriveParams(mode=case["interface"], loop_rate_hz=case.get("loop_rate_hz"))
        act = ActuatorParams(motor=MotorParams(), drive=drive, stops=stops, brake=brake,
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
    if kind == "step":  # a load step at period_s
        return f if t >= period else 0.0
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
        self.coasting = False

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
        if c["controller"] == "impact":
            return self._impact(iface, v)
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

    def _impact(self, iface: str, v: float) -> float:
        """Onto the limit: the position loop asked past it, the speed loop at the impact speed, or full
        effort until the screw turns at the impact speed and then none (a free impact)."""
        imp = self.case["impact"]
        d, w_hit = imp["direction"], imp["speed_rad_s"]
        if iface == "position":
            return self.case["target_m"]
        if iface == "velocity":
            return d * w_hit
        self.coasting = self.coasting or d * v / self.p >= w_hit
        return 0.0 if self.coasting else d * TORQUE_LIMIT_NM


def run_case(case: dict, record: bool = False) -> Result:
    """Run one case and check the envelope's invariants (module doc); never raises. `record`:
    keep the session's actions and the states they gave (`Result.actions`, `Result.states`)."""
    res = Result(actions=[] if record else None, states=[] if record else None)
    try:
        with warnings.catch_warnings():
            # the draws include drive loops past their Jury bound on purpose, judged here (`_loop_rings_by_itself`)
            warnings.simplefilter("ignore", DriveLoopWarning)
            _run(case, res)
    except Exception as e:  # a valid closed loop must not raise: that is itself the finding
        res.error = f"{type(e).__name__}: {e}"
        res.violations.append(f"raised {res.error}")
    return res


def _run(case: dict, res: Result) -> None:
    run = _Run(case, res)
    if run.loop():
        run.check_rest()
        run.check_ringing()


class _Run:
    """One case's closed loop and the invariants it is checked against, step by step (`loop`) and at
    its end (`check_rest`, `check_ringing`). `step_checks` return False at the first violation, which
    ends the run."""

    def __init__(self, case: dict, res: Result, resolved: bool = False) -> None:
        self.case, self.res = case, res
        self.resolved = resolved  # the run of `_rings_alike_when_resolved`: its rings are not refined again
        self.session, self.act, self.p = build(case)
        self.sim = self.session.simulator
        self.dt = self.sim.dt_s
        self.actions = res.actions if res.actions is not None else _Discard()
        geo = self.p.geometry
        self.travel, self.nut_length = geo.travel_m, geo.nut_length_m
        self.limits = self.sim.limits
        self.k_stop = self.limits[0].stiffness_n_m if self.limits else 1e8
        self.tail = max(1, int(round(0.5 / self.dt)))
        # times at which what the plant sees changes besides the command and the load: faults start and end
        self.events = sorted({t for fd in case.get("faults", ()) for t in (fd["start_s"],
                                                                           fd["start_s"] + fd["duration_s"])})
        self.last_event = -math.inf
        self.t_offset = 0.0
        self.did_reset = self.did_pause = False
        self.out: Outputs | None = None
        self._start()

    def _start(self) -> None:
        """The loop's memory at the (initial or reset) start: the nut's position, the stored energy, no history."""
        self.hist_w: list[float] = []
        self.hist_cmd: list[float] = []
        self.hist_contact: list[float] = []
        self.hist_load: list[float] = []
        self.hist_v: list[float] = []
        st = self.sim.state
        model = self.sim.model
        if self.act is not None:
            self.x_prev, self.stored_prev = model.nut_position_m(st), model.stored_energy(st)
        else:
            self.x_prev, self.stored_prev = model.nut_motion(st)[0], model.total_stored_energy_j(st)
        self.stored0 = self.stored_prev
        self.v_prev = self.energy_in_prev = self.load_work_prev = 0.0
        self.diss_prev = 0.0 if self.act is None else st.ledger.dissipated_j(
            st.screw.dissipated_j, stop_stored_j(self.limits, model.nut_position_m(st)))
        self.w_contact: float | None = None  # energy available since first contact
        self.ctl = _Controller(self.case, self.p, self.dt)
        self.engaged = self.released = False

    @property
    def last(self) -> Outputs:
        """The last step's outputs (the end checks run only after a step)."""
        assert self.out is not None  # `loop` returns False when no step was taken
        return self.out

    def contact_of(self, x: float) -> float:
        for lim in self.limits:
            d = lim.sign * (x - lim.position_m)
            if d > 0.0:
                return d
        return 0.0

    def loop(self) -> bool:
        """The closed loop over the case's duration; False when it stopped at a violation."""
        case, n = self.case, int(round(self.case["duration_s"] / self.dt))
        pause_at, reset_at = case.get("pause_at_s"), case.get("reset_at_s")
        for _ in range(n):
            t = self.sim.time_s + self.t_offset
            if pause_at is not None and not self.did_pause and t >= pause_at:
                self.did_pause = True
                self.session = _pause_and_continue(case, self.session, self.actions, self.res)
                self.sim = self.session.simulator
                if self.res.violations:
                    return False
            if reset_at is not None and not self.did_reset and t >= reset_at:
                t = self._reset(t)
            self._brake(t)
            f = _load(case, t - (self.t_offset if self.did_reset else 0.0))
            cmd = self.ctl.command(t, self.x_prev, self.v_prev, f)
            while self.events and self.events[0] <= self.sim.time_s:
                self.last_event = max(self.last_event, self.events.pop(0) + self.t_offset)
            out = self.out = self.session.step(float(cmd), f)
            self.actions.append(("step", float(cmd), f))
            self.res.steps += 1
            if not self.step_checks(out, t, cmd, f):
                return False
        return self.out is not None

    def _reset(self, t: float) -> float:
        self.did_reset = True
        self.t_offset = t
        self.session.reset()
        self.actions.append(("reset",))
        self.out = None
        self._start()
        return self.t_offset

    def _brake(self, t: float) -> None:
        # a refused request (e.g. release while a drive fault holds the torque off) is the library's answer
        brake = self.case.get("brake")
        if not (brake and self.act is not None):
            return
        if not self.engaged and t >= brake["engage_s"]:
            self.engaged, self.last_event = True, t
            self.session.brake(True)
            self.actions.append(("brake", True))
        elif self.engaged and not self.released and t >= brake["release_s"]:
            self.released, self.last_event = True, t
            self.session.brake(False)
            self.actions.append(("brake", False))

    def step_checks(self, out, t: float, cmd: float, f: float) -> bool:
        """A step's invariants: finite, the energy guard and the actuator's ledger, an impact within the
        work, the nut on its threads; then the history the end checks read. False at a violation."""
        res = self.res
        x, v = out.nut_position_m, out.nut_velocity_m_s
        if res.states is not None:
            res.states.append((out.screw_angle_rad, out.screw_speed_rad_s, x, v))
        fin = math.isfinite
        if not (fin(out.screw_angle_rad) and fin(out.screw_speed_rad_s) and fin(out.carrier_speed_rad_s) and fin(x)
                and fin(v) and fin(out.nut_force_n) and fin(out.energy_residual_j)):
            res.violations.append(f"non-finite state at t = {t:.4f} s")
            return False
        if out.energy_fault:
            res.violations.append(f"energy guard tripped at t = {t:.4f} s (residual {out.energy_residual_j:.3g} J "
                                  f"of {out.energy_flow_j:.3g} J)")
            return False
        books = self._books(out, t, x, f)
        if books is None:
            return False
        e_in, load_work, stored = books
        delta = self.contact_of(x)
        res.max_penetration_m = max(res.max_penetration_m, delta)
        if not self._impact_within_work(delta, e_in, load_work, t):
            return False
        if self.travel is not None and abs(x) > 0.5 * self.travel + 0.5 * self.nut_length:
            res.violations.append(f"the nut left its threads: x = {x:.5f} m at t = {t:.4f} s")
            return False
        self.hist_w.append(out.screw_speed_rad_s)
        self.hist_cmd.append(cmd)
        self.hist_contact.append(delta)
        self.hist_load.append(f)
        self.hist_v.append(v)
        self.x_prev, self.v_prev, self.stored_prev = x, v, stored
        self.energy_in_prev, self.load_work_prev = e_in, load_work
        return True

    def _books(self, out, t: float, x: float, f: float) -> tuple[float, float, float] | None:
        """(energy in, load work, stored energy) so far, J; None (a violation) when the actuator's ledger
        misses more than the energy guard allows."""
        if self.act is None:
            # work of the screw torque and of the external load over the step
            e_in, load_work = self.energy_in_prev + out.power_in_w * self.dt, self.load_work_prev + f * (x - self.x_prev)
            if not self._second_law(out.power_dissipated_w * self.dt, abs(e_in) + abs(load_work), t):
                return None
            return e_in, load_work, out.stored_energy_j
        at = self.sim.model.block_at  # the actuator's block in the internal vector
        e_in, load_work, diss, stored = out.internal[[at + i for i in _BOOKS_AT]].tolist()
        miss = e_in - load_work - diss - (stored - self.stored0)
        scale = abs(e_in) + abs(load_work) + abs(diss)
        if scale > ENERGY_GUARD_MIN_FLOW_J and abs(miss) > ENERGY_GUARD_REL * scale:  # the guard's own rule
            self.res.violations.append(f"actuator ledger misses {miss:.3g} J of {scale:.3g} J at t = {t:.4f} s")
            return None
        if not self._second_law(diss - self.diss_prev, scale, t):
            return None
        self.diss_prev = diss
        return e_in, load_work, stored

    def _second_law(self, dissipated_j: float, flow_j: float, t: float) -> bool:
        """A step's dissipation (J) is not negative beyond rounding of the flow so far (`flow_j`, J)."""
        if dissipated_j >= -(SECOND_LAW_TOL * flow_j + SECOND_LAW_FLOOR_J):
            return True
        self.res.violations.append(f"dissipation fell by {-dissipated_j:.4g} J of {flow_j:.4g} J flowed at "
                                   f"t = {t:.4f} s")
        return False

    def _impact_within_work(self, delta: float, e_in: float, load_work: float, t: float) -> bool:
        """½ k δ² ≤ W past a stop or thread end, W the energy stored at first contact plus the work of the
        drive and the load since."""
        if delta <= 0.0:
            self.w_contact = None
            return True
        if self.w_contact is None:  # first contact: what was stored just before it
            self.w_contact = self.stored_prev - self.energy_in_prev + self.load_work_prev
        w = self.w_contact + e_in - load_work
        k = self.k_stop
        if 0.5 * k * delta * delta > w * (1 + 1e-6) + 1e-9:
            self.res.violations.append(f"impact past the work: ½kδ² = {0.5 * k * delta * delta:.4g} J > W = "
                                       f"{w:.4g} J at t = {t:.4f} s (δ = {delta * 1e6:.2f} µm)")
            return False
        return True

    def check_rest(self) -> None:
        """At rest against a stop at the end: δ within the static deflection of the net force + 2 µm
        (screw and nut: an elastic nut can still ring on its chain while the screw is held).

        At rest over the last 0.1 s from its start: the state before the window's first step is at rest too.
        The nut force is the one held over the last step, static only when that step began at rest: a step
        that stops the screw on a stiff stop (backward Euler at a step that does not resolve it ends at rest
        where it began) holds the force of the stopping impulse, not the static law's."""
        last = int(round(0.1 / self.dt)) + 1  # end states: the window's steps and the state it starts from
        hist_w, hist_v, hist_contact = self.hist_w, self.hist_v, self.hist_contact
        if len(hist_w) >= last and max(abs(w) for w in hist_w[-last:]) < 1e-3 \
                and max(abs(q) for q in hist_v[-last:]) < 1e-6 and hist_contact[-1] > 0.0:
            f = self.hist_load[-1]  # held over the last step (the load at its end time is the next step's)
            net = abs(f - self.last.nut_force_n)
            k = self.k_stop
            if hist_contact[-1] > net / k + REST_SLACK_M:
                stop_f = self._stop_force()
                self.res.violations.append(f"at rest {hist_contact[-1] * 1e6:.2f} µm into the stop, the net force "
                                           f"{net:.1f} N deflects it {net / k * 1e6:.2f} µm "
                                           f"(stop force {stop_f:.1f} N)")

    def _stop_force(self) -> float:
        if self.act is None:
            return self.session.simulator.thread_end_force_n
        return float(self.sim.layout.view(self.last.internal, "actuator")[_Q["stop_force_n"]])

    def check_ringing(self) -> None:
        """Held against a stop under a constant command: no ringing (`_ring`) that is neither the contact's own
        decaying mode (`_decays_as_the_contact_does`) nor the closed loop's own: a drive loop that does not settle
        even on the free inertia (`_loop_rings_by_itself`), or a ring the same at a resolved step
        (`_rings_alike_when_resolved`)."""
        ptp = self._ring()
        if ptp is None or self._decays_as_the_contact_does(self.hist_w[-self.tail:]) \
                or self._loop_rings_by_itself() or self._rings_alike_when_resolved(ptp):
            return
        self.res.violations.append(f"screw speed rings {ptp:.3f} rad/s peak to peak against a stop "
                                   "under a constant command")

    def _ring(self, settle_s: float = SETTLE_S) -> float | None:
        """The screw speed's peak to peak (rad/s) over the last 0.5 s where it rings held against a stop under a
        constant command (and nothing else changed: no brake command, fault start or end in that time; the impact
        that brought it there `settle_s` or more before the window, so what is judged is a hold, not an impact's
        decay); None where it does not."""
        tail, dt, hist_w = self.tail, self.dt, self.hist_w
        settle = int(round(settle_s / dt))
        if not (len(hist_w) >= tail + settle and min(self.hist_contact[-tail - settle:]) > 0.0
                and len(set(self.hist_cmd[-tail:])) == 1 and len(set(self.hist_load[-tail:])) == 1
                and self.last_event <= self.sim.time_s + self.t_offset - tail * dt - 0.1):
            return None
        ptp = max(hist_w[-tail:]) - min(hist_w[-tail:])
        # ringing reverses the screw and lasts: swings of a quarter of the limit either way still there in
        # the window's last 0.1 s. A one-way creep (the speed loop's integral pressing the nut further in)
        # and the decaying ring when the torque limit then halts it are the controller's physics
        last = hist_w[-max(2, int(round(0.1 / dt))):]
        w = [q for q in last if abs(q) >= 0.25 * P2P_LIMIT_RAD_S]
        reversals = sum(1 for a, b in zip(w, w[1:], strict=False) if a * b < 0.0)
        return ptp if ptp >= P2P_LIMIT_RAD_S and reversals >= 2 else None

    def _loop_rings_by_itself(self) -> bool:
        """The drive's sampled loop, as the case sets it, does not settle on the inertia it drives
        (`Actuator.drive_loop_radius` ≥ 1: the Jury bound ω_b h < 4(√2 − 1) of its speed loop; the campaign's
        steps above 8.8 ms with the loop at the step's rate, 30 Hz bandwidth). Such a loop rings by itself, and
        against a stiff stop it has more than one end: seed 36720 (a 94 Hz position loop on a 1e8 N/m stop) comes
        to rest at plant steps of T/3, T/10, T/100 and T/1000 and holds a ±142 rad/s limit cycle off the stop at
        T/30 and T/300, so no step's run stands for the others; what a step makes of the contact is judged on the
        loops that settle and on torque commands."""
        return self.act is not None and self.sim.model.drive_loop_radius(session_interface(self.case)) >= 1.0

    def _rings_alike_when_resolved(self, ptp: float) -> bool:
        """The ring is the closed loop's own, not the step's: the same case at a step RESOLVE_FACTOR or more times
        shorter, the drive's loop rate kept (`resolved_case`), rings in the same window with a peak to peak within
        RING_AGREEMENT of `ptp` (a convergence check: a step's artefact changes with the step). A sampled drive
        loop that saturates its torque on a stiff stop holds a limit cycle of its own (seed 46302: a 58 Hz
        position loop on a 60 mm screw, 1e7 N/m stop, rings 48.6 rad/s peak to peak at a 5.7 ms step and
        50.7 rad/s at 0.57 ms, unchanged over 2 s)."""
        if self.resolved:
            return False
        res = Result()
        run = _Run(resolved_case(self.case), res, resolved=True)
        if not run.loop() or res.violations:
            return False
        fine = run._ring(settle_s=0.0)  # the same window, whenever the resolved impact settled into it
        return fine is not None and abs(fine - ptp) <= RING_AGREEMENT * ptp

    def _decays_as_the_contact_does(self, window: list[float]) -> bool:
        """The ring is the contact's own mode: it decays at least at half the rate σ = c/(2 m) its damping c
        gives the nut's reflected mass m = J (2π/L)² (J: the screw's inertia, and the rotor's if it turns
        with it), between the window's first and last 0.1 s. A screw of large inertia and fine lead (19 t
        reflected on a 54 mm, 2 mm-lead screw) rings on a 1e8 N/m stop at ~11 Hz with ζ ≈ 0.07: a physical
        ring that lasts ~0.2 s per e-fold; on s30 (~350 kg) σ ≈ 290/s leaves no ring to accept."""
        if not self.limits:
            return False
        model = self.sim.model
        inertia = model.J if self.act is not None else model.kinetic[0]
        mass = inertia / self.p.geometry.lead_per_rad_m ** 2
        sigma = self.limits[0].damping_n_s_m / (2.0 * mass)
        n = max(2, int(round(0.1 / self.dt)))
        first = max(abs(q) for q in window[:n])
        last = max(abs(q) for q in window[-n:])
        span = (len(window) - n) * self.dt
        return last <= first * math.exp(-0.5 * sigma * span)


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
