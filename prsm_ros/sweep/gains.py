"""The demo controller's gains file: what `prsm-sweep tune` writes and `prsm-demo --gains` reads.

    # gains for the demo position controller (prsm_sim.control.PositionController)
    controller:
      bandwidth_hz: 24.7      # closed-loop bandwidth (Hz)
      damping: 1.38           # ζ of the error dynamics
      integral_ratio: 10.0    # κ: integral at ω³/κ
      max_torque_nm: 50.0     # output clamp (N·m)

Any subset of the four; the others keep the demo's defaults. Other top-level keys (the study, the
tuning figures) are kept for the reader and ignored here. A study's `set:` takes the same values
as `controller.<name>` (`as_study_set`), so a tuned file can be checked with `prsm-sweep run`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from prsm_sim.errors import InputError

GAIN_NAMES = ("bandwidth_hz", "damping", "integral_ratio", "max_torque_nm")


def parse_gains(data: Any, where: str = "gains") -> dict[str, float]:
    """The `controller:` mapping of a gains document → name → positive finite float; InputError otherwise."""
    if not isinstance(data, dict) or not isinstance(data.get("controller"), dict):
        raise InputError(f"{where}: expected a mapping with a `controller:` mapping of "
                         f"{', '.join(GAIN_NAMES)}")
    out = {}
    for k, v in data["controller"].items():
        if k not in GAIN_NAMES:
            raise InputError(f"{where}: controller.{k}: unknown gain; allowed: {', '.join(GAIN_NAMES)}")
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise InputError(f"{where}: controller.{k} = {v!r}: must be a positive finite number")
        out[k] = float(v)
    return out


def load_gains(path: str | Path) -> dict[str, float]:
    """Read a gains file (YAML); InputError naming the file and what is wrong."""
    from prsm_ros.limits import load_yaml, read_text_file
    p = Path(path)
    data = load_yaml(read_text_file(p, what="gains file", error=InputError), source=str(p), error=InputError)
    return parse_gains(data, str(p))


def gains_document(gains: dict[str, float], comment: str = "") -> str:
    """A gains file's text (YAML, one gain a line), `comment` lines first."""
    lines = [f"# {c}" for c in comment.splitlines()] + ["controller:"]
    lines += [f"  {k}: {gains[k]!r}" for k in GAIN_NAMES if k in gains]
    return "\n".join(lines) + "\n"


def as_study_set(gains: dict[str, float]) -> dict[str, float]:
    """The gains as a study's `set:` entries (`controller.<name>`)."""
    return {f"controller.{k}": v for k, v in gains.items()}
