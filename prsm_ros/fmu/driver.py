"""Drive an FMU through fmpy, the same calls for FMI 2.0 and 3.0: set inputs, doStep, get outputs, FMU state.

The importer's side, as the tests and `prsm-bench --only fmu` use it (fmpy is the reference importer
here). Every FMI status worse than a warning comes back as fmpy's `FMICallException`; `do_step`
returns the status instead, and every message the FMU logs is kept in `messages` as (status, text).
"""

from __future__ import annotations

import shutil

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.simulation import instantiate_fmu

OK = 0


class FmuDriver:
    """One instance of the FMU at `path`, initialised at time `start_time_s` and ready to step."""

    def __init__(self, path: str, start_time_s: float = 0.0) -> None:
        self.description = md = read_model_description(str(path), validate=True)
        self.fmi3 = md.fmiVersion.startswith("3")
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.messages: list[tuple[int, str]] = []
        self._unzipped = extract(str(path))
        # FMI 2 logger: (env, instance, status, category, message); FMI 3: (env, status, category, message)
        self._logger = lambda *a: self.messages.append((int(a[-3]), a[-1].decode("utf-8", "replace")))
        self.fmu = fmu = instantiate_fmu(self._unzipped, md, debug_logging=True, logger=self._logger)
        self._get, self._set = (fmu.getFloat64, fmu.setFloat64) if self.fmi3 else (fmu.getReal, fmu.setReal)
        self._start_time_s = start_time_s
        self._initialise()

    def _initialise(self) -> None:
        fmu = self.fmu
        if self.fmi3:
            fmu.enterInitializationMode(startTime=self._start_time_s)
        else:
            fmu.setupExperiment(startTime=self._start_time_s)
            fmu.enterInitializationMode()
        fmu.exitInitializationMode()

    def refs(self, names) -> list[int]:
        return [self.vr[n] for n in names]

    def set(self, refs: list[int], values: list[float]) -> None:
        self._set(refs, values)

    def get(self, refs: list[int]) -> list[float]:
        return list(self._get(refs))

    def do_step(self, t: float, h: float) -> int:
        """One communication step; the FMI status (0 OK)."""
        try:
            self.fmu.doStep(t, h)
        except FMICallException as e:
            return e.status
        return OK

    def get_state(self):
        return self.fmu.getFMUState() if self.fmi3 else self.fmu.getFMUstate()

    def set_state(self, state) -> None:
        (self.fmu.setFMUState if self.fmi3 else self.fmu.setFMUstate)(state)

    def free_state(self, state) -> None:
        (self.fmu.freeFMUState if self.fmi3 else self.fmu.freeFMUstate)(state)

    def serialize(self, state) -> bytes:
        return bytes(self.fmu.serializeFMUState(state) if self.fmi3 else self.fmu.serializeFMUstate(state))

    def deserialize(self, data: bytes):
        return self.fmu.deserializeFMUState(data) if self.fmi3 else self.fmu.deSerializeFMUstate(data)

    def reset(self) -> None:
        """fmiReset, then initialised again, ready to step from the start time."""
        self.fmu.reset()
        self._initialise()

    def close(self) -> None:
        try:
            self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
            shutil.rmtree(self._unzipped, ignore_errors=True)

    def __enter__(self) -> FmuDriver:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
