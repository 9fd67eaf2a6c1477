"""Mutated shipped bags through every `prsm-bag` verb under a memory limit (`prsm_ros.cli.bag_fuzz`).

hypothesis chooses one to four mutations (byte flips, 4- and 8-byte fields set to edge values,
truncation, zeroed and duplicated ranges, damage aimed at record headers); derandomised, so a run
is repeatable. Each case runs in a forked child limited to DEFAULT_MEMORY_MIB of address space:
no verb may end in a traceback, a MemoryError, a signal or a hang, and `repair` must keep at least
the messages mcap's stream reader reads from the same data section. The default tier runs a
handful of cases on the smallest verbs; the `slow` tier many more through every verb.
Thousands of cases: `python -m prsm_ros.cli.bag_fuzz --cases 5000`.
"""

import functools
import multiprocessing
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from prsm_ros.cli import bag_fuzz as fuzz
from prsm_ros.bag.reader import open_bag

ROOT = Path(__file__).resolve().parent.parent
BAG = ROOT / "bags" / "light_load.mcap"
OPS = st.lists(st.tuples(st.sampled_from(fuzz.KINDS), st.integers(0, 2**32 - 1), st.integers(0, 2**64 - 1)),
               min_size=1, max_size=4)
DATA = BAG.read_bytes()
TOPICS = fuzz.export_topics(open_bag(BAG))


def _case_here(ops, verbs) -> dict:
    fuzz.preload(verbs)  # as the fuzzer does: a child under its memory limit maps no new library
    with tempfile.TemporaryDirectory(prefix="prsm-fuzz-test-") as d:
        work = Path(d)
        bag = work / BAG.name
        bag.write_bytes(fuzz.apply(DATA, ops))
        return fuzz.run_case(bag, work, fuzz.available_verbs(verbs), TOPICS,
                             memory_bytes=fuzz.DEFAULT_MEMORY_MIB << 20, timeout_s=fuzz.DEFAULT_TIMEOUT_S)


@functools.cache
def _worker() -> ProcessPoolExecutor:
    """One spawned worker for the cases: run_case forks, and this test process may hold threads
    (rclpy's, Ray's from earlier tests) whose locks a fork would copy without them."""
    return ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"))


def _case(ops, verbs) -> dict:
    return _worker().submit(_case_here, ops, verbs).result(timeout=20 * fuzz.DEFAULT_TIMEOUT_S)


@pytest.fixture(scope="module", autouse=True)
def _stop_worker():
    yield
    if _worker.cache_info().currsize:
        _worker().shutdown(wait=True, cancel_futures=True)


@pytest.mark.slow
@settings(max_examples=4, derandomize=True, deadline=None, suppress_health_check=list(HealthCheck))
@given(OPS)
def test_mutated_bags_through_info_check_and_repair(ops):
    assert _case(ops, ("info", "check", "repair")) == {}, ops


@pytest.mark.slow
# 20 cases here (about a minute); thousands behind the command in the module doc
@settings(max_examples=20, derandomize=True, deadline=None, suppress_health_check=list(HealthCheck))
@given(OPS)
def test_mutated_bags_through_every_verb(ops):
    assert _case(ops, fuzz.VERBS) == {}, ops


@pytest.mark.slow
def test_the_fuzzer_sees_a_traceback_a_hang_and_a_short_repair(tmp_path, monkeypatch):
    """The oracle itself: a verb that raises, one that never ends, and a repair that keeps fewer
    messages than the stream reader are each reported (by stand-ins for main and the counter)."""
    import time
    bag = tmp_path / BAG.name
    bag.write_bytes(DATA)

    def fake_main(argv):
        if argv[0] == "layout":
            raise KeyError("shape")
        if argv[0] == "report":
            time.sleep(60)
        return 0

    monkeypatch.setattr("prsm_ros.cli.bag.main", fake_main)  # stand-ins: they take no lock a fork could copy
    monkeypatch.setattr(fuzz, "repaired_count", lambda path: 1)
    (tmp_path / "repair.mcap").write_bytes(b"")
    found = fuzz.run_case(bag, tmp_path, ("layout", "repair", "report"), TOPICS, memory_bytes=2 << 30, timeout_s=5)
    assert found["layout"].startswith("traceback: KeyError")
    assert found["repair"] == "kept 1 message(s), the stream reader reads 2501"
    assert found["report"].startswith("hang")

