"""One design for everything the node refuses (commands, faults, parameters): visible, and bounded.

A refusal is reported in full once per writer and reason — an event on `~/events` and a log line —
and after that only counted; /diagnostics carries the counts. So a writer that sends a refused
command ten thousand times a second costs a counter increment per message, and `~/events`, the
log and the bag get one entry from it per reason, however long it goes on. Pure Python (no ROS):
the node turns a first refusal into its event and log line.

Writers are the DDS participants commands come from (`ownership.participant_name`), or a name the
caller chooses where the middleware gives none (a service or parameter request). At most
MAX_KEYS (writer, reason) pairs are remembered; refusals beyond them are counted under
`overflow` without an event, so many writers cannot grow memory or the event stream either.
"""

from __future__ import annotations

MAX_KEYS = 256
MAX_TEXT = 300  # characters of a refusal's text kept for its event (a value quoted from input stays short)


class Refusals:
    """Counts of refusals per (writer, reason code); `refuse` says whether this one is the first."""

    def __init__(self, max_keys: int = MAX_KEYS) -> None:
        self._max_keys = max_keys
        self._counts: dict[tuple[str, str], int] = {}
        self.total = 0
        self.overflow = 0  # refusals from pairs beyond max_keys: counted only

    def refuse(self, writer: str, code: str) -> bool:
        """Count one refusal; True when it is the first of this writer for this reason (report it)."""
        self.total += 1
        key = (writer, code)
        n = self._counts.get(key)
        if n is not None:
            self._counts[key] = n + 1
            return False
        if len(self._counts) >= self._max_keys:
            self.overflow += 1
            return False
        self._counts[key] = 1
        return True

    def count(self, writer: str | None = None, code: str | None = None) -> int:
        """Refusals of a writer, a reason, or both (None: any)."""
        return sum(n for (w, c), n in self._counts.items()
                   if (writer is None or w == writer) and (code is None or c == code))

    def diagnostics(self, top: int = 10) -> dict[str, object]:
        """For /diagnostics: the total and the `top` most frequent (writer, reason) pairs with their counts."""
        ranked = sorted(self._counts.items(), key=lambda kv: -kv[1])[:top]
        return {"refusals_total": self.total,
                "refusals": "; ".join(f"{w} {c} ({n})" for (w, c), n in ranked) or "none",
                "refusals_unlisted": self.overflow}


def short(text: str) -> str:
    """`text` cut to MAX_TEXT characters for an event or log line."""
    return text if len(text) <= MAX_TEXT else text[:MAX_TEXT - 1] + "…"
