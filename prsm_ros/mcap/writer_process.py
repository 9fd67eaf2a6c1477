"""The MCAP writer as a process of its own: `McapFile` run with its own interpreter, fed through a pipe.

    python -P -m prsm_ros.mcap.writer_process FD_IN FD_OUT PARENT_PID

Started by `recorder_process.McapProcessRecorder` (never by hand): it reads frames from FD_IN and
answers on FD_OUT, one line each. The writer's Python (records, the chunk index, the untrusted-bytes
check, finishing) then holds this interpreter's lock, not the node's: the node's step thread never
waits for it.

Frames (parent → child), each a `FRAME` header (kind, payload length) and the payload:

- `O` open (first, once): JSON {path, metadata, chunk_size, deterministic, flush_interval_s};
- `C` a channel: JSON {topic, type, qos, untrusted}: the type name, its `offered_qos_profiles` text,
  and whether its bytes are checked with rclpy's deserializer, as the thread recorder checks them (the
  class imported by its type name from the interface's message packages only: `schema.message_class`);
- `M` messages: for each, `MESSAGE` (channel index in the order the channels came, stamp ns, length)
  and the CDR bytes;
- `F` finish: write the summary and footer, answer `done`, exit.

Lines (child → parent): `open`, or `error WHAT` (the file could not be opened; nothing else follows);
then `count WRITTEN MALFORMED` after each flush; `done WRITTEN MALFORMED` after finishing, or
`fail WRITTEN MALFORMED WHAT` when writing failed (the file is closed as it is).

End of input without `F`, or the parent gone (`os.getppid()` checked every `PARENT_POLL_S`: a
parent killed by SIGKILL cannot send anything, and a forked grandchild could hold the pipe open),
means the parent died: the file is closed without a summary, readable up to its last complete
chunk (`prsm-bag repair` recovers it), and the process exits. PR_SET_PDEATHSIG is not used: it
fires when the *thread* that started the child ends, which is not the parent's death.
"""

from __future__ import annotations

import json
import os
import select
import signal
import struct
import sys
import time

from prsm_sim.errors import InputError

from prsm_ros.mcap import schema as mcap_schema

FRAME = struct.Struct("<cI")  # kind, payload length
MESSAGE = struct.Struct("<HqI")  # channel index, stamp ns (log = publish time), CDR length
PARENT_POLL_S = 0.1  # how long the child may outlive a parent that died without closing the pipe
READ_BYTES = 1 << 20


class ParentGone(Exception):
    """Input ended without a finish frame: the parent died."""


class FrameReader:
    """Frames from a pipe, read in large pieces; `ParentGone` at end of input or when the parent is gone."""

    def __init__(self, fd: int, parent_pid: int) -> None:
        self.fd, self.parent_pid = fd, parent_pid
        self._buf = bytearray()

    def frames(self, timeout_s: float) -> list[tuple[bytes, memoryview]]:
        """The complete frames that arrived within `timeout_s` (maybe none)."""
        ready, _, _ = select.select([self.fd], [], [], timeout_s)
        if os.getppid() != self.parent_pid:
            raise ParentGone
        if ready:
            data = os.read(self.fd, READ_BYTES)
            if not data:
                raise ParentGone
            self._buf += data
        out, buf, off = [], self._buf, 0
        while len(buf) - off >= FRAME.size:
            kind, n = FRAME.unpack_from(buf, off)
            if len(buf) - off - FRAME.size < n:
                break
            out.append((kind, memoryview(bytes(buf[off + FRAME.size:off + FRAME.size + n]))))
            off += FRAME.size + n
        del buf[:off]
        return out


class Writer:
    """What the child does with each frame, around one `McapFile`."""

    def __init__(self, opening: dict) -> None:
        from prsm_ros.mcap.recorder import McapFile
        self.file = McapFile(opening["path"], metadata=opening["metadata"], chunk_size=int(opening["chunk_size"]),
                             deterministic=bool(opening["deterministic"]))
        self.flush_interval_s = float(opening["flush_interval_s"])
        self.ids: list[int] = []
        self.checked: dict[int, type] = {}  # channel index → class its bytes must deserialize as
        self.malformed = 0

    def channel(self, payload: memoryview) -> None:
        c = json.loads(bytes(payload))
        cls = None
        if c["untrusted"]:  # only the interface's message packages are imported (`schema.message_class`)
            cls = mcap_schema.message_class(c["type"])
            if cls is None:
                raise InputError(f"channel {c['topic']}: type {c['type']!r} is not a message class of "
                                 f"{', '.join(sorted(mcap_schema.MESSAGE_PACKAGES))}: its bytes cannot be checked")
            self.file.prepare_checks()
            self.checked[len(self.ids)] = cls
        self.ids.append(self.file.add_named_channel(c["topic"], c["type"], c["qos"], cls))

    def messages(self, payload: memoryview) -> None:
        ids, checked, check, unpack, size = self.ids, self.checked, self.file.check, MESSAGE.unpack_from, MESSAGE.size
        items: list[tuple[int, object, int]] = []
        off, end = 0, len(payload)
        while off < end:
            index, stamp, n = unpack(payload, off)
            off += size
            data = bytes(payload[off:off + n])
            off += n
            cls = checked.get(index)
            if cls is not None and not check(cls, data):
                self.malformed += 1
                continue
            items.append((ids[index], data, stamp))
        self.file.write_many(items)

    def counts(self) -> str:
        return f"{self.file.messages_written} {self.malformed}"


def _say(fd: int, line: str) -> None:
    data = (line.replace("\n", " ") + "\n").encode()
    while data:
        data = data[os.write(fd, data):]


def _what(e: BaseException) -> str:
    return e.strerror if isinstance(e, OSError) and e.strerror else (str(e) or type(e).__name__)


def _open(reader: FrameReader, out: int) -> Writer | None:
    """The writer for the first frame (`O`), or None after saying why not."""
    frames: list = []
    while not frames:
        frames = reader.frames(PARENT_POLL_S)
    kind, payload = frames[0]
    if kind != b"O" or len(frames) > 1:
        _say(out, "error the recorder's first frame was not a lone open frame")
        return None
    try:
        writer = Writer(json.loads(bytes(payload)))
    except (OSError, ValueError) as e:
        _say(out, f"error {_what(e)}")
        return None
    _say(out, "open")
    return writer


def serve(reader: FrameReader, out: int) -> int:
    """Open, then write what arrives until the finish frame (0) or the parent's death (0, no summary)."""
    w = _open(reader, out)
    if w is None:
        return 1
    f = w.file
    next_flush = time.monotonic() + w.flush_interval_s
    handlers = {b"C": w.channel, b"M": w.messages}
    written_since_flush = False
    try:
        while True:
            frames = reader.frames(PARENT_POLL_S)
            for kind, payload in frames:
                if kind == b"F":
                    f.finish()
                    _say(out, f"done {w.counts()}")
                    return 0
                handlers[kind](payload)
            written_since_flush = written_since_flush or bool(frames)
            # flushed when the data comes (every wake-up costs CPU: none for the clock alone while data
            # flows), or at the poll after it stops; a deterministic file only pushes its bytes to the OS
            if written_since_flush and time.monotonic() >= next_flush:
                f.flush()  # bounds the loss on SIGKILL (see recorder.FLUSH_INTERVAL_S)
                _say(out, f"count {w.counts()}")
                written_since_flush = False
                next_flush = time.monotonic() + w.flush_interval_s
    except ParentGone:
        f.abort()  # no summary: a killed parent's file stays as the thread recorder's would
        return 0
    except Exception as e:  # disk full, I/O error: say it once, keep what reached the disk
        f.abort()
        try:
            _say(out, f"fail {w.counts()} {_what(e)}")
        except OSError:
            pass  # the parent is gone as well
        return 1


def main(argv: list[str] | None = None) -> int:
    fd_in, fd_out, parent_pid = (int(a) for a in (argv if argv is not None else sys.argv[1:]))
    # Ctrl-C is the parent's to handle: it then finishes the file through the pipe
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:  # started from the node's SCHED_FIFO thread: the writer is no part of the realtime loop
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    try:
        return serve(FrameReader(fd_in, parent_pid), fd_out)
    except ParentGone:  # before the open frame
        return 0


if __name__ == "__main__":
    sys.exit(main())
