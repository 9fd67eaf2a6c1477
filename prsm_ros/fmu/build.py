"""Build an FMU from a configuration (`config.make_config`) with pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0)."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

from prsm_ros.fmu.config import CONFIG_NAME

HERE = Path(__file__).resolve().parent
# The slave module each FMI version's FMU loads. Distinct module names: an importer running both
# kinds of FMU in one Python process imports each once, by name.
SLAVE_MODULES = {2: "prsm_fmu2_slave", 3: "prsm_fmu3_slave"}
SLAVE_SOURCES = {2: HERE / "slave_fmi2.py", 3: HERE / "slave_fmi3.py"}


def build_fmu(config: dict, dest: str | Path) -> Path:
    """Write the FMU `dest` (a .fmu path) for `config`; returns its path.

    The slave module and the configuration go into the FMU's resources; the FMU declares state
    handling and serialisation (its state is the session's whole state).
    """
    fmi = config["fmi"]
    dest = Path(dest)
    with tempfile.TemporaryDirectory(prefix="prsm_fmu_") as tmp:
        tmp = Path(tmp)
        src = tmp / "src"
        src.mkdir()
        script = src / f"{SLAVE_MODULES[fmi]}.py"
        shutil.copyfile(SLAVE_SOURCES[fmi], script)
        cfg = src / CONFIG_NAME
        cfg.write_text(json.dumps(config, indent=1), encoding="utf-8")
        out = tmp / "out"
        if fmi == 2:
            from pythonfmu import FmuBuilder
            built = FmuBuilder.build_FMU(script, dest=out, project_files=[cfg], canGetAndSetFMUstate=True,
                                         canSerializeFMUstate=True)
        else:
            from pythonfmu3 import FmuBuilder as Fmu3Builder
            built = Fmu3Builder.build_FMU(script, dest=out, project_files=[cfg], canGetAndSetFMUState=True,
                                          canSerializeFMUState=True, canHandleVariableCommunicationStepSize=True)
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(built), dest)
    return dest
