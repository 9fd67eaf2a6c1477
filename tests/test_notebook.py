"""examples/getting_started.ipynb runs top to bottom in a fresh kernel, from a folder that is not the repository's.

Oracles are the notebook's own asserts (a parameter file read back equals the parameter set; a
restored session continues bit for bit; the bag's joint states equal the simulated trajectory)
and here: no cell raises, each figure is drawn, nothing is written into the working folder.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from ros_procs import CEILING_FACTOR

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")

NOTEBOOK = Path(__file__).resolve().parent.parent / "examples" / "getting_started.ipynb"
BUDGET_S = 30.0  # a user's first run on a quiet machine, kernel start-up included


@pytest.mark.slow
def test_getting_started_notebook_runs(tmp_path):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert not any(c.get("outputs") for c in nb.cells if c.cell_type == "code")  # shipped clean
    t0 = time.monotonic()
    nbclient.NotebookClient(nb, timeout=int(BUDGET_S * CEILING_FACTOR), kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    elapsed = time.monotonic() - t0
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    assert "as simulated" in text and "both at" in text and "tracking error rms" in text
    assert len(images) == 2  # the loop, the loads
    assert list(tmp_path.iterdir()) == []  # its files go to a temporary folder of its own
    assert elapsed < BUDGET_S * CEILING_FACTOR
