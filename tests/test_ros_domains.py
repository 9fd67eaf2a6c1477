"""The tests' ROS_DOMAIN_IDs (`ros_domains.domain_id`): inside 1..232 (the domains whose DDS ports fit), one
per salt, and in disjoint slices for the pytest-xdist workers `.ci/run` runs the slow tier in, so two
workers' nodes never share a domain. Oracle: the slices counted by hand (232 domains, two workers: 1..116
and 117..232)."""

from __future__ import annotations

import pytest

from ros_domains import domain_id


@pytest.mark.parametrize(("workers", "worker", "lo", "hi"), [
    ("", "", 1, 232),        # one pytest process, no xdist
    ("2", "gw0", 1, 116),
    ("2", "gw1", 117, 232),
    ("3", "gw2", 155, 231),  # 232 // 3 = 77 domains each
])
def test_each_worker_takes_its_own_slice(monkeypatch, workers, worker, lo, hi):
    for name, value in (("PYTEST_XDIST_WORKER_COUNT", workers), ("PYTEST_XDIST_WORKER", worker)):
        if value:
            monkeypatch.setenv(name, value)
        else:
            monkeypatch.delenv(name, raising=False)
    ids = {domain_id(f"module-{k}") for k in range(500)}
    assert min(ids) >= lo and max(ids) <= hi
    assert len(ids) > (hi - lo + 1) // 2  # the salt spreads modules over the slice
