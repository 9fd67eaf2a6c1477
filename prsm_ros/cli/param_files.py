"""Deprecated alias of `prsm_ros.param_files` (which every layer may use); removed in prsm 0.2.0.

Importing it warns (DeprecationWarning); import `prsm_ros.param_files` instead.
"""

import warnings

from prsm_ros.param_files import load_params_file, params_from_yaml, params_to_yaml, resolve_params

__all__ = ["load_params_file", "params_from_yaml", "params_to_yaml", "resolve_params"]

warnings.warn("prsm_ros.cli.param_files is deprecated and is removed in prsm 0.2.0: import prsm_ros.param_files",
              DeprecationWarning, stacklevel=2)
