"""Alias of `prsm_ros.param_files`, which every layer may use; kept for one release."""

from prsm_ros.param_files import load_params_file, params_from_yaml, params_to_yaml, resolve_params

__all__ = ["load_params_file", "params_from_yaml", "params_to_yaml", "resolve_params"]
