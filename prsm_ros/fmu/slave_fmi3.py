"""The FMI 3.0 co-simulation slave (pythonfmu3): the module an FMU built by `prsm-fmu build --fmi 3` loads.

pythonfmu3's C++ wrapper finds the slave by reading this file for a class deriving from
Fmi3Slave; it delegates everything to `prsm_ros.fmu.core.SlaveCore`. A doStep returns its FMI
status: refused inputs and model failures end the step with fmi3Error (the instance and its state
intact) and the message in the FMU's log. A Python exception would be fmi3Fatal, so none escapes.
"""

from pythonfmu3 import Fmi3Causality, Fmi3Slave, Fmi3Status, Fmi3StepResult, Fmi3Variability, Float64
from pythonfmu3.default_experiment import DefaultExperiment
from pythonfmu3.unit import Unit

from prsm_ros.fmu.core import UNITS, attach, life_cycle, state_from_bytes

_STATUS = {"ok": Fmi3Status.ok, "warning": Fmi3Status.warning, "error": Fmi3Status.error}
_CAUSALITY = {"input": Fmi3Causality.input, "output": Fmi3Causality.output, "parameter": Fmi3Causality.parameter}
_VARIABILITY = {"input": Fmi3Variability.continuous, "output": Fmi3Variability.continuous,
                "parameter": Fmi3Variability.tunable}
_OK = Fmi3StepResult()
_ERROR = Fmi3StepResult(status=Fmi3Status.error)


class PrsmActuator(Fmi3Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.core = core = attach(self, _STATUS, DefaultExperiment)
        self.time = 0.0
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous, description="simulation time",
                                       unit="s"))
        used = {"s"}
        for v in core.variables:
            getter, setter = core.accessors(v)
            self.register_variable(Float64(v.name, causality=_CAUSALITY[v.causality],
                                           variability=_VARIABILITY[v.causality], description=v.description,
                                           unit=v.unit, getter=getter, setter=setter))
            used.add(v.unit)
        self.register_units([Unit(u, **UNITS[u]) for u in sorted(used)])

    def to_xml(self, model_options=None):
        """pythonfmu3's description with start values written to come back exact (it writes 16 digits)."""
        root = super().to_xml(model_options or {})
        for v in root.find("ModelVariables"):
            if v.get("start") is not None and v.get("name") != "time":
                v.set("start", repr(self.core.get(v.get("name"))))
        return root

    # FMI's order of calls, kept by the core; deserialising never raises (see prsm_ros.fmu.core)
    enter_initialization_mode, exit_initialization_mode, terminate = life_cycle()
    _fmu_state_from_bytes = staticmethod(state_from_bytes)

    def do_step(self, current_time, step_size):
        if self.core.do_step(current_time, step_size) is not None:
            return _ERROR
        self.time = current_time + step_size
        return _OK

    def _get_fmu_state(self):
        return {"time": self.time, "core": self.core.get_state()}

    def _set_fmu_state(self, state):
        core = state.get("core") if isinstance(state, dict) and "core" in state else state  # or an unreadable one
        if self.core.set_state(core) and isinstance(state.get("time"), float):
            self.time = state["time"]
