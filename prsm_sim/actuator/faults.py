"""Fault injection: which faults are active, what they change, and their start/clear events.

Friction faults act on the screw model's parameters (a surge or a loss of lubrication scales
its friction; the actuator switches to a model built with the scaled parameters while the
fault lasts) or, for a jam, add a dry-friction torque on the screw. None of the current
models resolves one roller: `ideal` has no rollers, `jones2016` and `fu2018` carry N_R
identical rollers with one symmetric load share (their per-roller outputs are copies), so a
fault naming one roller is refused with that reason rather than applied to all of them.
Growing backlash needs a model with a thread clearance: the `elastic` level without preload.
While the fault lasts the clearance is `elastic.axial_clearance_m` + value × (t − start) (value
in m/s), held over each step at its value at the step's start and carried into the model as
`State.extra_clearance_m`. When the fault clears the gap closes back to the parameter's value
as far as the flanks are apart (never onto a loaded flank: that would be a force step out of
nothing), so it is fully back at the next pass of the nut through the gap. A gap widening with
a flank in contact unloads it at fixed deflection: the actuator books the elastic energy
released as dissipated (`Ledger.backlash_j`, ≥ 0), so its ledger closes and the model's own
balance and energy guard stay those of a fixed clearance.
"""

from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple

from prsm_sim.actuator.params import Fault
from prsm_sim.errors import ParamError
from prsm_sim.models.registry import model_class
from prsm_sim.params import Params

MODELS_RESOLVING_ROLLERS: tuple[str, ...] = ()


def check_fault(fault: Fault, params: Params, model_name: str, has_motor: bool) -> Fault:
    """Refuse a fault this actuator cannot apply, with one line saying why (ParamError)."""
    if not isinstance(fault, Fault):
        raise ParamError(f"fault: expected a Fault record, got {type(fault).__name__}")
    n = params.geometry.n_rollers
    if fault.roller is not None:
        if fault.roller >= n:
            raise ParamError(f"fault.roller = {fault.roller}: beyond n_rollers = {n} (allowed 0..{n - 1}, or None for all)")
        if model_name not in MODELS_RESOLVING_ROLLERS:
            raise ParamError(f"fault.roller = {fault.roller}: model {model_name!r} treats all rollers alike "
                             f"(none of ideal, jones2016, fu2018 resolves one roller); use roller None for all")
    # a clearance grows only where the nut sits on its own axial chain
    if fault.kind == "backlash" and not model_class(model_name).has_axial_chain:
        raise ParamError(f"fault.kind = 'backlash': growing backlash is not implemented for model {model_name!r} "
                         "(it needs the elastic model's thread clearance: use model 'elastic'; "
                         "elastic.axial_clearance_m sets a fixed backlash)")
    if fault.kind == "backlash" and params.elastic.preload_n > 0:
        raise ParamError(f"fault.kind = 'backlash': elastic.preload_n = {params.elastic.preload_n} (a preloaded nut "
                         "has no clearance to grow); allowed with preload_n = 0")
    if fault.kind in ("torque_limit_drop",) and not has_motor:
        raise ParamError("fault.kind = 'torque_limit_drop': the ideal actuator (no motor) has no torque limit; "
                         "configure a motor")
    return fault


class Active(NamedTuple):
    """What the faults active at one instant do."""

    friction_factor: float = 1.0
    lubrication_factor: float = 1.0
    jam_nm: float = 0.0
    torque_factor: float = 1.0
    drive_off: bool = False
    sensor: tuple[tuple[str, str, float], ...] = ()  # (sensor, kind, value)


NONE = Active()


def active(faults: tuple[Fault, ...], t_s: float) -> Active:
    """Combine the faults active at `t_s` (factors multiply, jams add)."""
    if not faults:
        return NONE
    ff = lf = tf = 1.0
    jam = 0.0
    off = False
    sens = []
    for f in faults:
        if not f.active(t_s):
            continue
        k = f.kind
        if k == "friction_surge":
            ff *= f.value
        elif k == "lubrication_loss":
            lf *= f.value
        elif k == "jam":
            jam += f.value
        elif k == "torque_limit_drop":
            tf *= f.value
        elif k == "drive_fault":
            off = True
        elif k.startswith("sensor_"):
            sens.append((str(f.sensor), k, f.value))  # a sensor fault names its sensor (`Fault` checks it)
    return Active(friction_factor=ff, lubrication_factor=lf, jam_nm=jam, torque_factor=tf, drive_off=off,
                  sensor=tuple(sens))


def scaled_params(params: Params, friction_factor: float, lubrication_factor: float) -> Params:
    """Screw parameters with friction scaled by the surge × lubrication factors.

    Every friction coefficient (Coulomb, viscous, pin, rolling) scales with both; a loss of
    lubrication also divides the lubricant's viscosity (the churning drag of the ring gear gap)
    by its factor: the film that carried the load and dragged the carrier is gone. `ideal`:
    the loss fractions (1/η_f − 1) and (1 − η_b) and the bearing viscous torque scale.
    """
    f = friction_factor * lubrication_factor
    fr, il = params.friction, params.ideal
    fr2 = replace(fr, viscous_n_s_m=fr.viscous_n_s_m * f, mu_screw_roller=min(0.99, fr.mu_screw_roller * f),
                  mu_pin=fr.mu_pin * f, mu_nut_roller_rolling=fr.mu_nut_roller_rolling * f,
                  lubricant_viscosity_m2_s=fr.lubricant_viscosity_m2_s / lubrication_factor)
    il2 = replace(il, efficiency_forward=1.0 / (1.0 + f * (1.0 / il.efficiency_forward - 1.0)),
                  efficiency_backward=max(-1.0, 1.0 - f * (1.0 - il.efficiency_backward)),
                  viscous_nm_s_rad=il.viscous_nm_s_rad * f)
    return replace(params, friction=fr2, ideal=il2)


def extra_clearance_m(faults: tuple[Fault, ...], t_s: float) -> float:
    """Clearance the active backlash faults add at `t_s`: Σ value × (t − start), m (0 once cleared)."""
    return sum(f.value * (t_s - f.start_s) for f in faults if f.kind == "backlash" and f.active(t_s))


class FaultEvent(NamedTuple):
    time_s: float
    what: str  # "start" or "clear"
    fault: Fault

    def describe(self) -> str:
        return f"fault {self.what}: {self.fault.describe()}"


def fault_events(faults: tuple[Fault, ...], t0_s: float, t1_s: float) -> list[FaultEvent]:
    """Faults active at `t1_s` but not at `t0_s` ("start") and the reverse ("clear").

    A step starting at t uses the faults active at t: with t0, t1 the start times of two
    consecutive steps these are the faults the second step starts or stops applying.
    """
    ev = []
    for f in faults:
        a0, a1 = f.active(t0_s), f.active(t1_s)
        if a1 and not a0:
            ev.append(FaultEvent(max(f.start_s, 0.0), "start", f))
        elif a0 and not a1:
            ev.append(FaultEvent(f.end_s, "clear", f))
    return sorted(ev, key=lambda e: e.time_s)
