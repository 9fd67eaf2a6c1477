"""Deprecated alias of `prsm_ros.json_out` (which every layer may use); removed in prsm 0.2.0.

Importing it warns (DeprecationWarning); import `prsm_ros.json_out` instead.
"""

import warnings

from prsm_ros.json_out import dumps, jsonable

__all__ = ["dumps", "jsonable"]

warnings.warn("prsm_ros.cli.json_out is deprecated and is removed in prsm 0.2.0: import prsm_ros.json_out",
              DeprecationWarning, stacklevel=2)
