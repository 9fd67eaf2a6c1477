"""The FMI 2.0 co-simulation slave (pythonfmu): the module an FMU built by `prsm-fmu build --fmi 2` loads.

pythonfmu's C++ wrapper finds the slave by reading this file for a class whose only base is
Fmi2Slave, so the class below derives from it directly and delegates everything to
`prsm_ros.fmu.core.SlaveCore`. pythonfmu 0.7 maps a doStep that returns False to fmi2Discard and a
Python exception to fmi2Fatal; refused inputs and model failures therefore end the step with
fmi2Discard (the instance and its state intact) and the message in the FMU's log.
"""

from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

from prsm_ros.fmu.core import UNITS, attach, life_cycle, state_from_bytes

_STATUS = {"ok": Fmi2Status.ok, "warning": Fmi2Status.warning, "error": Fmi2Status.error}
_CAUSALITY = {"input": Fmi2Causality.input, "output": Fmi2Causality.output, "parameter": Fmi2Causality.parameter}
_VARIABILITY = {"input": Fmi2Variability.continuous, "output": Fmi2Variability.continuous,
                "parameter": Fmi2Variability.tunable}


class PrsmActuator(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.core = core = attach(self, _STATUS, DefaultExperiment)
        self._units = {}
        for v in core.variables:
            getter, setter = core.accessors(v)
            self.register_variable(Real(v.name, causality=_CAUSALITY[v.causality],
                                        variability=_VARIABILITY[v.causality], description=v.description,
                                        getter=getter, setter=setter))
            self._units[v.name] = v.unit

    # FMI's order of calls, kept by the core; deserialising never raises (see prsm_ros.fmu.core)
    enter_initialization_mode, exit_initialization_mode, terminate = life_cycle()
    _fmu_state_from_bytes = staticmethod(state_from_bytes)

    def do_step(self, current_time, step_size):
        return self.core.do_step(current_time, step_size) is None

    def _get_fmu_state(self):
        return self.core.get_state()

    def _set_fmu_state(self, state):
        self.core.set_state(state)

    def to_xml(self, model_options=None):
        """pythonfmu's description plus units (FMI 2.0 UnitDefinitions) and the outputs' InitialUnknowns."""
        root = super().to_xml(model_options or {})
        used = sorted(set(self._units.values()))
        defs = Element("UnitDefinitions")
        for u in used:
            SubElement(SubElement(defs, "Unit", name=u), "BaseUnit", {k: str(e) for k, e in UNITS[u].items()})
        root.insert(list(root).index(root.find("CoSimulation")) + 1, defs)
        for sv in root.find("ModelVariables"):
            real = sv.find("Real")
            real.set("unit", self._units[sv.get("name")])
            if real.get("start") is not None:  # pythonfmu writes 16 digits; a double may need 17 to come back exact
                real.set("start", repr(self.core.get(sv.get("name"))))
        outputs = root.find("ModelStructure/Outputs")
        unknowns = SubElement(root.find("ModelStructure"), "InitialUnknowns")
        for u in outputs:
            SubElement(unknowns, "Unknown", index=u.get("index"))
        return root
