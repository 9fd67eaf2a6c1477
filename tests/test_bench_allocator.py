"""`prsm-bench` measures every figure under one allocator (`bench.common.steady_allocator`).

Oracle: the kernel's own count of the process's minor page faults (`getrusage`), in a fresh interpreter.
Temporaries of 1 MiB, several alive at once and then freed (a batch run's column arithmetic in small), are
given back to the OS at glibc's default thresholds (mapped apart from the heap, or trimmed off its top), so
every page of them faults again at each round; once the bench has fixed the thresholds their memory stays
with the process, and the same rounds fault (almost) no more.
"""

from __future__ import annotations

import json
import platform
import subprocess
import sys

import pytest

CHILD = r"""
import json, resource, sys
import numpy as np
from prsm_ros.bench.common import steady_allocator

def faults(cycles=20, alive=8, n=1 << 17):
    # a batch run's column arithmetic in small: several 1 MiB temporaries alive at once, then all freed
    def cycle():
        a = [np.ones(n) for _ in range(alive)]
        del a
    cycle()  # the first one faults wherever its memory comes from
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(cycles):
        cycle()
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

default = faults()
said = steady_allocator()
print(json.dumps({"default": default, "steady": faults(), "said": said}))
"""


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                    reason="the thresholds are glibc malloc's")
def test_the_bench_fixes_the_allocator_so_large_temporaries_stop_faulting_pages_at_every_run():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=120, check=True)
    got = json.loads(out.stdout)
    assert got["said"].startswith("glibc malloc: mmap threshold 32 MB"), got
    pages = 20 * 8 * (1 << 20) // 4096  # 20 cycles of 8 arrays of 256 pages each (4 KiB pages)
    assert got["default"] >= pages // 2, got  # given back at each free (mapped, or trimmed off the heap's top)
    assert got["steady"] <= pages // 50, got  # kept: its pages stay mapped
