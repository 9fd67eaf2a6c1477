"""The environment every test runs in, whatever the developer's shell holds (hermetic tests).

Set in `pytest_configure`, before any test module is imported: several modules build the
environment of their child processes at import time (`ros_procs.ros_test_env`, module-level
`ENV` dicts), so a fixture would come too late for them. Tests that need another value still set
it themselves (e.g. RERUN=off for node processes, a per-module ROS_DOMAIN_ID in `ros_procs`).

- Rerun on by default (a shell's RERUN=off would silently turn every sink off).
- ROS 2 on this machine only, over the one RMW the `ros` extra installs, on a domain of this
  pytest process; nothing from the shell that changes discovery, security, logging or QoS.
- SIGINT handled (not ignored) in this process, so the children the tests start can be stopped with
  Ctrl-C: a shell starting pytest in the background (`pytest &`, nohup) sets SIGINT to ignored,
  and an ignored signal is inherited across exec, so every Ctrl-C test would wait out its run.
"""

from __future__ import annotations

import os
import signal

from ros_domains import domain_id

# The RMW the `ros` extra installs; a shell's RMW_IMPLEMENTATION=rmw_cyclonedds_cpp would fail to load.
RMW = "rmw_fastrtps_cpp"

HERMETIC_ENV = {
    "ROS_DOMAIN_ID": str(domain_id("conftest")),  # this process's; ros_procs picks one per module the same way
    "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    "RMW_IMPLEMENTATION": RMW,
    # Fast DDS's shared-memory transport logs "Failed init_port …: open_and_lock_file failed" to stderr
    # when many participants start at once (it then picks another port): harmless, but it breaks the
    # tests that read a refused start-up's stderr as exactly one line. Loopback UDP has no such race.
    "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4",
    # an embedded Ray on loopback only (prsm_ros.ray_runner.LOCAL_ONLY_ENV), read when Ray is imported:
    # test modules import Ray before their fixtures start it
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    # set before numpy loads here, as every prsm command sets it (prsm_ros/__init__.py): scipy's expm behind
    # a model's friction work form differs in the last bit with OpenBLAS's thread count, and the tests
    # compare runs in this process with runs in the processes it starts bit for bit
    "OPENBLAS_NUM_THREADS": "1",
}

# Removed: each changes what a test sees (discovery peers, a DDS profile, security enclaves, log
# routing to stdout or a changed log format the tests read, Rerun forced off, a debug traceback).
CLEARED = (
    "RERUN", "PRSM_DEBUG",
    "ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS", "ROS_DISCOVERY_SERVER", "ROS_SUPER_CLIENT",
    "ROS_SECURITY_ENABLE", "ROS_SECURITY_STRATEGY", "ROS_SECURITY_KEYSTORE", "ROS_SECURITY_ENCLAVE_OVERRIDE",
    "ROS_DISABLE_LOANED_MESSAGES", "FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE",
    "RMW_FASTRTPS_USE_QOS_FROM_XML", "RMW_FASTRTPS_PUBLICATION_MODE",
    "CYCLONEDDS_URI", "RCUTILS_LOGGING_USE_STDOUT", "RCUTILS_LOGGING_BUFFERED_STREAM",
    "RCUTILS_CONSOLE_OUTPUT_FORMAT", "RCUTILS_COLORIZED_OUTPUT",
)


def pytest_configure(config) -> None:
    # A Python handler (unlike SIG_IGN) is reset to the default at exec, where Python installs its own.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for name in CLEARED:
        os.environ.pop(name, None)
    os.environ.update(HERMETIC_ENV)
