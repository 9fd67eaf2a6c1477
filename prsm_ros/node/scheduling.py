"""Scheduling for every thread the realtime loop depends on, where the OS allows.

The step thread raises itself (`stepping.request_realtime_priority`); the threads created after the
node's set-up inherit the executor thread's policy. The middleware's own threads (Fast DDS's
receive, event and discovery threads) exist before either and stay at normal priority, so on a busy
machine a command could wait in a socket while a CPU hog runs. `raise_process_threads` puts every
thread of this process that is still at normal priority under SCHED_FIFO at `priority`. They all
block on sockets, conditions or timers, so they cannot starve the machine.
"""

from __future__ import annotations

import os


def raise_process_threads(priority: int) -> str:
    """SCHED_FIFO `priority` for every thread of this process under SCHED_OTHER; what happened, in words."""
    if priority <= 0:
        return "normal (realtime_priority 0)"
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError as e:  # not Linux
        return f"normal (threads not listed: {e.strerror or e})"
    raised, refused = 0, ""
    for tid in tids:
        try:
            if os.sched_getscheduler(tid) != os.SCHED_OTHER:
                continue  # already raised (the step thread, or by us)
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
            raised += 1
        except ProcessLookupError:
            continue  # the thread ended meanwhile
        except (OSError, AttributeError) as e:
            refused = getattr(e, "strerror", None) or str(e)
            break
    if refused:
        return f"normal (SCHED_FIFO {priority} refused: {refused})"
    return f"SCHED_FIFO {priority} ({raised} threads incl. middleware)"
