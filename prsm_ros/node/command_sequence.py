"""Commands a writer sent that the node never took: gaps in each writer's publication sequence numbers.

A command reader keeps a bounded queue (keep-last); when a controller publishes faster than the
node takes, the oldest waiting commands are replaced before any step sees them. They never reach
the gate or the bag, and DDS does not report them. Every sample carries its writer's publication
sequence number (rclpy's message info `publication_sequence_number`, one counter per writer), so
the number of commands superseded in the queue is the sum of the gaps between consecutive taken
samples of each writer (from 1 for its first taken sample: a command a writer sent before the
node's reader matched it is counted too, as never taken): exact, without recording anything
extra, at one dictionary look-up per command. A writer's gid (`publisher_gid`) tells writers apart; middlewares that give no sequence
number leave the count at zero and say so (`supported`).
"""

from __future__ import annotations

from collections import defaultdict


class SupersededCounter:
    """`observe(topic, info)` for every command taken; `total` and `by_topic` count the gaps."""

    MAX_WRITERS = 1024  # writers remembered; beyond that the oldest is forgotten (a gap may go uncounted)

    def __init__(self) -> None:
        self._last: dict[bytes, int] = {}
        self.total = 0
        self.by_topic: dict[str, int] = defaultdict(int)
        self.supported = True

    def observe(self, topic: str, info: dict | None) -> int:
        """The commands of this sample's writer missed since its previous taken one (its first: since 1)."""
        seq = (info or {}).get("publication_sequence_number")
        gid = (info or {}).get("publisher_gid")
        data = gid.get("data") if isinstance(gid, dict) else None
        if not isinstance(seq, int) or not data:
            self.supported = False
            return 0
        key = bytes(data)
        last = self._last.pop(key, None)  # re-inserted last: the dict stays in order of use
        self._last[key] = seq
        if len(self._last) > self.MAX_WRITERS:
            del self._last[next(iter(self._last))]
        # a writer numbers its samples from 1: those before its first taken one were missed too
        gap = seq - (last if last is not None else 0) - 1 if seq > (last or 0) else 0
        if gap:
            self.total += gap
            self.by_topic[topic] += gap
        return gap

    def reset(self) -> None:
        """Counts to zero (a ~/reset); the writers' last numbers stay, so no gap is counted twice."""
        self.total = 0
        self.by_topic.clear()

    def report(self) -> dict[str, str]:
        """For /diagnostics."""
        if not self.supported and not self._last:
            return {"commands_superseded": "unknown (the middleware gives no publication sequence numbers)"}
        return {"commands_superseded": str(self.total),
                "commands_superseded_by_topic": ", ".join(f"{k}: {v}" for k, v in sorted(self.by_topic.items()))}
