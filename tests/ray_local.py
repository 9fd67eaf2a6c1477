"""One embedded Ray for the whole test session: its own short temp dir (unix socket paths stay short),
2 CPUs, no dashboard, shut down and removed at the end. Import the fixture into a test module; a
module that finds Ray already started by another uses it (Ray takes seconds to start)."""

from __future__ import annotations

import shutil
import tempfile

import pytest


@pytest.fixture(scope="session")
def embedded_ray():
    import ray  # the test extra installs it: a missing Ray is a failure, not a skip
    if ray.is_initialized():  # started by this fixture for an earlier module: its teardown stops it
        yield
        return
    tmp = tempfile.mkdtemp(prefix="prsmray-", dir="/tmp")
    # workers at normal priority, as prsm-sweep starts them: Ray's default niceness starves them on a busy machine
    ray.init(num_cpus=2, _temp_dir=tmp, include_dashboard=False, logging_level="ERROR", log_to_driver=False,
             _system_config={"worker_niceness": 0})
    try:
        yield
    finally:
        ray.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
