"""Environment and launching for runs that start their own ROS processes (demo, benchmarks, tests).

A ROS_DOMAIN_ID the user set is respected; otherwise these runs pick one from the process id, so
two demos (or a demo and someone else's robot on the same network) do not see each other. Discovery
defaults to this machine only (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) unless the user chose a range.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from prsm_sim.errors import ParamError


def isolated_env(domain_id: int | None = None, *, respect_user: bool = True, **extra: str) -> dict[str, str]:
    """os.environ plus ROS_DOMAIN_ID (given, the user's, or 100 + pid % 100) and localhost discovery."""
    env = dict(os.environ)
    if domain_id is None and not (respect_user and env.get("ROS_DOMAIN_ID", "").strip()):
        domain_id = 100 + os.getpid() % 100
    if domain_id is not None:
        if not 0 <= domain_id <= 232:
            raise ParamError(f"ROS domain id {domain_id}: must be in 0..232")
        env["ROS_DOMAIN_ID"] = str(domain_id)
    if not (respect_user and env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip()):
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    env.update(extra)
    return env


def ros_args(params: dict[str, Any]) -> list[str]:
    """`--ros-args -p name:=value ...` keeping each value's Python type through ROS's YAML parsing."""
    out = ["--ros-args"]
    for k, v in params.items():
        if isinstance(v, bool):
            text = "true" if v else "false"
        elif isinstance(v, float):
            text = repr(v) if any(c in repr(v) for c in ".en") else f"{v}.0"  # "1e-05", "nan", "inf" stay as they are
        elif isinstance(v, str):
            text = "'" + v.replace("'", "''") + "'"  # quoted: YAML would read off/yes/1.0 as bool or number
        else:
            text = str(v)
        out += ["-p", f"{k}:={text}"]
    return out


def start_module(module: str, args: list[str], env: dict[str, str], *, cwd: Path | str | None = None,
                 stdout=None, stderr=None) -> subprocess.Popen:
    """`python -m module args...` with this interpreter (works from a venv with nothing sourced)."""
    return subprocess.Popen([sys.executable, "-m", module, *args], env=env, cwd=cwd, stdout=stdout, stderr=stderr)
