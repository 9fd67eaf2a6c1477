"""Alias of `prsm_ros.json_out`, which every layer may use; kept for one release."""

from prsm_ros.json_out import dumps, jsonable

__all__ = ["dumps", "jsonable"]
