"""The actuator around the screw: drive, motor, coupling, sensors, end stops, brake, faults (issue 14)."""

from prsm_sim.actuator.actuator import ACTUATOR_QUANTITIES, MEASURED_QUANTITIES, Actuator, ActuatorState, Ledger
from prsm_sim.actuator.faults import FaultEvent
from prsm_sim.actuator.params import (COMMAND_INTERFACES, FAULT_KINDS, SENSORS, ActuatorParams, BrakeParams,
                                      DriveParams, Fault, MotorParams, SensorParams, StopParams, check_interface)

__all__ = ["ACTUATOR_QUANTITIES", "MEASURED_QUANTITIES", "Actuator", "ActuatorState", "Ledger", "FaultEvent",
           "COMMAND_INTERFACES", "FAULT_KINDS", "SENSORS", "ActuatorParams", "BrakeParams", "DriveParams", "Fault",
           "MotorParams", "SensorParams", "StopParams", "check_interface"]
