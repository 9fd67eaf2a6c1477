"""The actuator around the screw: drive, motor, coupling, sensors, end stops, brake, faults."""

from prsm_sim.actuator.actuator import ACTUATOR_QUANTITIES, MEASURED_QUANTITIES, Actuator, ActuatorState, Ledger
from prsm_sim.actuator.faults import FaultEvent
from prsm_sim.actuator.params import (COMMAND_INTERFACES, FAULT_KINDS, SENSORS, ActuatorParams, BrakeParams,
                                      DriveParams, Fault, MotorParams, SensorParams, StopParams,
                                      actuator_params_from_dict, actuator_params_to_dict, check_interface,
                                      fault_from_dict, parse_fault, parse_faults)

__all__ = ["ACTUATOR_QUANTITIES", "MEASURED_QUANTITIES", "Actuator", "ActuatorState", "Ledger", "FaultEvent",
           "COMMAND_INTERFACES", "FAULT_KINDS", "SENSORS", "ActuatorParams", "BrakeParams", "DriveParams", "Fault",
           "MotorParams", "SensorParams", "StopParams", "check_interface", "actuator_params_from_dict",
           "actuator_params_to_dict", "fault_from_dict", "parse_fault", "parse_faults"]
