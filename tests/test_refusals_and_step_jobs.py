"""The node's refusal bookkeeping and its step jobs, pure Python (no DDS).

Oracles: counts given by construction (so many refusals sent, so many steps asked for), and the
events the jobs thread reports; waits are on events with generous ceilings, never sleeps.
"""

import threading

from prsm_ros.node.refusals import MAX_TEXT, Refusals, short
from prsm_ros.node.step_jobs import STEP_REQUEST, StepJobs, answer, done_event, stop_reason

CEILING_S = 60.0


def test_a_refusal_is_reported_once_per_writer_and_reason_then_only_counted():
    r = Refusals(max_keys=3)
    firsts = [r.refuse(w, c) for w, c in [("a", "not_owner")] * 10_000 + [("a", "malformed"), ("b", "not_owner")]]
    assert firsts.count(True) == 3 and firsts[0] and firsts[10_000] and firsts[10_001]
    assert (r.total, r.count("a"), r.count(code="not_owner")) == (10_002, 10_001, 10_001)
    assert r.refuse("c", "not_owner") is False and r.overflow == 1  # beyond max_keys: counted only
    d = r.diagnostics()
    assert d["refusals_total"] == 10_003 and d["refusals"].startswith("a not_owner (10000)")
    assert len(short("x" * 10_000)) == MAX_TEXT


class _Session:
    def __init__(self, paused: bool) -> None:
        self.paused, self.fault, self.steps = paused, None, 0


def _jobs(session: _Session, stop: threading.Event, done: list, gate: threading.Event | None = None):
    def run_slice(job, n):
        if gate is not None:
            gate.wait(CEILING_S)
        why = stop_reason(job, session, stop.is_set())
        if why:
            return 0, why
        session.steps += n
        return n, None
    return StepJobs(run_slice, done.append, stop)


def test_a_short_request_is_answered_when_done_and_a_long_one_is_detached_then_reported():
    session, stop, done = _Session(paused=True), threading.Event(), []
    jobs = _jobs(session, stop, done)
    job = jobs.submit(5_000, STEP_REQUEST)
    assert jobs.wait_or_detach(job, CEILING_S) and job.done == 5_000 and job.stopped is None
    assert answer(job, True, 5.0) == (True, "stepped 5000 of 5000 steps to t = 5.000000 s") and done == []

    gate = threading.Event()  # hold the slice: the request cannot end before its answer
    jobs = _jobs(session, stop, done, gate)
    job = jobs.submit(100, STEP_REQUEST)
    assert not jobs.wait_or_detach(job, 0.0) and job.detached
    assert answer(job, False, 0.0)[1].startswith("accepted: 100 steps")
    gate.set()
    assert job.finished.wait(CEILING_S)
    jobs.stop()
    assert done == [job] and done_event(job, 1.0)["code"] == "step_done" and job.done == 100


def test_stop_and_resume_end_a_job_between_slices():
    session, stop, done = _Session(paused=True), threading.Event(), []
    gate = threading.Event()
    jobs = _jobs(session, stop, done, gate)
    job = jobs.submit(10_000_000, STEP_REQUEST)
    session.paused = False  # resumed while the ~/step job waits for its slice
    gate.set()
    assert job.finished.wait(CEILING_S) and job.stopped == "resumed before the steps were done"
    job = jobs.submit(10_000_000, "lockstep command")  # a lockstep job runs while not paused
    stop.set()
    assert jobs.stop(CEILING_S) and job.finished.is_set() and job.stopped == "the node is stopping"
    assert job.done < 10_000_000
