"""ROS_DOMAIN_IDs for the tests: one per pytest process and salt, disjoint between pytest-xdist workers.

The slow tier runs in two pytest-xdist workers (`.ci/run`): two modules starting nodes named
`/prsm_actuator` at once on one domain would talk to each other's nodes. Each worker therefore takes
its own slice of the 232 domains the DDS port mapping allows (1..232), and within it the pid and a salt
(a module's name) pick one, so modules of one process, and concurrent pytest processes, differ too.
No imports but the standard library: `conftest.py` reads it before any test module loads numpy.
"""

from __future__ import annotations

import os
import zlib

FIRST, LAST = 1, 232  # the domain IDs whose DDS ports stay below 65535 with Fast DDS's default mapping


def domain_id(salt: str = "") -> int:
    """A ROS_DOMAIN_ID in this worker's slice of 1..232, from the pid and `salt`."""
    workers = max(1, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1))
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[:2] == "gw" and worker[2:].isdigit() else 0
    span = (LAST - FIRST + 1) // workers
    return FIRST + (index % workers) * span + (os.getpid() + zlib.crc32(salt.encode())) % span
