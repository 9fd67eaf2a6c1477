"""`McapProcessRecorder`: `McapRecorder`'s interface and promises, the writing done in a child process.

In the node, the thread recorder's Python (records, chunk indexes, the untrusted-bytes check) held
the interpreter lock the step thread waits for. Here the caller's side is the same bounded queue
(`RecorderQueue`: O(1), never blocks, exact counts); a forwarding thread, woken by a hand-over once
FORWARD_NUDGE_AFTER_S has passed since its last drain (or by its clock), builds the deferred messages and
packs what is queued into one blob (`writer_process.MESSAGE` headers and the CDR bytes) and writes it to a pipe
(`os.write` releases the lock while the bytes move); the child (`python -P -m
prsm_ros.mcap.writer_process`, started by exec, never by fork: the node has DDS threads) runs the
same `McapFile` code, so the same messages give the same bytes (a lockstep bag is still a golden
file), and holds the chunk indexes, so the memory bound is the thread recorder's.

Opening is a handshake: the child opens the file and answers within `OPEN_TIMEOUT_S`, so an
unwritable path is `error` at once, as with the thread recorder. Later failures (disk full, the
child killed) set `error` in one line; the caller is never interrupted, and every message offered
ends in exactly one of `messages_written` (the child's count of messages handed to its writer),
`messages_dropped` and `messages_malformed`. A SIGKILLed parent leaves the child an end of input
without the finish frame: it closes the file without a summary (readable to its last chunk,
`prsm-bag repair` recovers it) and exits within `writer_process.PARENT_POLL_S`.
"""

from __future__ import annotations

import atexit
import fcntl
import json
import os
import select
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from prsm_ros.mcap import schema as mcap_schema
from prsm_ros.mcap.recorder import (CLOSE_TIMEOUT_S, DEFAULT_CHUNK_SIZE, FLUSH_INTERVAL_S, MAX_WAKE_S,
                                    Deferred, RecorderQueue)
from prsm_ros.mcap.writer_process import FRAME, MESSAGE

# The forwarding thread's longest sleep between hand-overs (a producer that writes goes first:
# FORWARD_NUDGE_AFTER_S). Each wake-up costs CPU in both processes (~0.1 ms each on the bench machine,
# before any work), and the child flushes when data comes, so a chunk closes every flush interval plus
# at most this: at 1 kHz, 10 ms cost ~4 % of a core in wake-ups and hand-overs, 25 ms ~1.5 %.
FORWARD_WAKE_S = 0.025
# After a drain, the forwarding thread is woken by the first hand-over (`write_many`) this long after, rather than by
# its clock (FORWARD_WAKE_S): a paced caller's hand-over ends its step, and the step thread then sleeps until its next
# period, so the forwarder's work (the pack, the bag's deferred internal loads: ~0.1-0.2 ms for 20 steps at 1 kHz)
# holds the interpreter lock while nobody waits for it. Woken by its clock at a random moment, it held the lock
# as the step thread woke, which waited up to the switch interval (`fu2018` realtime, 20 s, jitter p99: 94-192 µs
# woken by the clock with the loads built there, 39-142 µs without them, 23-48 µs woken by the hand-over). By time,
# not by a count of steps: a fast producer (lockstep) wakes it about as often as the clock does.
FORWARD_NUDGE_AFTER_S = 0.02
OPEN_TIMEOUT_S = 60.0  # the child's start (interpreter, mcap, rclpy) and the file opened, on a busy machine
PIPE_BYTES = 1 << 20  # asked of the kernel for the pipe to the child (a full pipe blocks the forwarder only)
KILL_WAIT_S = 0.5  # reaping a child killed after a close that timed out (SIGKILL acts at once)
EXIT_WAIT_S = 5.0  # after the child's answers end, its exit status (what `error` names) on a busy machine
_F_SETPIPE_SZ = 1031  # fcntl.h (Linux)


def _frame(kind: bytes, payload: bytes) -> bytes:
    return FRAME.pack(kind, len(payload)) + payload


class McapProcessRecorder(RecorderQueue):
    """Record ROS 2 messages to MCAP from a child process, without blocking the caller.

    The arguments, methods and counts are `McapRecorder`'s (`prsm_ros.mcap.recorder`). Differences a
    caller can see: `messages_written` follows the child's reports (at most one wake-up behind), and
    a `close` that times out kills the child, leaving the file without a summary.
    """

    def __init__(self, path, *, metadata: dict[str, dict[str, str]] | None = None,
                 queue_size: int = 100_000, chunk_size: int = DEFAULT_CHUNK_SIZE,
                 flush_interval_s: float = FLUSH_INTERVAL_S, deterministic: bool = False) -> None:
        super().__init__(path, queue_size)
        self._wake_s = min(float(flush_interval_s) / 2, FORWARD_WAKE_S)
        self._nudge_after = time.monotonic() + FORWARD_NUDGE_AFTER_S
        self._index: dict[str, int] = {}  # topic → channel index in the order the child was told
        self._taken_count = 0  # messages taken from the queue for the child (under `_lock`)
        self._written = self._malformed = 0  # the child's last report (under `_lock`)
        self._settled = False  # final counts made: nothing changes them after (under `_lock`)
        self._child_done = False  # it said done or fail
        self._eof = False  # its answers ended
        self._status = bytearray()
        self._serialize: Callable[[Any], bytes] | None = None
        self._thread: threading.Thread | None = None
        opening = {"path": str(self.path), "metadata": metadata or {}, "chunk_size": int(chunk_size),
                   "deterministic": bool(deterministic), "flush_interval_s": float(flush_interval_s)}
        self._in = self._out = -1
        try:
            self._proc: subprocess.Popen | None = self._spawn()
        except OSError as e:  # no processes or descriptors left
            self._proc = None
            failure: str | None = f"the writer process could not start: {e.strerror or e}"
        else:
            failure = self._handshake(_frame(b"O", json.dumps(opening).encode()))
        if failure is not None:
            self.error = f"recording to {self.path} stopped: {failure}"
            self._settle()
            self._reap(KILL_WAIT_S)
            self._close_pipes()
            return
        self._thread = threading.Thread(target=self._run, name=f"mcap-forward:{self.path.name}", daemon=True)
        self._thread.start()
        atexit.register(self.close)

    def _spawn(self) -> subprocess.Popen:
        self._in, status_w = os.pipe()
        try:
            data_r, self._out = os.pipe()
        except OSError:
            os.close(status_w)
            raise
        try:
            fcntl.fcntl(self._out, _F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:
            pass  # the default (64 KB) only makes the forwarder block sooner
        try:
            # -P: nothing importable from the working directory; a session of its own: a terminal's Ctrl-C
            # is the parent's, which then finishes the file
            return subprocess.Popen([sys.executable, "-P", "-m", "prsm_ros.mcap.writer_process",
                                     str(data_r), str(status_w), str(os.getpid())],
                                    pass_fds=(data_r, status_w), stdin=subprocess.DEVNULL,
                                    stdout=subprocess.DEVNULL, start_new_session=True)
        finally:
            os.close(data_r)
            os.close(status_w)

    def _handshake(self, opening: bytes) -> str | None:
        """Send the open frame and wait for the child's answer; None when the file is open, else why not."""
        deadline = time.monotonic() + OPEN_TIMEOUT_S
        os.set_blocking(self._out, False)  # a child that never reads must not hold the caller past the deadline
        view = memoryview(opening)
        try:
            while view and select.select([], [self._out], [], max(deadline - time.monotonic(), 0.0))[1]:
                view = view[os.write(self._out, view):]
        except OSError:
            pass  # the child is gone: its answer (or its absence) says why
        finally:
            os.set_blocking(self._out, True)
        while True:
            line = self._next_line(max(deadline - time.monotonic(), 0.0))
            if line is None:
                return self._ended() if self._eof else f"the writer process did not answer within {OPEN_TIMEOUT_S:g} s"
            if line == "open":
                os.set_blocking(self._in, False)
                return None
            if line.startswith("error "):
                return line[6:]

    # ---- caller side (the rest is `RecorderQueue`'s) -------------------------------------------

    @property
    def messages_written(self) -> int:
        """Messages handed to the MCAP writer in the child (on disk once their chunk is flushed)."""
        return self._written

    @property
    def messages_malformed(self) -> int:
        """Bytes on an `untrusted` channel that did not deserialize as its type: not written."""
        return self._malformed

    def add_channel(self, topic: str, msg_class, qos, *, untrusted: bool = False) -> None:
        """Declare a topic before writing to it (`McapRecorder.add_channel`); the child is told its type
        name and QoS text, and whether its bytes are to be checked (`untrusted`: the child imports the class by
        that type name, from the interface's message packages only)."""
        self._declare(topic, msg_class)
        if topic in self._index:
            return
        self._index[topic] = len(self._index)
        self._queue.append(_frame(b"C", json.dumps({
            "topic": topic, "type": mcap_schema.type_name(msg_class),
            "qos": mcap_schema.offered_qos_profiles_yaml(qos), "untrusted": bool(untrusted)}).encode()))

    def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> bool:
        """`McapRecorder.close`: what is queued is written, then the summary and footer, within `timeout_s`.

        If the child has not finished by then (a stalled disk), it is killed: what it had not
        confirmed is counted as dropped, `error` says so, and the file is readable up to its last chunk."""
        if not self._closed:
            deadline = time.monotonic() + timeout_s
            self._stop_writer(self._thread, timeout_s, self._settle)
            self._reap(max(deadline - time.monotonic(), 0.0))
        return self.error is None

    # ---- forwarding thread ---------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._forward()
        except Exception as e:  # never a file left unfinished while close reports success
            self.error = self.error or f"recording to {self.path} stopped: {type(e).__name__}: {e}"
        try:
            if not self._settled_now():
                if self.error is None and not self._child_done:
                    self.error = f"recording to {self.path} stopped: {self._ended()}"
                self._settle()
        finally:
            self._close_pipes()

    def _forward(self) -> None:
        """Hand what is queued to the child every wake-up; after close, the finish frame and the child's answer."""
        queue = self._queue
        while True:
            self._wake.wait(self._wake_s)
            self._nudge_after = time.monotonic() + FORWARD_NUDGE_AFTER_S
            self._wake.clear()  # a nudge from here on is for what comes after this drain
            stopping = self._stop.is_set()
            self._read_status()
            if self._child_done or self._eof or self._settled_now():
                return
            try:
                while queue:
                    if type(queue[0]) is bytes:  # a channel declaration, kept in order with the messages
                        self._send(queue.popleft())
                    else:
                        self._send(self._pack(self._take_batch(queue)))
                if stopping:
                    self._send(_frame(b"F", b""))
                    self._finish()
                    return
            except OSError:  # the child is gone (EPIPE): its last lines, or their absence, say why
                self._read_status()
                return

    def _pack(self, entry: list) -> bytes:
        """One `M` frame: each message's header and CDR bytes (objects serialised here, as `McapFile` would)."""
        index, pack = self._index, MESSAGE.pack
        parts = []
        for topic, msg, stamp in entry:
            if type(msg) is Deferred:
                msg = msg.build()
            elif type(msg) is not bytes:
                msg = self._serializer()(msg)
            parts.append(pack(index[topic], stamp, len(msg)))
            parts.append(msg)
        body = b"".join(parts)
        return FRAME.pack(b"M", len(body)) + body

    def _serializer(self) -> Callable[[Any], bytes]:
        """rclpy's serializer (what `McapFile` uses for message objects), imported when first needed."""
        if self._serialize is None:
            from rclpy.serialization import serialize_message
            self._serialize = serialize_message
        return self._serialize

    def _taken(self, entry: list) -> list:
        if self._settled:  # counted as lost when the counts were settled
            self._lost += len(entry)
            return []
        self._taken_count += len(entry)
        return entry

    def _send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self._out, view):]

    def _finish(self) -> None:
        """After the finish frame: the child's last lines, until it says done or goes (or close stops waiting)."""
        os.close(self._out)
        self._out = -1
        while not self._child_done and not self._eof and not self._settled_now():
            line = self._next_line(MAX_WAKE_S)
            if line is not None:
                self._apply(line)

    def _close_pipes(self) -> None:
        for fd in (self._in, self._out):
            if fd >= 0:
                os.close(fd)
        self._in = self._out = -1

    # ---- the child's answers -------------------------------------------------------------------

    def _next_line(self, timeout_s: float) -> str | None:
        """The next line from the child, waiting up to `timeout_s`; None on timeout or end of input (`_eof`)."""
        end = time.monotonic() + timeout_s
        while b"\n" not in self._status:
            r, _, _ = select.select([self._in], [], [], max(end - time.monotonic(), 0.0))
            if not r:
                return None
            data = os.read(self._in, 4096)
            if not data:
                self._eof = True
                return None
            self._status += data
        line, _, rest = bytes(self._status).partition(b"\n")
        self._status[:] = rest
        return line.decode(errors="replace")

    def _read_status(self) -> None:
        """Apply what the child said since the last look (never blocks)."""
        try:
            while data := os.read(self._in, 65536):
                self._status += data
            self._eof = True
        except BlockingIOError:
            pass
        while b"\n" in self._status:
            line, _, rest = bytes(self._status).partition(b"\n")
            self._status[:] = rest
            self._apply(line.decode(errors="replace"))

    def _apply(self, line: str) -> None:
        word, _, rest = line.partition(" ")
        if word not in ("count", "done", "fail"):
            return
        written, malformed, what = (rest.split(" ", 2) + [""])[:3]
        with self._lock:
            if not self._settled:
                self._written, self._malformed = int(written), int(malformed)
        if word == "fail":
            self.error = f"recording to {self.path} stopped: {what}"
        if word != "count":
            self._child_done = True

    def _ended(self) -> str:
        """Why the child is gone, in words."""
        if self._proc is None:
            return "the writer process did not start"
        try:
            code = self._proc.wait(timeout=EXIT_WAIT_S)
        except subprocess.TimeoutExpired:
            return "the writer process stopped answering"
        if code < 0:
            import signal
            return f"the writer process was killed by {signal.Signals(-code).name}"
        return f"the writer process exited with code {code}"

    def _settled_now(self) -> bool:
        with self._lock:
            return self._settled

    def _settle(self) -> int:
        """Final counts (once): admission closed, what is queued and what the child did not confirm are
        dropped; returns how many messages that was."""
        with self._lock:
            self._writing = False
            if self._settled:
                return 0
            self._settled = True
            unconfirmed = self._taken_count - self._written - self._malformed
            self._lost += unconfirmed
        return unconfirmed + self._discard_queued()

    def _reap(self, timeout_s: float) -> None:
        """Wait up to `timeout_s` for the child to exit, then kill it."""
        if self._proc is None:
            return
        try:
            self._proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            try:
                self._proc.wait(timeout=KILL_WAIT_S)
            except subprocess.TimeoutExpired:
                pass  # stuck in the kernel (a dead disk): it ends when the call returns; nobody waits for it
