"""What the sensors around the screw report: the motor encoder, a nut linear encoder and the nut load
cell, with their resolution, noise, filter, dropout and injected faults, for one actuator.

`SensorSuite.measure` turns the true sample the sensors see (`sensors.TrueSample`, delayed by their
latency in the actuator's state) into the `measured` block; the drive reads its feedback through
`read_encoder` and `read_linear`. Each sensor's readings are wired by name (`sensors.SENSORS`), so a
new sensor is one entry there plus its reading here.
"""

from __future__ import annotations

import math

from prsm_sim.actuator import faults as fl
from prsm_sim.actuator.params import SensorParams
from prsm_sim.actuator.sensors import (MEASURED_QUANTITIES, SENSORS, STREAM, TrueSample, first_order, normal,
                                      quantise, uniform)

_MEASURED_NAMES = tuple(n for n, _ in MEASURED_QUANTITIES)
_READING_NAMES = tuple(q for s in SENSORS for q in s.names)  # the readings of the measured block, in order
# `SensorSuite.measure` makes the readings in this order (a new sensor's reading goes in there too)
assert _READING_NAMES == ("motor_angle_rad", "screw_angle_rad", "screw_speed_rad_s", "nut_position_m",
                          "nut_velocity_m_s", "nut_force_n")
_ALL_FRESH = (1.0,) * len(SENSORS)  # the freshness flags when no sensor dropped out or is faulted


class SensorSuite:
    """The sensors of one actuator (pure functions of their inputs; the memory is in the actuator's state).

    Parameters
    ----------
    params : SensorParams
        Resolution, noise, bias, filter, latency, dropout and the seed of the draws.
    ratio : float
        The gear ratio (motor / screw): the encoder sits on the motor shaft.
    rigid : bool
        The coupling is rigid: the screw turns with the motor.
    lead_per_rad_m : float
        L/2π, m/rad: the nut's position from the screw angle without a linear encoder.
    dt_s : float
        The step the sensors report at, s.
    """

    def __init__(self, params: SensorParams, ratio: float, rigid: bool, lead_per_rad_m: float, dt_s: float) -> None:
        self.params, self.ratio, self.rigid, self.p, self.dt_s = params, ratio, rigid, lead_per_rad_m, dt_s

    def encoder_screw_angle(self, motor_angle_rad: float, screw_angle_rad: float) -> float:
        counts = self.params.encoder_counts_per_rev
        if counts == 0:
            return screw_angle_rad if self.rigid else motor_angle_rad / self.ratio
        return quantise(motor_angle_rad, 2.0 * math.pi / counts) / self.ratio

    def faulted(self, sensor: str, value: float, held: float, act: fl.Active, key: int) -> tuple[float, bool]:
        """Apply the active faults of `sensor` to a fresh reading: (value, fresh?)."""
        seed = self.params.seed
        for s, kind, v in act.sensor:
            if s != sensor:
                continue
            if kind == "sensor_bias":
                value += v
            elif kind == "sensor_noise":
                value += v * normal(seed, key, 100 + STREAM[sensor])
            elif kind == "sensor_stuck":
                return held, False
            elif kind == "sensor_dropout" and uniform(seed, key, 110 + STREAM[sensor]) <= v:
                return held, False
        return value, True

    def read_encoder(self, motor_angle_rad: float, screw_angle_rad: float, act: fl.Active, key: int,
                      held: float) -> float:
        v = self.encoder_screw_angle(motor_angle_rad, screw_angle_rad)
        return self.faulted("motor_encoder", v, held, act, key)[0] if act.sensor else v

    def read_linear(self, nut_m: float, encoder_screw_rad: float, act: fl.Active, key: int) -> float:
        res = self.params.linear_encoder_resolution_m
        if res is None:
            return self.p * encoder_screw_rad
        v = quantise(nut_m, res)
        return self.faulted("linear_encoder", v, v, act, key)[0] if act.sensor else v

    def measure(self, key: int, prev: tuple, filtered_n: float, now: TrueSample, before: TrueSample,
                 act: fl.Active, first: bool = False) -> tuple[tuple[float, ...], float]:
        """What the sensors report at step `key` for the delayed true sample `now` (`before`: a step earlier).

        `prev`: the last reading (held on dropout or a stuck fault); `filtered_n`: the load cell
        filter's memory. Returns the MEASURED_QUANTITIES values and the new filter memory.
        """
        sp, h = self.params, self.dt_s
        motor, screw, speed = self._read_motor_encoder(now, before, first)
        nut_x, nut_v = self._read_nut(now, before, first, screw, speed)
        # load cell, in a conditioning chain's order: element (true force) → amplifier (bias, white noise of
        # σ per sample at the step rate) → anti-alias first-order low-pass, so the filter acts on the noise
        raw = now.nut_force_n + sp.load_cell_bias_n if sp.load_cell_bias_n else now.nut_force_n
        if sp.load_cell_noise_n:
            raw += sp.load_cell_noise_n * normal(sp.seed, key, STREAM["load_cell"])
        filt = first_order(filtered_n, raw, sp.load_cell_bandwidth_hz, h) if not first else raw
        readings = (motor, screw, speed, nut_x, nut_v, filt)  # in _READING_NAMES order
        if not (prev and (sp.dropout_probability > 0 or act.sensor)):
            return readings + _ALL_FRESH, filt  # nothing dropped or faulted: every sensor fresh
        vals = dict(zip(_READING_NAMES, readings))
        fresh = {s.name: 1.0 for s in SENSORS}
        self._hold_or_fault(vals, fresh, dict(zip(_MEASURED_NAMES, prev)), act, key)
        return tuple(vals[n] for n in _READING_NAMES) + tuple(fresh[s.name] for s in SENSORS), filt

    def _read_motor_encoder(self, now: TrueSample, before: TrueSample, first: bool) -> tuple[float, float, float]:
        """The motor encoder's readings: motor angle, and from it the screw's angle and speed (by
        differences of counts over the step; ideal: the true values)."""
        ang = self.encoder_screw_angle(now.motor_angle_rad, now.screw_angle_rad)
        if self.params.encoder_counts_per_rev == 0:
            return now.motor_angle_rad, ang, now.screw_speed_rad_s
        spd = 0.0 if first else (ang - self.encoder_screw_angle(before.motor_angle_rad, before.screw_angle_rad)) \
            / self.dt_s
        return ang * self.ratio, ang, spd

    def _read_nut(self, now: TrueSample, before: TrueSample, first: bool, screw_angle_rad: float,
                  screw_speed_rad_s: float) -> tuple[float, float]:
        """Nut position and velocity: from the linear encoder if fitted, else through the lead from the
        motor encoder's readings of the screw's angle and speed (ideal and rigid: the true values)."""
        sp, p = self.params, self.p
        res = sp.linear_encoder_resolution_m
        if res is None:
            if sp.encoder_counts_per_rev == 0 and self.rigid:
                return now.nut_position_m, now.nut_velocity_m_s
            return p * screw_angle_rad, p * screw_speed_rad_s
        x = quantise(now.nut_position_m, res)
        v = now.nut_velocity_m_s if res == 0 else (0.0 if first else (x - quantise(before.nut_position_m, res))
                                                   / self.dt_s)
        return x, v

    def _hold_or_fault(self, vals: dict[str, float], fresh: dict[str, float], prev: dict[str, float],
                       act: fl.Active, key: int) -> None:
        """Each sensor's dropout and active faults on its readings `vals` (in place): a dropped or stuck
        sensor holds its last readings `prev` and reports not fresh; bias and noise act on its primary
        reading. Without a linear encoder the nut's readings follow the motor encoder's."""
        sp, p = self.params, self.p
        lin = sp.linear_encoder_resolution_m is not None
        for s in SENSORS:
            if s.name == "linear_encoder" and not lin:
                continue
            dropped = sp.dropout_probability > 0 and uniform(sp.seed, key, s.dropout_stream) <= sp.dropout_probability
            if not dropped and act.sensor:
                v, ok = self.faulted(s.name, vals[s.primary], prev[s.primary], act, key)
                dropped = not ok
                if ok and v != vals[s.primary]:
                    vals[s.primary] = v
                    if s.name == "motor_encoder":
                        vals["motor_angle_rad"] = v * self.ratio
            if dropped:
                for q in s.names:
                    vals[q] = prev[q]
                fresh[s.name] = 0.0
            if s.name == "motor_encoder" and not lin and (dropped or act.sensor):
                vals["nut_position_m"], vals["nut_velocity_m_s"] = p * vals["screw_angle_rad"], \
                    p * vals["screw_speed_rad_s"]
