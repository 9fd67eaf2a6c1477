"""Long step requests run on their own thread, in slices, so no request can hold the node.

`~/step` may ask for up to 10,000,000 steps and a lockstep command for up to `lockstep_steps`
(1,000,000): minutes of work. Run inside the executor, that work would keep every service
unanswered and SIGTERM unheeded until it ended. Here the work is a `StepJob` handed to one worker
thread, which runs it in slices of about SLICE_S, taking the node's lock for one slice at a time:
between slices services answer, commands arrive, and a stop ends the job within one slice.

A request waits for its job up to `wait_or_detach`'s timeout (`~/step`: INLINE_WAIT_S, so work
of up to a second is answered when done, as before); a job still running then is *detached*: the
request answers "accepted" at once, and `on_detached_done` runs when the job ends (the node posts
an event). Jobs run one after another in the order submitted.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

INLINE_WAIT_S = 1.0   # a request's work up to this long is answered when done
STEP_REQUEST = "~/step"  # StepJob.what of a ~/step request (it runs while paused; lockstep jobs while not)
INLINE_STEPS = 1000   # lockstep: a command's steps up to this many run at once in the executor (≲ 0.1 s)
SLICE_S = 0.01        # work per slice (the node's lock is held that long at most, plus one step)
# Lockstep work waiting on the jobs thread, at most: two of the largest command's batches
# (lockstep_steps <= 1,000,000) and this many jobs. A command beyond it is recorded and offered to
# the gate as any other, but advances no time: refused (once per writer on ~/events, counted on
# /diagnostics), so a controller that sends faster than the node steps cannot grow the queue, and
# the node stops stepping soon after the controller stops sending.
LOCKSTEP_BACKLOG_STEPS = 2_000_000
LOCKSTEP_BACKLOG_JOBS = 1000
STOP_JOIN_S = 1.0


@dataclass
class StepJob:
    steps: int
    what: str                      # who asked ("~/step", "lockstep command")
    done: int = 0                  # steps done so far
    stopped: str | None = None     # why it ended before `steps` (None: all done, or still running)
    finished: threading.Event = field(default_factory=threading.Event)
    detached: bool = False         # its request was answered before it ended

    @property
    def remaining(self) -> int:
        return self.steps - self.done


def request_refused(session, jobs: StepJobs) -> str | None:
    """Why a ~/step request is refused now (None: it may run): only while paused, not faulted, one at a time."""
    if not session.paused:
        return "not paused: ~/step works only while paused (call ~/pause true first)"
    if session.fault is not None:
        return f"faulted: {session.fault}"
    return "a step request is still running (~/events reports step_done)" if jobs.busy else None


def stop_reason(job: StepJob, session, stopping: bool) -> str | None:
    """Why `job` must end before its next slice (None: go on). A ~/step job runs while paused, a
    lockstep job while running; neither runs on a fault or while the node stops."""
    if stopping:
        return "the node is stopping"
    if (job.what == STEP_REQUEST) != session.paused:
        return f"{'resumed' if job.what == STEP_REQUEST else 'paused'} before the steps were done"
    return f"faulted: {session.fault}" if session.fault is not None else None


def answer(job: StepJob, ended: bool, time_s: float) -> tuple[bool, str]:
    """(success, message) for the request that submitted `job`; `ended`: it ended before the answer."""
    if not ended:
        return True, (f"accepted: {job.steps} steps run in the background ({job.done} done so far); "
                      "~/events reports step_done when they end")
    return job.stopped is None, (f"stepped {job.done} of {job.steps} steps to t = {time_s:.6f} s"
                                 + (f" ({job.stopped})" if job.stopped else ""))


def done_event(job: StepJob, time_s: float) -> dict:
    """The `~/events` entry (severity, code, message, details) for a detached job that has ended."""
    return {"severity": "info" if job.stopped is None else "warn", "code": "step_done",
            "message": (f"{job.what}: {job.done} of {job.steps} steps done at t = {time_s:.6f} s"
                        + (f" ({job.stopped})" if job.stopped else "")),
            "details": {"steps": job.steps, "done": job.done, "stopped": job.stopped or ""}}


class StepJobs:
    """One worker thread running StepJobs in slices.

    `run_slice(job, n)` does up to `n` steps of `job` (taking whatever lock it needs) and returns
    how many it did, with a reason as second value when the job must end early (a fault, a
    resume, a stop). `on_detached_done(job)` runs on the worker thread after a detached job ends.
    """

    def __init__(self, run_slice: Callable[[StepJob, int], tuple[int, str | None]],
                 on_detached_done: Callable[[StepJob], None], stop: threading.Event) -> None:
        self._run_slice = run_slice
        self._on_detached_done = on_detached_done
        self._stop = stop
        self._cond = threading.Condition()
        self._queue: deque[StepJob] = deque()
        self._current: StepJob | None = None
        self._thread: threading.Thread | None = None
        self._per_slice = 1.0  # steps per slice, adapted to SLICE_S from what the last slice took
        self.refused_lockstep = 0

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._current is not None or bool(self._queue)

    def backlog(self) -> tuple[int, int]:
        """(jobs waiting or running, steps they still have to do)."""
        with self._cond:
            jobs = [*self._queue, *([self._current] if self._current else [])]
            return len(jobs), sum(j.remaining for j in jobs)

    def refuse_lockstep(self, steps: int) -> str | None:
        """Why a lockstep command's `steps` may not join the backlog now (None: they may)."""
        jobs, waiting = self.backlog()
        if jobs >= LOCKSTEP_BACKLOG_JOBS or waiting + steps > LOCKSTEP_BACKLOG_STEPS:
            self.refused_lockstep += 1
            return (f"lockstep backlog full ({jobs} requests, {waiting} steps waiting; at most "
                    f"{LOCKSTEP_BACKLOG_JOBS} and {LOCKSTEP_BACKLOG_STEPS} steps): this command advances no time; "
                    "wait for the state of the last one before sending the next")
        return None

    def report(self) -> dict[str, int]:
        """For /diagnostics: the backlog now and the lockstep commands refused for it."""
        jobs, waiting = self.backlog()
        return {"step_jobs_waiting": jobs, "step_jobs_steps_waiting": waiting,
                "lockstep_commands_refused_backlog": self.refused_lockstep}

    def submit(self, steps: int, what: str) -> StepJob:
        job = StepJob(steps, what)
        with self._cond:
            self._queue.append(job)
            if self._thread is None:
                self._thread = threading.Thread(target=self._work, name="prsm-step-jobs", daemon=True)
                self._thread.start()
            self._cond.notify()
        return job

    def wait_or_detach(self, job: StepJob, timeout_s: float) -> bool:
        """Wait up to `timeout_s` for `job`; True when it ended, else it is detached (False)."""
        if job.finished.wait(timeout_s):
            return True
        with self._cond:
            if job.finished.is_set():
                return True
            job.detached = True
            return False

    def stop(self, timeout_s: float = STOP_JOIN_S) -> bool:
        """Wake the worker (the node's stop event is set) and wait for it; True when it ended."""
        with self._cond:
            self._cond.notify_all()
            thread = self._thread
        if thread is None:
            return True
        thread.join(timeout_s)
        return not thread.is_alive()

    def _work(self) -> None:
        import time
        while True:
            with self._cond:
                while not self._queue and not self._stop.is_set():
                    self._cond.wait()
                if self._stop.is_set():
                    for job in [*self._queue, *([self._current] if self._current else [])]:
                        job.stopped = job.stopped or "the node is stopping"
                        job.finished.set()
                    self._queue.clear()
                    return
                job = self._current = self._queue.popleft()
            while job.remaining > 0 and job.stopped is None:
                if self._stop.is_set():
                    job.stopped = "the node is stopping"
                    break
                n = max(1, min(job.remaining, int(self._per_slice)))
                t0 = time.perf_counter()
                did, why = self._run_slice(job, n)
                took = time.perf_counter() - t0
                job.done += did
                if did and took > 0:
                    self._per_slice = min(max(did * SLICE_S / took, 1.0), 1e6)
                if why is not None or did < n:
                    job.stopped = why or "stepping stopped"
            with self._cond:
                self._current = None
                job.finished.set()
                detached = job.detached
            if detached:
                self._on_detached_done(job)
