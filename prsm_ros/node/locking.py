"""The node's lock, which long work hands to waiting callbacks between its slices.

Python's lock is not fair: a thread that releases it and takes it again at once (the step-jobs
thread between two slices of a ten-million-step request) keeps it from a thread already waiting,
which must first get the GIL back; on a busy machine the executor's services and timers then wait
for the whole request. `NodeLock` counts who waits, and `let_waiters_first` (called by the jobs
thread before each slice) sleeps until they have had their turn.
"""

from __future__ import annotations

import threading
import time

YIELD_S = 5e-5  # a waiting thread is looked for again after this long
MAX_YIELD_S = 0.5  # the longest a slice waits for others: callbacks that wait for ever cannot stop the work


class NodeLock:
    """A mutex (`with lock:`) that knows how many threads wait for it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        # the bare mutex, for the realtime step thread's once-a-step hold (it sleeps between steps, so it
        # never keeps a waiter out; the counting `with` costs about 0.7 µs more a time)
        self.raw = self._lock
        self._count_lock = threading.Lock()
        self.waiting = 0

    def __enter__(self) -> NodeLock:
        if self._lock.acquire(blocking=False):  # the common case: nobody holds it, nothing to count
            return self
        with self._count_lock:
            self.waiting += 1
        try:
            self._lock.acquire()
        finally:
            with self._count_lock:
                self.waiting -= 1
        return self

    def __exit__(self, *exc) -> None:
        self._lock.release()

    def locked(self) -> bool:
        return self._lock.locked()

    def let_waiters_first(self) -> None:
        """Sleep while another thread waits for the lock (at most MAX_YIELD_S)."""
        end = time.monotonic() + MAX_YIELD_S
        while self.waiting > 0 and time.monotonic() < end:
            time.sleep(YIELD_S)
