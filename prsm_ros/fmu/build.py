"""Build an FMU from a configuration (`config.make_config`) with pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from prsm_sim.errors import PrsmError

from prsm_ros.fmu.config import CONFIG_NAME

HERE = Path(__file__).resolve().parent
# The slave module each FMI version's FMU loads. Distinct module names: an importer running both
# kinds of FMU in one Python process imports each once, by name.
SLAVE_MODULES = {2: "prsm_fmu2_slave", 3: "prsm_fmu3_slave"}
SLAVE_SOURCES = {2: HERE / "slave_fmi2.py", 3: HERE / "slave_fmi3.py"}
BUILD_TIMEOUT_S = 300.0  # a build takes about a second; a stalled child is ended


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
        # pythonfmu packs its own package into each FMU's resources, and an FMU loaded into a Python
        # process puts that copy in place of the installed one (its builder then looks for the
        # export library inside a deleted folder and writes an FMU without binaries). A child
        # process builds from the installed package whatever this process has loaded.
        res = subprocess.run([sys.executable, "-m", "prsm_ros.fmu.build", str(fmi), str(script), str(cfg), str(out)],
                             capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
        if res.returncode != 0:
            raise PrsmError(f"the FMU builder failed: {(res.stderr.strip().splitlines() or ['no message'])[-1]}")
        built = Path(res.stdout.strip().splitlines()[-1])
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(built), dest)
    return dest


def _build_in_this_process(fmi: int, script: Path, cfg: Path, out: Path) -> Path:
    """The pythonfmu (FMI 2.0) or pythonfmu3 (FMI 3.0) builder, run in a fresh process by `build_fmu`."""
    if fmi == 2:
        from pythonfmu import FmuBuilder
        return FmuBuilder.build_FMU(script, dest=out, project_files=[cfg], canGetAndSetFMUstate=True,
                                    canSerializeFMUstate=True)
    from pythonfmu3 import FmuBuilder as Fmu3Builder
    return Fmu3Builder.build_FMU(script, dest=out, project_files=[cfg], canGetAndSetFMUState=True,
                                 canSerializeFMUState=True, canHandleVariableCommunicationStepSize=True)


if __name__ == "__main__":  # the child of build_fmu: FMI version, slave script, configuration, output folder
    print(_build_in_this_process(int(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), Path(sys.argv[4])))
