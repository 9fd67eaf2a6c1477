"""Wall-clock pacing for the node's step thread, pure Python (no ROS), so it is tested without DDS.

- `DeadlinePacer`: realtime pacing on absolute deadlines t0 + k·period (no drift: lateness is
  never folded into the next period), with catch-up for late steps, a bound on how far it
  catches up, and the measured real-time factor and overruns.
- `every_n_steps`: publish decimation for a rate in Hz.
- `reduce_timer_slack`, `request_realtime_priority`: the step thread's scheduling.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field


def every_n_steps(rate_hz: float, update_rate_hz: float) -> int:
    """Publish every n-th step for `rate_hz` (0 or >= update rate: every step)."""
    if rate_hz <= 0 or rate_hz >= update_rate_hz:
        return 1
    return max(1, round(update_rate_hz / rate_hz))


@dataclass
class PacerStats:
    """Realtime pacing figures since start (or `DeadlinePacer.restart`)."""

    steps: int = 0
    overruns: int = 0  # steps that started more than one period after their deadline
    skipped_periods: int = 0  # periods dropped when too far behind to catch up
    lateness_s: list[float] = field(default_factory=list)  # per-step start − deadline (bounded ring)


class DeadlinePacer:
    """Absolute-deadline pacing: step k is due at t0 + k·period/rtf (wall clock, monotonic).

    `wait()` sleeps until the next deadline and returns; a late step is not waited for (catch-up),
    and when the loop falls more than `max_catchup_periods` behind it jumps the schedule forward
    (counting the skipped periods) instead of running a burst. Sleeping uses the monotonic clock
    with the thread's timer slack reduced to 1 µs (Linux prctl), so wake-ups are not rounded up by
    the default 50 µs slack.

    Thread safety: the step thread calls `wait`/`count_step` while the executor thread calls
    `restart` and `set_rate` (a reset, a parameter change), so the schedule and the counters are
    behind one lock, never held while sleeping. A restart during a sleep is seen on waking: the
    step then waits on the new schedule (so a rate change takes effect within one old period).
    Read the figures with `snapshot()`; `stats` is replaced on every restart.
    """

    def __init__(self, period_s: float, real_time_factor: float = 1.0, *, max_catchup_periods: int = 50,
                 clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep,
                 keep_lateness: int = 200_000, spin_s: float = 0.0) -> None:
        self.nominal_period_s = period_s
        self.spin_s = spin_s
        self.max_catchup_periods = max_catchup_periods
        self._clock, self._sleep = clock, sleep
        self._keep = keep_lateness
        self._lock = threading.Lock()
        self._generation = 0  # bumped by every restart: a wait() that slept across one re-plans
        self.set_rate(real_time_factor)

    def set_rate(self, real_time_factor: float) -> None:
        """Change the real-time factor; the schedule restarts from now so no burst or gap follows."""
        with self._lock:
            self.real_time_factor = real_time_factor
            self.period_s = self.nominal_period_s / real_time_factor
            self._restart_locked()

    def restart(self) -> None:
        """New schedule from now (after a pause, a reset or a rate change)."""
        with self._lock:
            self._restart_locked()

    def _restart_locked(self) -> None:
        self._t0 = self._clock()
        self._k = 0
        self._generation += 1
        self.stats = PacerStats()

    @property
    def next_deadline(self) -> float:
        with self._lock:
            return self._t0 + (self._k + 1) * self.period_s

    def wait(self) -> float:
        """Sleep until the next step is due; returns its lateness in seconds (>= 0 when on time)."""
        while True:
            with self._lock:
                generation, due = self._generation, self._t0 + (self._k + 1) * self.period_s
            now = self._clock()
            if due - self.spin_s > now:
                self._sleep(due - self.spin_s - now)
                now = self._clock()
            while now < due:  # the last spin_s: poll the clock instead of trusting the wake-up latency
                now = self._clock()
            with self._lock:
                if generation == self._generation:
                    return self._account_locked(now - due)
            # restarted (reset, new rate) while asleep: wait for the first deadline of the new schedule

    def _account_locked(self, late: float) -> float:
        period = self.period_s
        if late > self.max_catchup_periods * period:
            skip = int(late // period)
            self._k += skip
            self.stats.skipped_periods += skip
            late -= skip * period
        if late > period:
            self.stats.overruns += 1
        self._k += 1
        self.stats.steps += 1
        lat = self.stats.lateness_s
        if len(lat) >= self._keep:
            del lat[: self._keep // 2]
        lat.append(late)
        return late

    def count_step(self) -> int:
        """Count a step taken without pacing (fast mode); returns the steps since the last restart."""
        with self._lock:
            self.stats.steps += 1
            return self.stats.steps

    def snapshot(self, lateness: bool = False) -> PacerStats:
        """A consistent copy of the figures (the lateness ring only when asked: it can be long)."""
        with self._lock:
            s = self.stats
            return PacerStats(s.steps, s.overruns, s.skipped_periods, list(s.lateness_s) if lateness else [])

    def achieved_rtf(self, sim_dt_s: float) -> float:
        """Simulated time over wall time since the schedule started."""
        with self._lock:
            wall, steps = self._clock() - self._t0, self.stats.steps
        return steps * sim_dt_s / wall if wall > 0 else math.nan


def reduce_timer_slack() -> bool:
    """Set this thread's timer slack to 1 ns (Linux), so sleeps wake on time; False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        pr_set_timerslack = 29
        return libc.prctl(pr_set_timerslack, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def request_realtime_priority(priority: int) -> str:
    """Put the calling thread under SCHED_FIFO at `priority` (Linux, needs CAP_SYS_NICE or an rtprio limit).

    A paced thread that sleeps most of each period loses little to this and gains on-time
    wake-ups when other processes keep the cores busy. Returns what was applied, in words.
    """
    if priority <= 0:
        return "normal (realtime_priority 0)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as e:
        return f"normal (SCHED_FIFO {priority} refused: {getattr(e, 'strerror', None) or e})"
    return f"SCHED_FIFO {priority}"
