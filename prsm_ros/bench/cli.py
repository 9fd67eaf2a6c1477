"""`prsm-bench`: every performance figure of the system beside its target, on this machine.

Each area measures itself in its own module (`core`, `node`, `recorder`, `viz` (shown as
"rerun"), `soak`, `realtime`, `sweep`, `elastic`, `fmu`, `fit`), each with `measure(quick) -> list[figure]`; this command
runs them in turn and prints one table (or `--json`). Ratios are measured side by side in one run, repeated, and
reported as median with spread. `--quick` is a smoke run of under a minute: its figures are
indicative only, and nothing here asserts a timing.
"""

from __future__ import annotations

import sys

from prsm_ros.bench import common, core, elastic, fit, fmu, node, realtime, recorder, soak, sweep, viz

AREAS: dict[str, common.Measure] = {
    "core": core.measure,
    "node": node.measure,
    "recorder": recorder.measure,
    "rerun": viz.measure,
    "soak": soak.measure,
    "realtime": realtime.measure,
    "sweep": sweep.measure,
    "elastic": elastic.measure,
    "fmu": fmu.measure,
    "fit": fit.measure,
}


def main(argv: list[str] | None = None) -> int:
    return common.main(AREAS, argv, description=__doc__.splitlines()[0])


if __name__ == "__main__":
    sys.exit(main())
