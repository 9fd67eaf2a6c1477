"""The command echo and the loop latency, pure Python (no ROS), so it is tested without DDS.

A controller that wants its own loop latency needs to know which state first reflects each
command. The node notes every accepted command's stamp (`offer`): the DDS `source_timestamp` of a
`std_msgs/Float64` (it has no header), the header stamp of a `JointState` (its source timestamp
when the header is left at zero). After each step `take()` returns the stamp of the newest command
that step applied, once; the node publishes it on `~/command_echo` beside that step's state, and
`record_latency` keeps the wall time from the command's stamp to that state's publication for
/diagnostics (both on the system clock of one machine).
"""

from __future__ import annotations

import numpy as np

KEEP = 10_000  # latencies kept between two diagnostics reports


def stamp_of(header_stamp_ns: int | None, source_timestamp_ns: int | None) -> int | None:
    """The command's stamp: its header stamp when set, else the DDS source timestamp (ns)."""
    if header_stamp_ns:
        return int(header_stamp_ns)
    return int(source_timestamp_ns) if source_timestamp_ns else None


class CommandEcho:
    """Pending command stamp → the step that applies it; latency statistics between reports."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._pending: tuple[int, str] | None = None
        self._latencies: list[float] = []
        self.echoed = 0

    def offer(self, stamp_ns: int | None, source: str) -> None:
        """An accepted command with this stamp (ns, system clock) from topic `source`."""
        if stamp_ns is not None:
            self._pending = (stamp_ns, source)

    def take(self) -> tuple[int, str] | None:
        """After a step: the (stamp, source) of the command it applied first, once; else None."""
        p, self._pending = self._pending, None
        if p is not None:
            self.echoed += 1
        return p

    def record_latency(self, command_stamp_ns: int, published_ns: int) -> None:
        if len(self._latencies) < KEEP:
            self._latencies.append((published_ns - command_stamp_ns) * 1e-9)

    def report(self) -> dict[str, str]:
        """p50, p99 and max latency (ms) since the last report, then start a new window."""
        lat, self._latencies = self._latencies, []
        if not lat:
            return {"command_latency_p50_ms": "n/a", "command_latency_p99_ms": "n/a",
                    "command_latency_max_ms": "n/a", "commands_echoed": str(self.echoed)}
        a = np.asarray(lat) * 1e3
        p50, p99 = np.percentile(a, (50, 99))
        return {"command_latency_p50_ms": f"{p50:.3f}", "command_latency_p99_ms": f"{p99:.3f}",
                "command_latency_max_ms": f"{float(a.max()):.3f}", "commands_echoed": str(self.echoed)}

