"""Scheduling for every thread the realtime loop depends on, where the OS allows.

The step thread raises itself (`stepping.request_realtime_priority`); the threads created after the
node's set-up inherit the executor thread's policy. The middleware's own threads (Fast DDS's
receive, event and discovery threads) exist before either and stay at normal priority, so on a busy
machine a command could wait in a socket while a CPU hog runs. `raise_process_threads` puts every
thread of this process that is still at normal priority under SCHED_FIFO at `priority`. They all
block on sockets, conditions or timers, so they cannot starve the machine.

`step_thread_cpu` gives the step thread a CPU of its own: the thread that builds the node moves itself
to the other CPUs before it starts anything (`pin_calling_thread`), so every thread and process
started after it (recorder, its writer process, Rerun, the step thread) starts there; the step thread
then moves itself onto its CPU, and `move_process_threads` moves the middleware's threads, which exist
before the node's set-up, off it. The step thread's CPU then serves it alone (nothing queued before
it at a deadline, nothing else in its caches): on the 2-core bench machine, in four runs of
`prsm-bench --only realtime`, the node's CPU was 12.7–16.1 % of a core with it against 16.2–19.2 %
without (docs/performance.md).
"""

from __future__ import annotations

import os


def _thread_ids() -> list[int]:
    """The OS ids of this process's threads (Linux's /proc; OSError elsewhere)."""
    return [int(t) for t in os.listdir("/proc/self/task")]


def raise_process_threads(priority: int) -> str:
    """SCHED_FIFO `priority` for every thread of this process under SCHED_OTHER; what happened, in words."""
    if priority <= 0:
        return "normal (realtime_priority 0)"
    try:
        tids = _thread_ids()
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


def allowed_cpus() -> frozenset[int]:
    """The CPUs this process may run on (Linux's affinity mask; empty where the OS does not say)."""
    try:
        return frozenset(os.sched_getaffinity(0))
    except (OSError, AttributeError):
        return frozenset()


def other_cpus(cpu: int) -> frozenset[int]:
    """The CPUs this process may run on but `cpu`: where the step thread's CPU leaves the node's other threads."""
    return allowed_cpus() - {cpu}


def cpu_list(cpus) -> str:
    """CPUs in words: "CPU 1", "CPUs 0, 2"."""
    cpus = sorted(cpus)
    return f"CPU{'s' if len(cpus) != 1 else ''} {', '.join(map(str, cpus))}"


def pin_calling_thread(cpus) -> str:
    """Run the calling thread on `cpus` only (threads it starts after inherit them); what happened, in words."""
    try:
        os.sched_setaffinity(0, cpus)
    except (OSError, AttributeError) as e:
        return f"any CPU ({cpu_list(cpus)} refused: {getattr(e, 'strerror', None) or e})"
    return cpu_list(cpus)


def move_process_threads(cpus, keep: frozenset[int] = frozenset()) -> str:
    """Every thread of this process but those whose ids are in `keep` onto `cpus`; what happened, in words."""
    try:
        tids = _thread_ids()
    except OSError as e:  # not Linux
        return f"any CPU (threads not listed: {e.strerror or e})"
    moved = 0
    for tid in tids:
        if tid in keep:
            continue
        try:
            os.sched_setaffinity(tid, cpus)
            moved += 1
        except ProcessLookupError:
            continue  # the thread ended meanwhile
        except (OSError, AttributeError) as e:
            return f"any CPU ({cpu_list(cpus)} refused: {getattr(e, 'strerror', None) or e})"
    return f"{cpu_list(cpus)} ({moved} threads incl. middleware)"
