"""Reading ROS 2 MCAP files for `prsm-bag`: ours or recorded elsewhere, finished or not.

A finished file is read through its summary (schemas, channels, statistics, chunk and metadata
indexes) with the mcap library's seeking reader. A file without a summary or footer — a recording
killed mid-run — is read by `scan_records`, which walks the records from the start and keeps every
complete one, chunks included, stopping at the first truncated record; `Bag.note` then says what
was recovered. Messages are decoded with mcap_ros2's CDR decoder from the file's own `ros2msg`
schemas, so no ROS package needs to be installed to read a bag.

`resolve_topics` finds the topics `prsm-bag` works with by type and name (the node's interface),
so a bag from another recorder with standard JointState / WrenchStamped topics works too. A topic
whose messages cannot be decoded (`TopicInfo.problem`) never fills a role.
"""

from __future__ import annotations

import io
import math
import os
import re
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Iterator

from prsm_sim.errors import PrsmError

from prsm_ros.interface import TOPIC_DEFS
from prsm_ros.limits import file_kind

MAGIC = b"\x89MCAP0\r\n"
# What one chunk may decompress to. Its records are all held at once (for the log-time merge), so
# the cap bounds a reader's memory whatever the file declares: the output itself is bounded, not
# only the declared size. rosbag2 writes 768 KiB chunks, the mcap CLI 4 MiB, our recorder 1 MiB.
MAX_CHUNK_BYTES = 64 << 20
MAX_RECORD_BYTES = MAX_CHUNK_BYTES + (1 << 20)  # a record read whole: a chunk's data and its header fields
MAX_WINDOW_S = 1e9  # --start/--end: seconds from the first message (int64 nanoseconds hold ±9.2e9 s)


class BagError(PrsmError):
    """A bag could not be used; the message says which file, what is wrong and what would work."""


@dataclass
class TopicInfo:
    topic: str
    type: str                   # schema name, normalised to pkg/msg/Type
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    qos_yaml: str = ""
    message_encoding: str = ""
    schema_encoding: str = ""
    channel_ids: list[int] = field(default_factory=list)
    problem: str | None = None  # why its messages cannot be decoded (foreign encoding, schema not as its type says)
    malformed: int = 0          # messages skipped because they did not decode with the schema
    first_malformed: str | None = None

    @property
    def rate_hz(self) -> float | None:
        """Mean rate between the first and last message; None with fewer than two messages."""
        if self.count < 2 or self.first_ns is None or self.last_ns is None or self.last_ns <= self.first_ns:
            return None
        return (self.count - 1) / ((self.last_ns - self.first_ns) * 1e-9)

    def _add(self, t: int) -> None:
        self.count += 1
        self.first_ns = t if self.first_ns is None else min(self.first_ns, t)
        self.last_ns = t if self.last_ns is None else max(self.last_ns, t)


@dataclass
class BagMessage:
    topic: str
    type: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes
    msg: object | None          # decoded message (attribute access), None if undecodable


def normalise_type(name: str) -> str:
    """`pkg/Type` and `pkg/msg/Type` both → `pkg/msg/Type`."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


def resolve_path(path) -> Path:
    """The .mcap file for `path`: the file itself, or the single .mcap inside a rosbag2 directory."""
    p = Path(path)
    if p.is_dir():
        files = sorted(p.glob("*.mcap"))
        if len(files) != 1:
            raise BagError(f"{p}: a directory holding {len(files)} .mcap files; give one .mcap file")
        return files[0]
    if not p.exists():
        raise BagError(f"{p}: no such file")
    return p


def damaged_data_errors() -> tuple[type[BaseException], ...]:
    """What the mcap library raises on bytes that are not valid records: a damaged or cut file, not a bug.

    McapError (bad magic, end of data, a record longer than its file, CRC mismatch is a
    ValueError), struct.error (a field cut short), ValueError (UnicodeDecodeError in a string,
    an unknown enum), zstandard.ZstdError (a chunk that does not decompress). Anything else — a
    TypeError, AttributeError, KeyError — is a bug in the reading code and propagates.
    """
    from mcap.exceptions import McapError
    errors: list[type[BaseException]] = [McapError, struct.error, ValueError, EOFError]
    try:
        import zstandard
    except ImportError:  # mcap then reports a zstd chunk as UnsupportedCompressionError (a McapError)
        pass
    else:
        errors.append(zstandard.ZstdError)
    return tuple(errors)


def _require_magic(f, path) -> None:
    if f.read(8) != MAGIC:
        raise BagError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")


class _Bounded:
    """A file whose reads never ask for more than is left in it.

    The mcap library reads a record's fields with the lengths the file declares; a damaged length
    (2^40 bytes) would otherwise make Python allocate that much before finding the file shorter.
    Not an io.RawIOBase: the mcap library would wrap one in a BufferedReader that closes it.
    """

    def __init__(self, f, size: int) -> None:
        self._f, self._size = f, size

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        target = {io.SEEK_SET: 0, io.SEEK_CUR: self._f.tell(), io.SEEK_END: self._size}[whence] + offset
        return self._f.seek(min(max(target, 0), self._size))

    def tell(self) -> int:
        return self._f.tell()

    def read(self, n: int = -1) -> bytes:
        left = self._size - self._f.tell()
        return self._f.read(left if n is None or n < 0 else min(n, left))


class ChunkSkipped(Exception):
    """A chunk that cannot be used (the reason says why); its messages are skipped, the rest is read."""


def _zstd(data: bytes, cap: int) -> bytes:
    import zstandard
    try:
        size = zstandard.frame_content_size(data)
        if size > cap:
            raise ChunkSkipped(f"its zstd frame holds {size} bytes, more than the {cap >> 20} MiB a chunk may hold here")
        if size >= 0:  # the output is allocated at the frame's size, checked above
            return zstandard.ZstdDecompressor().decompress(data)
        reader = zstandard.ZstdDecompressor().stream_reader(data)
        parts, held = [], 0
        while held <= cap:
            part = reader.read(1 << 20)
            if not part:
                break
            parts.append(part)
            held += len(part)
        return b"".join(parts)
    except zstandard.ZstdError as e:
        raise ChunkSkipped(f"does not decompress (zstd: {str(e)[:60]})") from None


def _lz4(data: bytes, cap: int) -> bytes:
    import lz4.frame
    try:
        return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=cap + 1)
    except RuntimeError as e:  # the lz4 binding's only error type for a frame it cannot read (LZ4F_* codes)
        raise ChunkSkipped(f"does not decompress (lz4: {str(e)[:60]})") from None


def chunk_data(chunk, cap: int = MAX_CHUNK_BYTES) -> bytes:
    """A chunk's records as bytes, decompressed to at most `cap` bytes and checked by its CRC.

    ChunkSkipped naming the reason: a declared size over `cap`, an output that would exceed it (the
    output is bounded as it is produced, so a frame that lies about its size costs nothing), a
    codec error, a CRC mismatch. With a CRC the data are good whatever size the chunk declares
    (the mcap library's own readers decompress by the frame); without one (0: "not computed",
    MCAP spec) they must have the declared size.
    """
    size = chunk.uncompressed_size
    if size > cap:
        raise ChunkSkipped(f"declares {size} bytes uncompressed, more than the {cap >> 20} MiB a chunk may hold here")
    try:
        if chunk.compression == "zstd":
            data = _zstd(chunk.data, cap)
        elif chunk.compression == "lz4":
            data = _lz4(chunk.data, cap)
        elif chunk.compression == "":
            data = chunk.data
        else:
            raise ChunkSkipped(f"unknown compression {chunk.compression[:40]!r}")
    except ImportError as e:
        raise ChunkSkipped(f"{chunk.compression} compression needs the {e.name} package") from None
    if len(data) > cap:
        raise ChunkSkipped(f"decompresses to more than the {cap >> 20} MiB a chunk may hold here")
    if chunk.uncompressed_crc != 0:
        if zlib.crc32(data) != chunk.uncompressed_crc:
            raise ChunkSkipped("CRC mismatch")
    elif len(data) != size:
        raise ChunkSkipped(f"decompresses to {len(data)} bytes, the chunk declares {size}")
    return data


def chunk_records(chunk) -> list:
    """The schema, channel and message records inside one chunk (`chunk_data` checks it first).

    Raises ChunkSkipped naming the reason when the chunk fails its checks or its records do not parse.
    """
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Message, Schema

    data = chunk_data(chunk)
    size = len(data)
    stream = ReadDataStream(io.BytesIO(data))
    out: list = []
    try:
        while stream.count < size:
            opcode, length = stream.read1(), stream.read8()
            if length > size - stream.count:
                raise ChunkSkipped(f"a record inside declares {length} bytes, more than the chunk has left")
            body = ReadDataStream(io.BytesIO(stream.read(length)))
            if opcode == Opcode.MESSAGE:
                out.append(Message.read(body, length))
            elif opcode == Opcode.CHANNEL:
                out.append(Channel.read(body))
            elif opcode == Opcode.SCHEMA:
                out.append(Schema.read(body))
    except damaged_data_errors() as e:
        raise ChunkSkipped(f"its records do not parse ({type(e).__name__})") from None
    return out


# Where a record's framing is damaged, a scan reads on from the next offset where two records in a
# row frame as records do: a known opcode (Header excepted), then a length (under 2^32) that ends
# inside the file, at another such record or at the closing magic.
_OPCODES = bytes([2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15])
_CANDIDATE = re.compile(b"[" + re.escape(_OPCODES) + rb"].{4}\x00{4}", re.S)


class _Empty:
    """An empty mapping for a file of size 0 (mmap cannot map it)."""

    def __enter__(self):
        return b""

    def __exit__(self, *exc):
        return False


def _mapped(f):
    import mmap
    size = os.fstat(f.fileno()).st_size
    return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) if size else _Empty()


def _next_record(mm, start: int, size: int) -> int | None:
    """The first offset ≥ `start` where a record and the one after it frame plausibly; None if none."""
    for m in _CANDIDATE.finditer(mm, start):
        p = m.start()
        q = p + 9 + int.from_bytes(mm[p + 1:p + 9], "little")
        if q + 8 == size and mm[q:q + 8] == MAGIC:
            return p
        if q + 9 <= size and mm[q] in _OPCODES and int.from_bytes(mm[q + 1:q + 9], "little") <= size - q - 9:
            return p
    return None


def _chunk_end(mm, pos: int, size: int) -> int:
    """Where the Chunk record at `pos` ends by its own fields (compression and data lengths), as mcap's
    stream reader reads it; -1 when they run past the file."""
    at = pos + 9
    if at + 32 > size:
        return -1
    (clen,) = struct.unpack_from("<I", mm, at + 28)
    if clen > 64 or at + 40 + clen > size:
        return -1
    (rlen,) = struct.unpack_from("<Q", mm, at + 32 + clen)
    end = at + 40 + clen + rlen
    return end if end <= size else -1


def _reframed_chunk(mm, pos: int, size: int) -> tuple[list, int] | None:
    """(records, end) of a Chunk read by its own fields when its record length is damaged; None unless
    it passes every check of `chunk_records` with a CRC (without one, nothing says it is whole)."""
    from mcap.records import Chunk
    end = _chunk_end(mm, pos, size)
    at = pos + 9
    if end < 0 or end - at > MAX_RECORD_BYTES:
        return None
    start_ns, end_ns, usize, crc, clen = struct.unpack_from("<QQQII", mm, at)
    if crc == 0:
        return None
    try:
        compression = bytes(mm[at + 32:at + 32 + clen]).decode("utf-8")
        chunk = Chunk(compression=compression, data=bytes(mm[at + 40 + clen:end]), message_end_time=end_ns,
                      message_start_time=start_ns, uncompressed_crc=crc, uncompressed_size=usize)
        return chunk_records(chunk), end
    except (UnicodeDecodeError, ChunkSkipped):
        return None


@dataclass
class Scan:
    """What a record walk found: header, schemas, channels, metadata, whether the file ended properly.

    `bad_chunks`: (byte offset, reason) of chunks skipped; `undeclared`: messages on a channel no
    Channel record declared (skipped).
    """

    header: object | None = None
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    metadata: list = field(default_factory=list)
    complete: bool = False
    chunks: int = 0
    stopped_at: int | None = None
    problem: str | None = None
    bad_chunks: list[tuple[int, str]] = field(default_factory=list)
    undeclared: int = 0
    gaps: list[tuple[int, int]] = field(default_factory=list)  # damaged byte ranges read past (start, end)


def scan_records(path, on_message=None) -> Scan:
    """Walk an MCAP file record by record, keeping every complete record; stop at a truncated one.

    The recovery routine for unfinished files (MCAP spec: records are length-prefixed, chunks are
    self-contained): schemas, channels and metadata are collected into the returned `Scan`, and
    each message (in complete chunks or bare) is passed to `on_message(schema, channel, message)`
    in file order. A chunk that fails its checks (`chunk_records`) is skipped and listed.
    """
    scan = Scan()
    for schema, channel, message in walk_records(path, scan):
        if on_message is not None:
            on_message(schema, channel, message)
    return scan


def _taker(scan: Scan):
    """`take(record)`: keeps a schema or channel in `scan`; a message → (schema, channel, message), None
    when its channel is unknown. A closure, so that the record types are looked up once per file."""
    from mcap.records import Channel, Message, Schema

    def take(rec):
        if isinstance(rec, Schema):
            scan.schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            scan.channels[rec.id] = rec
        elif isinstance(rec, Message):
            ch = scan.channels.get(rec.channel_id)
            if ch is not None:
                return scan.schemas.get(ch.schema_id), ch, rec
            scan.undeclared += 1
        return None
    return take


def _resume_after(mm, pos: int, size: int, scan: Scan) -> int | None:
    """Where reading goes on past an unreadable record at `pos`: the next record (the gap noted in `scan`).

    None when no record follows (`scan.stopped_at` set): the file ends there for us."""
    nxt = _next_record(mm, pos + 1, size)
    if nxt is None:
        scan.stopped_at = pos
        return None
    scan.gaps.append((pos, nxt))
    return nxt


def _record_reader(scan: Scan, take):
    """`read(body, opcode, length, pos)`: one record's `body` (`length` bytes, at byte `pos`) into `scan`
    through `take` (`_taker`), giving the (schema, channel, message) it holds; None at the footer, the
    record that ends the file. It raises one of `damaged_data_errors()` for a damaged body; a chunk that
    fails its checks is listed in `scan.bad_chunks`, the records after it stay readable. A closure, so
    that the mcap names are looked up once per file, not once per record."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema

    def read(body: bytes, opcode: int, length: int, pos: int) -> list | None:
        stream = ReadDataStream(io.BytesIO(body))
        found = []
        if opcode == Opcode.HEADER:
            scan.header = Header.read(stream)
        elif opcode == Opcode.SCHEMA:
            take(Schema.read(stream))
        elif opcode == Opcode.CHANNEL:
            take(Channel.read(stream))
        elif opcode == Opcode.MESSAGE:
            found.append(take(Message.read(stream, length)))
        elif opcode == Opcode.METADATA:
            scan.metadata.append(Metadata.read(stream))
        elif opcode == Opcode.CHUNK:
            try:
                found = [take(rec) for rec in chunk_records(Chunk.read(stream))]
                scan.chunks += 1
            except ChunkSkipped as e:  # framed by its length: the records after it are still readable
                scan.bad_chunks.append((pos, str(e)))
        elif opcode == Opcode.FOOTER:
            return None
        return [item for item in found if item is not None]
    return read


def walk_records(path, scan: Scan) -> Iterator[tuple]:
    """The generator behind `scan_records`: yields (schema, channel, message), fills `scan`."""
    from mcap.opcode import Opcode

    take = _taker(scan)
    read_record = _record_reader(scan, take)
    damaged = damaged_data_errors()
    with open(path, "rb") as f, _mapped(f) as mm:
        size = os.fstat(f.fileno()).st_size
        _require_magic(f, path)
        pos = 8
        while True:
            head = f.read(9)
            if len(head) < 9:
                scan.stopped_at = pos
                break
            opcode, length = struct.unpack("<BQ", head)
            if opcode == Opcode.CHUNK and length != _chunk_end(mm, pos, size) - pos - 9:
                reframed = _reframed_chunk(mm, pos, size)
                if reframed is not None:  # a damaged record length, the chunk whole by its own fields and CRC
                    records, end = reframed
                    scan.chunks += 1
                    scan.gaps.append((pos + 1, pos + 9))
                    yield from (item for item in (take(rec) for rec in records) if item is not None)
                    pos = end
                    f.seek(pos)
                    continue
            if length > size - pos - 9:  # cut short, or a damaged length: read on from the next record, if any
                nxt = _resume_after(mm, pos, size, scan)
                if nxt is None:
                    break
                pos = nxt
                f.seek(pos)
                continue
            if length > MAX_RECORD_BYTES:  # framed by its length: skipped unread, the records after it are read
                scan.bad_chunks.append((pos, f"a record of {length} bytes, more than the "
                                             f"{MAX_RECORD_BYTES >> 20} MiB a record may hold here"))
                f.seek(length, io.SEEK_CUR)
                pos += 9 + length
                continue
            body = f.read(length)
            try:
                found = read_record(body, opcode, length, pos)
            except damaged as e:  # a damaged record: read on from the next record, if any
                nxt = _resume_after(mm, pos, size, scan)
                if nxt is None:
                    scan.problem = f"damaged record at byte {pos} ({type(e).__name__})"
                    break
                pos = nxt
                f.seek(pos)
                continue
            if found is None:  # the footer: the file is finished when the closing magic follows
                scan.complete = f.read(8) == MAGIC
                break
            yield from found
            pos += 9 + length


def _footer(f, size: int):
    """(summary_start, summary_crc) from the footer record before the closing magic; None without one."""
    from mcap.opcode import Opcode
    if size < 8 + 37:
        return None
    f.seek(size - 37)
    tail = f.read(37)
    if tail[29:] != MAGIC or tail[0] != Opcode.FOOTER:
        return None
    summary_start, _, crc = struct.unpack_from("<QQI", tail, 9)
    return summary_start, crc


def summary_doubt(f, size: int, summary) -> str | None:
    """Why the summary of a finished file cannot be trusted to find every chunk; None when it can.

    The footer's summary CRC (when written) must match, and every chunk the data section holds
    must be one a chunk index points at: the top-level records are walked by their lengths
    (headers only, nothing decompressed) up to the summary or to the first record that runs
    past it. A summary that misses a chunk would make every reader drop its messages.
    """
    from mcap.opcode import Opcode
    foot = _footer(f, size)
    if foot is None:
        return "no footer"
    summary_start, crc = foot
    if not 8 < summary_start <= size - 37:
        return "the footer points outside the file"
    if crc != 0:
        f.seek(summary_start)
        left, got = size - 8 - 4 - summary_start, 0
        while left > 0:
            block = f.read(min(left, 1 << 20))
            if not block:
                break
            got = zlib.crc32(block, got)
            left -= len(block)
        if got != crc:
            return "its CRC does not match"
    indexed = {(ci.chunk_start_offset, ci.chunk_length) for ci in summary.chunk_indexes}
    pos = 8
    while pos + 9 <= summary_start:
        f.seek(pos)
        opcode, length = struct.unpack("<BQ", f.read(9))
        if opcode == Opcode.DATA_END or length > summary_start - pos - 9:
            break
        if opcode == Opcode.CHUNK and (pos, 9 + length) not in indexed:
            return f"the chunk at byte {pos} has no chunk index"
        pos += 9 + length
    return None


def _bad_chunks_note(name: str, bad: list[tuple[int, str]]) -> str:
    first = "; ".join(f"byte {pos}: {why}" for pos, why in bad[:3])
    more = f"; and {len(bad) - 3} more" if len(bad) > 3 else ""
    return f"{name}: skipped {len(bad)} damaged chunk(s) and the messages in them ({first}{more})"


class Bag:
    """One MCAP file opened for reading: topics, run metadata, decoded messages.

    `complete` is False for a file without footer (unfinished recording); `notes` say what was
    recovered then, and what was skipped: damaged chunks, messages on undeclared channels, topics
    whose schema the tools cannot use (`TopicInfo.problem`). Messages that do not decode with
    their schema are skipped as they are read and counted in `TopicInfo.malformed`
    (`reading_notes()`). Raises BagError for a file that is not MCAP.
    """

    def __init__(self, path) -> None:
        self.path = resolve_path(path)
        kind = file_kind(self.path.stat().st_mode)
        if kind:  # a FIFO would block the reader, a device never end
            raise BagError(f"{self.path}: {kind}, not an MCAP file (a regular file)")
        self.complete = True
        self.notes: list[str] = []
        self.profile = ""
        self.library = ""
        self.metadata: dict[str, dict[str, str]] = {}
        self.topics: dict[str, TopicInfo] = {}
        self._schemas: dict = {}
        self._channels: dict = {}
        self._chunk_indexes: list = []
        self._bad_chunks: dict[int, str] = {}   # byte offset → reason, found while reading
        self._decoders: dict[int, object] = {}
        self._summary_damaged = False
        self._summary_doubt: str | None = None  # why a summary that reads is not trusted (the file is scanned)
        self._indexed = False  # finished file with chunk indexes: read through the summary's chunk indexes
        self._size = self.path.stat().st_size
        with open(self.path, "rb") as f:
            _require_magic(f, self.path)
        summary = self._read_summary()
        if summary is None:
            self._load_by_scan()
        self._check_schemas()

    @property
    def note(self) -> str | None:
        """What was recovered or skipped, one sentence per finding; None for a sound file."""
        return "; ".join(self.notes + self.reading_notes()) or None

    # ---- loading -----------------------------------------------------------------------------

    def _read_summary(self):
        """Header, summary and metadata of a finished file; None when the file must be scanned."""
        from mcap.reader import SeekingReader
        try:
            with open(self.path, "rb") as raw:
                f = _Bounded(raw, self._size)
                reader = SeekingReader(f, record_size_limit=MAX_CHUNK_BYTES)
                header = reader.get_header()
                summary = reader.get_summary()
                if summary is None or summary.statistics is None or not summary.chunk_indexes:
                    return None  # nothing to seek by: scanning gives the per-topic times too
                why = summary_doubt(f, self._size, summary)
                if why is not None:
                    self._summary_doubt = why
                    return None
                metadata = list(reader.iter_metadata())
                message_index_times = self._channel_time_ranges(f, summary)
        except (*damaged_data_errors(), OSError):  # no footer, damaged footer or summary: scan the records
            self._summary_damaged = True
            return None
        self.profile, self.library = header.profile, header.library
        self._schemas, self._channels = dict(summary.schemas), dict(summary.channels)
        self._chunk_indexes = sorted(summary.chunk_indexes, key=lambda ci: (ci.message_start_time, ci.chunk_start_offset))
        self._indexed = True
        for m in metadata:
            self.metadata[m.name] = dict(m.metadata)
        counts = summary.statistics.channel_message_counts
        for cid, ch in self._channels.items():
            info = self._topic_for(ch)
            info.count += counts.get(cid, 0)
            first, last = message_index_times.get(cid, (None, None))
            if first is not None:
                info.first_ns = first if info.first_ns is None else min(info.first_ns, first)
                info.last_ns = last if info.last_ns is None else max(info.last_ns, last)
        undeclared = {cid: n for cid, n in counts.items() if cid not in self._channels and n}
        if undeclared:
            self.notes.append(f"{self.path.name}: skipped {sum(undeclared.values())} message(s) on channel(s) "
                              f"{', '.join(map(str, sorted(undeclared)[:5]))} that no Channel record declares")
        return summary

    @staticmethod
    def _channel_time_ranges(f, summary) -> dict[int, tuple[int, int]]:
        """First and last log time per channel from the message indexes, without decompressing.

        Only the channel's earliest and latest chunks are read (by their time ranges), so a long
        recording costs two small reads per channel; exact when chunks do not overlap in time,
        as rosbag2 and our recorder write them.
        """
        from mcap.data_stream import ReadDataStream
        from mcap.records import MessageIndex

        def index_times(offset: int) -> list[int]:
            f.seek(offset + 9)  # opcode and length precede the record
            return [t for t, _ in MessageIndex.read(ReadDataStream(f)).records]

        ranges: dict[int, tuple[int, int]] = {}
        for cid in summary.channels:
            chunks = [ci for ci in summary.chunk_indexes if cid in ci.message_index_offsets]
            if not chunks:
                continue
            first = min(chunks, key=lambda ci: ci.message_start_time)
            last = max(chunks, key=lambda ci: ci.message_end_time)
            lo, hi = index_times(first.message_index_offsets[cid]), index_times(last.message_index_offsets[cid])
            if lo and hi:
                ranges[cid] = (min(lo), max(hi))
        return ranges

    def _load_by_scan(self) -> None:
        scan = Scan()
        self._schemas, self._channels = scan.schemas, scan.channels  # filled as the walk goes
        for _, channel, message in walk_records(self.path, scan):
            self._topic_for(channel)._add(message.log_time)
        for ch in self._channels.values():
            self._topic_for(ch)
        if scan.header is not None:
            self.profile, self.library = scan.header.profile, scan.header.library
        for m in scan.metadata:
            self.metadata[m.name] = dict(m.metadata)
        self.complete = scan.complete and scan.problem is None
        if not self.complete:
            n = sum(t.count for t in self.topics.values())
            end = max((t.last_ns for t in self.topics.values() if t.last_ns is not None), default=None)
            why = scan.problem or "no footer: the recording did not finish (killed, or disk full)"
            upto = f" up to log time {end * 1e-9:.3f} s" if end is not None else ""
            self.notes.append(f"{self.path.name}: unfinished MCAP file ({why}); recovered {scan.chunks} complete "
                              f"chunk(s), {n} message(s){upto}; data after byte {scan.stopped_at} was lost")
        elif scan.complete and (self._summary_damaged or self._summary_doubt):
            why = self._summary_doubt or "damaged footer or summary"
            self.notes.append(f"{self.path.name}: the summary could not be used ({why}); read by scanning the records")
        if scan.gaps:
            where = ", ".join(f"{a}–{b}" for a, b in scan.gaps[:3]) + (" …" if len(scan.gaps) > 3 else "")
            self.notes.append(f"{self.path.name}: read past {len(scan.gaps)} damaged byte range(s) (bytes {where}) "
                              "to the next record")
        if scan.bad_chunks:
            self._bad_chunks.update(scan.bad_chunks)
            self.notes.append(_bad_chunks_note(self.path.name, scan.bad_chunks))
        if scan.undeclared:
            self.notes.append(f"{self.path.name}: skipped {scan.undeclared} message(s) on channels that no "
                              "Channel record declares")

    def _topic_for(self, ch) -> TopicInfo:
        info = self.topics.get(ch.topic)
        schema = self._schemas.get(ch.schema_id)
        if info is None:
            info = TopicInfo(topic=ch.topic, type=normalise_type(schema.name) if schema else "",
                             qos_yaml=ch.metadata.get("offered_qos_profiles", ""),
                             message_encoding=ch.message_encoding,
                             schema_encoding=schema.encoding if schema else "")
            self.topics[ch.topic] = info
        if ch.id not in info.channel_ids:
            info.channel_ids.append(ch.id)
            other = normalise_type(schema.name) if schema else ""
            if other != info.type or ch.message_encoding != info.message_encoding:
                info.problem = info.problem or (f"recorded with two types ({info.type or 'no schema'} and "
                                                f"{other or 'no schema'})"[:200])
        return info

    def _check_schemas(self) -> None:
        """Set `TopicInfo.problem` for topics whose messages cannot be decoded as their type says."""
        from prsm_ros.bag.schema_check import schema_problem
        for info in self.topics.values():
            for cid in info.channel_ids:
                ch = self._channels[cid]
                problem = schema_problem(ch.message_encoding, self._schemas.get(ch.schema_id))
                if problem is None and self._decoder(ch) is None:
                    problem = "its schema does not parse as a ros2msg definition"
                if problem is not None:
                    info.problem = problem
                    self._decoders[cid] = None
                    break
        bad = [f"{t} ({i.problem})" for t, i in sorted(self.topics.items()) if i.problem]
        if bad:
            self.notes.append(f"{self.path.name}: cannot decode {', '.join(bad[:5])}"
                              + (f" and {len(bad) - 5} more topic(s)" if len(bad) > 5 else ""))

    # ---- queries -----------------------------------------------------------------------------

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    @property
    def start_ns(self) -> int | None:
        return min((t.first_ns for t in self.topics.values() if t.first_ns is not None), default=None)

    @property
    def end_ns(self) -> int | None:
        return max((t.last_ns for t in self.topics.values() if t.last_ns is not None), default=None)

    @property
    def run_metadata(self) -> dict[str, str]:
        """The `prsm_run` record (empty for bags recorded elsewhere)."""
        return self.metadata.get("prsm_run", {})

    def reading_notes(self) -> list[str]:
        """What reading messages skipped so far: damaged chunks found in a finished file, malformed messages."""
        notes = []
        if self._indexed and self._bad_chunks:  # a scanned file's are among `notes` already
            notes.append(_bad_chunks_note(self.path.name, sorted(self._bad_chunks.items())))
        for t, info in sorted(self.topics.items()):
            if info.malformed:
                notes.append(f"{self.path.name}: skipped {info.malformed} malformed message(s) on {t} "
                             f"(first: {info.first_malformed})")
        return notes

    def require_topics(self, topics) -> None:
        """BagError naming the topics the bag has when one of `topics` is not in it."""
        for t in topics:
            if t not in self.topics:
                raise BagError(f"{self.path.name}: no topic {t!r}; topics: {', '.join(sorted(self.topics)) or 'none'}")

    def require_decodable(self, topics) -> None:
        """BagError saying why when one of `topics` cannot be decoded (`TopicInfo.problem`)."""
        self.require_topics(topics)
        for t in topics:
            if self.topics[t].problem:
                raise BagError(f"{self.path.name}: topic {t} ({self.topics[t].type or 'no schema'}) cannot be "
                               f"decoded: {self.topics[t].problem}")

    def window_ns(self, start_s: float | None, end_s: float | None) -> tuple[int | None, int | None]:
        """Log-time bounds (ns) for a range given in seconds from the bag's first message; None = open.

        BagError when a bound is not a finite number or `end_s` is before `start_s`.
        """
        for flag, v in (("--start", start_s), ("--end", end_s)):
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and abs(v) <= MAX_WINDOW_S):
                raise BagError(f"{flag} {v!r}: must be a finite number of seconds within ±{MAX_WINDOW_S:g}")
        if start_s is not None and end_s is not None and end_s < start_s:
            raise BagError(f"--end {end_s} is before --start {start_s}")
        base = self.start_ns or 0
        return (None if start_s is None else base + int(round(start_s * 1e9)),
                None if end_s is None else base + int(round(end_s * 1e9)))

    def topics_of_type(self, type_name: str) -> list[str]:
        t = normalise_type(type_name)
        return [name for name, info in self.topics.items() if info.type == t]

    def _decoder(self, channel):
        dec = self._decoders.get(channel.id, False)
        if dec is False:
            from mcap_ros2.decoder import DecoderFactory
            try:
                dec = DecoderFactory().decoder_for(channel.message_encoding, self._schemas.get(channel.schema_id))
            # a schema mcap_ros2 cannot parse or does not implement (wstring): the raw bytes are still available
            except (ValueError, NotImplementedError, KeyError, IndexError, AttributeError, *damaged_data_errors()):
                dec = None
            except Exception as e:  # its schema parser's own errors, whose classes only a private module exports
                if not type(e).__module__.startswith("mcap_ros2."):
                    raise
                dec = None
            self._decoders[channel.id] = dec
        return dec

    def _decode(self, channel, message):
        """The decoded message; None when it does not decode (counted as malformed on its topic)."""
        dec = self._decoder(channel)
        if dec is None:
            return None
        try:
            return dec(message.data)
        # CDR cut short, a length past the end, bytes not matching the schema
        except (IndexError, KeyError, TypeError, OverflowError, MemoryError, *damaged_data_errors()) as e:
            self.count_malformed(channel.topic, message.log_time, len(message.data), str(e) or type(e).__name__)
            return None

    def count_malformed(self, topic: str, log_time_ns: int, nbytes: int, why: str) -> None:
        """Count a message of `topic` that does not decode (skipped; `reading_notes` names the first)."""
        info = self.topics[topic]
        info.malformed += 1
        if info.first_malformed is None:
            info.first_malformed = f"log time {log_time_ns * 1e-9:.6f} s, {nbytes} bytes: {why[:80]}"

    def messages(self, topics=None, start_ns: int | None = None, end_ns: int | None = None, *,
                 decode: bool = True, progress: bool = False, desc: str = "reading") -> Iterator[BagMessage]:
        """Messages of `topics` (all when None) with start_ns <= log time <= end_ns, in log-time order.

        With `decode`, every topic must be decodable (`require_decodable`) and messages that do
        not decode are skipped and counted (`reading_notes`). Unfinished files are read in file
        order (the order their writer appended, which for our recorder is log-time order).
        """
        from tqdm import tqdm

        wanted = None if topics is None else set(topics)
        if decode:
            self.require_decodable(sorted(wanted if wanted is not None else
                                          (t for t, i in self.topics.items() if not i.problem)))
            if wanted is None:
                wanted = {t for t, i in self.topics.items() if not i.problem}
        else:
            self.require_topics(sorted(wanted or ()))
        total = sum(i.count for n, i in self.topics.items() if wanted is None or n in wanted)
        bar = tqdm(total=total, desc=desc, unit="msg", disable=(not progress) or None, mininterval=0.5, leave=False)
        try:
            for schema, channel, message in self._raw(wanted, start_ns, end_ns):
                bar.update(1)
                msg = None
                if decode:
                    msg = self._decode(channel, message)
                    if msg is None:
                        continue
                yield BagMessage(channel.topic, normalise_type(schema.name) if schema else "",
                                 message.log_time, message.publish_time, message.data, msg)
        finally:
            bar.close()

    def raw_messages(self, *, progress: bool = False) -> Iterator[tuple]:
        """(schema, channel, message) records of every topic in log-time order, as the file holds them.

        Messages of decodable topics that do not decode are skipped (counted as `messages` does);
        those of undecodable topics (`TopicInfo.problem`) are passed through undecoded.
        """
        from tqdm import tqdm
        bar = tqdm(total=self.message_count, desc="reading", unit="msg", disable=(not progress) or None,
                   mininterval=0.5, leave=False)
        try:
            for schema, channel, message in self._raw(None, None, None):
                bar.update(1)
                if self.topics[channel.topic].problem or self._decode(channel, message) is not None:
                    yield schema, channel, message
        finally:
            bar.close()

    def check(self, progress: bool = False) -> None:
        """Decode every message of every decodable topic, counting the malformed ones (`TopicInfo.malformed`)."""
        for _ in self.messages(progress=progress, desc="checking"):
            pass

    def _raw(self, wanted, start_ns, end_ns):
        def keep(channel, message) -> bool:
            return ((wanted is None or channel.topic in wanted)
                    and (start_ns is None or message.log_time >= start_ns)
                    and (end_ns is None or message.log_time <= end_ns))

        if self._indexed:
            yield from self._indexed_raw(wanted, start_ns, end_ns, keep)
            return
        for schema, channel, message in walk_records(self.path, Scan()):
            if keep(channel, message):
                yield schema, channel, message

    def _chunk_at(self, f, ci) -> list:
        """The records of the chunk a chunk index points at; ChunkSkipped saying why it cannot be used."""
        from mcap.data_stream import ReadDataStream
        from mcap.opcode import Opcode
        from mcap.records import Chunk

        if ci.chunk_length < 9 or ci.chunk_start_offset + ci.chunk_length > self._size:
            raise ChunkSkipped("its index points past the end of the file")
        f.seek(ci.chunk_start_offset)
        opcode, length = struct.unpack("<BQ", f.read(9))
        if opcode != Opcode.CHUNK or length != ci.chunk_length - 9:
            raise ChunkSkipped("its index does not point at a chunk")
        if length > MAX_RECORD_BYTES:
            raise ChunkSkipped(f"a record of {length} bytes, more than the {MAX_RECORD_BYTES >> 20} MiB a record "
                               "may hold here")
        try:
            chunk = Chunk.read(ReadDataStream(io.BytesIO(f.read(length))))
        except damaged_data_errors() as e:
            raise ChunkSkipped(f"the chunk record does not parse ({type(e).__name__})") from None
        return chunk_records(chunk)

    def _indexed_raw(self, wanted, start_ns, end_ns, keep):
        """Messages of a finished file in log-time order, chunk by chunk through the chunk indexes.

        A chunk is decompressed only when its first log time is due (a merge over overlapping
        chunks); one that fails its checks is skipped and noted, and messages on channels the
        summary does not declare are skipped.
        """
        import heapq

        from mcap.records import Message

        ids = None if wanted is None else {cid for t in wanted for cid in self.topics[t].channel_ids}
        chunks = [ci for ci in self._chunk_indexes
                  if (ids is None or ids & ci.message_index_offsets.keys())
                  and (start_ns is None or ci.message_end_time >= start_ns)
                  and (end_ns is None or ci.message_start_time <= end_ns)]
        heap: list = []
        seq = 0
        i = 0
        with open(self.path, "rb") as f:
            while i < len(chunks) or heap:
                while i < len(chunks) and (not heap or chunks[i].message_start_time <= heap[0][0]):
                    ci = chunks[i]
                    i += 1
                    try:
                        records = self._chunk_at(f, ci)
                    except ChunkSkipped as e:
                        self._bad_chunks[ci.chunk_start_offset] = str(e)
                        continue
                    for rec in records:
                        if isinstance(rec, Message):
                            channel = self._channels.get(rec.channel_id)
                            if channel is not None and keep(channel, rec):
                                heapq.heappush(heap, (rec.log_time, seq, channel, rec))
                                seq += 1
                if heap:
                    _, _, channel, message = heapq.heappop(heap)
                    yield self._schemas.get(channel.schema_id), channel, message


def open_bag(path) -> Bag:
    """Open an MCAP file (or a rosbag2 directory with one .mcap); BagError with a clear message otherwise."""
    try:
        return Bag(path)
    except BagError:
        raise
    except PermissionError as e:
        raise BagError(f"{path}: cannot read ({e.strerror})") from None
    except IsADirectoryError:
        raise BagError(f"{path}: is a directory without a single .mcap file") from None
    except OSError as e:
        raise BagError(f"{path}: cannot read ({e.strerror or e})") from None


# ---- topics prsm-bag works with --------------------------------------------------------------

def _role(key: str) -> tuple[str, str, str]:
    """(message type, name suffix that identifies it in our interface, default full name) of a topic."""
    t = TOPIC_DEFS[key]
    return t.type_name, "/" + t.name.removeprefix("~/").lstrip("/"), t.resolved()


# role → (message type, name suffix, default full name), from the node's interface
ROLES: dict[str, tuple[str, str, str]] = {
    role: _role(key) for role, key in (
        ("joint_states", "joint_states"), ("joint_commands", "joint_commands"), ("wrench", "wrench"),
        ("internal_loads", "internal_loads"), ("labels", "labels"), ("reference", "nut_position_reference"),
        ("screw_torque", "screw_torque"), ("clock", "clock"))
}
# Roles that may fall back to the only topic of their type when no name matches (other recorders).
_BY_TYPE_ALONE = ("joint_states", "wrench")
# Older types a role also accepts: the reference was a plain Float64 before it was stamped.
_ALSO_TYPES = {"reference": ("std_msgs/msg/Float64",)}


def _given_topic(bag: Bag, role: str, topic: str, type_name: str) -> str:
    """`topic`, named for `role` on the command line, checked: present, of the role's type, decodable."""
    if topic not in bag.topics:
        raise BagError(f"{bag.path.name}: no topic {topic!r} (given for {role}); "
                       f"topics: {', '.join(sorted(bag.topics)) or 'none'}")
    if bag.topics[topic].type not in (type_name, *_ALSO_TYPES.get(role, ())):
        raise BagError(f"{bag.path.name}: topic {topic!r} is {bag.topics[topic].type}; {role} needs {type_name}")
    bag.require_decodable([topic])
    return topic


def _found_topic(bag: Bag, role: str, type_name: str, suffix: str, default: str) -> str | None:
    """The topic of `bag` that plays `role`, by type and name suffix (None: none; BagError: several)."""
    typed = [t for ty in (type_name, *_ALSO_TYPES.get(role, ())) for t in bag.topics_of_type(ty)
             if not bag.topics[t].problem]
    named = [t for t in typed if t == suffix or t.endswith(suffix)]
    if role in _BY_TYPE_ALONE and not named:
        others = [t for t in typed if not any(t.endswith(s) for r, (ty, s, _) in ROLES.items()
                                               if r != role and ty == type_name)]
        named = others if len(others) == 1 else []
    if len(named) > 1:
        if default in named:
            named = [default]
        else:
            flag = role.replace("_", "-")
            raise BagError(f"{bag.path.name}: several topics could be {role}: {', '.join(named)}; "
                           f"choose one with --{flag}-topic")
    return named[0] if named else None


def resolve_topics(bag: Bag, overrides: dict[str, str | None] | None = None) -> dict[str, str | None]:
    """role → topic in `bag` (None when absent). `overrides` names topics explicitly (checked).

    A role matches topics of its type whose name ends with the role's suffix; with several, the
    default full name wins, else BagError asks for an explicit choice. JointState and WrenchStamped
    topics of other recorders are accepted by type alone when they are the only candidate.
    """
    overrides = {k: v for k, v in (overrides or {}).items() if v}
    out: dict[str, str | None] = {}
    for role, (type_name, suffix, default) in ROLES.items():
        if role in overrides:
            out[role] = _given_topic(bag, role, overrides[role], type_name)
        else:
            out[role] = _found_topic(bag, role, type_name, suffix, default)
    return out
