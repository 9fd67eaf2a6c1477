"""One embedded Ray for a test module: its own short temp dir (unix socket paths stay short), 2 CPUs,
no dashboard, shut down and removed after the module. Import the fixture into a test module."""

from __future__ import annotations

import shutil
import tempfile

import pytest


@pytest.fixture(scope="module")
def embedded_ray():
    ray = pytest.importorskip("ray")
    tmp = tempfile.mkdtemp(prefix="prsmray-", dir="/tmp")
    ray.init(num_cpus=2, _temp_dir=tmp, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
