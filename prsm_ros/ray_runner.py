"""Ray on this machine or a cluster: join or start it, and leave it as found.

The generic part of every Ray user here (studies, tuning, the bag fleet report): an embedded Ray
listens on loopback only and has its own temp dir; a cluster is reached by address after a TCP
check, so a wrong address is one line, not Ray's retries.
"""

from __future__ import annotations

import os
import shutil
import socket
import tempfile

from prsm_sim.errors import PrsmError

# An embedded Ray is for this machine only. Ray takes the node's address from the network (its
# route to the outside) and its gRPC servers (GCS, raylet, object manager, workers) then listen
# on every interface; with cluster mode off (Ray's switch for single-machine platforms, read when
# Ray is imported and inherited by the processes it starts) the node address is the loopback
# one and every server listens on 127.0.0.1 only. Token authentication, which Ray 2.60 turns on
# for a new local cluster unless RAY_AUTH_MODE says otherwise, guards those ports against other
# users of this machine.
LOCAL_ONLY_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0"}
LOOPBACK = "127.0.0.1"


class RayUnavailable(PrsmError, ValueError):
    """Ray could not be started or reached, or would listen beyond loopback."""


def reachable(address: str, timeout_s: float = 3.0) -> None:
    """RayUnavailable unless `address` is HOST:PORT with something listening there."""
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit():
        raise RayUnavailable(f"--address {address!r}: expected HOST:PORT of a Ray head (e.g. 10.0.0.5:6379) or auto")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise RayUnavailable(f"--address {address}: no Ray head reachable there ({e.strerror or e})") from None


def connect(address: str | None, workers: int | None):
    """Start or join Ray → (ray module, shutdown-when-done, temp dir to remove).

    An already initialised Ray (a caller's own, e.g. a test's) is used as it is. An embedded
    Ray gets its own short temp dir (unix socket paths are limited to ~100 characters), no
    dashboard and listens on loopback only (`start_embedded`); `workers` caps its CPUs.
    """
    if not address:
        os.environ.update(LOCAL_ONLY_ENV)  # before Ray is imported (see start_embedded)
    try:
        import ray
    except ImportError as e:
        raise ImportError("ray is not installed; install the sweep extra: pip install 'prsm[sweep]'", name="ray") from e
    if ray.is_initialized():
        return ray, False, None
    if address and address != "auto":
        reachable(address)
    tmp = None
    try:
        if address:
            ray.init(address=address, logging_level="ERROR", log_to_driver=False)
        else:
            tmp = tempfile.mkdtemp(prefix="prsmray-", dir="/tmp")
            start_embedded(workers or os.cpu_count() or 1, tmp)
    except Exception as e:  # Ray's own errors (ConnectionError, RuntimeError, ...): one line for the user
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        hint = " (a head with token authentication needs RAY_AUTH_MODE=token here)" if address else ""
        raise RayUnavailable(f"cannot {'join Ray at ' + address if address else 'start Ray'}: {first}{hint}") from None
    return ray, True, tmp


def start_embedded(num_cpus: int, temp_dir: str) -> None:
    """`ray.init` of a Ray on this machine only (loopback, no dashboard, workers at normal priority).

    RayUnavailable when Ray would still listen on another address.
    """
    os.environ.update(LOCAL_ONLY_ENV)  # before Ray is imported, and for the processes it starts
    import ray
    # worker_niceness 0: Ray nices its workers (15) by default, which starves a study's runs
    # behind any normal-priority process on a busy machine; here the tasks are the work
    ray.init(num_cpus=num_cpus, _temp_dir=temp_dir, include_dashboard=False, _node_ip_address=LOOPBACK,
             logging_level="ERROR", log_to_driver=False, _system_config={"worker_niceness": 0})
    node_ip = ray.util.get_node_ip_address()
    if node_ip != LOOPBACK:
        ray.shutdown()
        # Ray reads the switch when it is imported: a caller (a notebook) imported it before this ran
        raise RayUnavailable(f"the embedded Ray would listen on {node_ip}, not only on {LOOPBACK}: set "
                             f"{', '.join(f'{k}={v}' for k, v in LOCAL_ONLY_ENV.items())} in the environment "
                             "before Ray is imported")


def disconnect(ray, owned: bool, tmp: str | None) -> None:
    """Undo `connect`: shut down a Ray it started and remove its temp dir."""
    if owned:
        ray.shutdown()
    if tmp:
        shutil.rmtree(tmp, ignore_errors=True)
