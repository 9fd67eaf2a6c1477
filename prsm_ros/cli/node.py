"""`prsm-node`: the entry point around `PrsmNode` (`prsm_ros.node.process`: arguments, init, spin, a clean shutdown).

`python -m prsm_ros.cli.node` and `python -m prsm_ros.node` are the same as `prsm-node`.
"""

from __future__ import annotations

import sys

from prsm_ros.node.process import main, rcl_reason

__all__ = ["main", "rcl_reason"]

if __name__ == "__main__":
    sys.exit(main())
