"""One embedded Ray for the whole test session: its own short temp dir (unix socket paths stay short),
2 CPUs, no dashboard, shut down and removed at the end. Import the fixture into a test module; a
module that finds Ray already started by another uses it (Ray takes seconds to start)."""

from __future__ import annotations

import os
import shutil
import tempfile

import pytest


@pytest.fixture(scope="session")
def embedded_ray():
    from prsm_ros.ray_runner import LOCAL_ONLY_ENV, start_embedded
    os.environ.update(LOCAL_ONLY_ENV)  # before Ray is imported (see start_embedded)
    import ray  # the test extra installs it: a missing Ray is a failure, not a skip
    if ray.is_initialized():  # started by this fixture for an earlier module: its teardown stops it
        yield
        return
    tmp = tempfile.mkdtemp(prefix="prsmray-", dir="/tmp")
    start_embedded(2, tmp)  # as prsm-sweep starts it: loopback only, workers at normal priority
    try:
        yield
    finally:
        ray.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
