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
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

from prsm_sim.errors import PrsmError

from prsm_ros.interface import TOPIC_DEFS
from prsm_ros.limits import file_kind

MAGIC = b"\x89MCAP0\r\n"
# A chunk's uncompressed size is allocated before it is read: a damaged size must not decide it.
# rosbag2 writes 768 KiB chunks, the mcap CLI 4 MiB, our recorder 1 MiB.
MAX_CHUNK_BYTES = 256 << 20
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


def chunk_records(chunk) -> list:
    """The schema, channel and message records inside one chunk, after its size and CRC are checked.

    Raises ChunkSkipped naming the reason: a declared size over MAX_CHUNK_BYTES (so a damaged length
    cannot make the reader allocate it), data that does not decompress to the declared size, a CRC
    mismatch (a CRC of 0 means "not computed", MCAP spec), records that do not parse.
    """
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Message, Schema

    size = chunk.uncompressed_size
    if size > MAX_CHUNK_BYTES:
        raise ChunkSkipped(f"declares {size} bytes uncompressed, more than the {MAX_CHUNK_BYTES >> 20} MiB "
                           "a chunk may hold here")
    try:
        if chunk.compression == "zstd":
            import zstandard
            declared = zstandard.frame_content_size(chunk.data)
            if declared not in (-1, size):  # -1: the frame does not say
                raise ChunkSkipped(f"its zstd frame holds {declared} bytes, the chunk declares {size}")
            data = zstandard.ZstdDecompressor().decompress(chunk.data, max_output_size=size)
        elif chunk.compression == "lz4":
            import lz4.frame
            data = lz4.frame.decompress(chunk.data)
        elif chunk.compression == "":
            data = chunk.data
        else:
            raise ChunkSkipped(f"unknown compression {chunk.compression[:40]!r}")
    except ImportError as e:
        raise ChunkSkipped(f"{chunk.compression} compression needs the {e.name} package") from None
    except damaged_data_errors() as e:
        raise ChunkSkipped(f"does not decompress ({type(e).__name__})") from None
    if len(data) != size:
        raise ChunkSkipped(f"decompresses to {len(data)} bytes, the chunk declares {size}")
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ChunkSkipped("CRC mismatch")
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


def walk_records(path, scan: Scan) -> Iterator[tuple]:
    """The generator behind `scan_records`: yields (schema, channel, message), fills `scan`."""
    from mcap.data_stream import ReadDataStream
    from mcap.opcode import Opcode
    from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema

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

    damaged = damaged_data_errors()
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        _require_magic(f, path)
        pos = 8
        while True:
            head = f.read(9)
            if len(head) < 9:
                scan.stopped_at = pos
                break
            opcode, length = struct.unpack("<BQ", head)
            if length > size - pos - 9:  # cut short, or a damaged length: nothing after it can be framed
                scan.stopped_at = pos
                break
            body = f.read(length)
            stream = ReadDataStream(io.BytesIO(body))
            found = []
            try:
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
                    scan.complete = f.read(8) == MAGIC
                    break
            except damaged as e:  # a damaged record: keep what came before it
                scan.stopped_at = pos
                scan.problem = f"damaged record at byte {pos} ({type(e).__name__})"
                break
            yield from (item for item in found if item is not None)
            pos += 9 + length


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
        elif scan.complete and self._summary_damaged:
            self.notes.append(f"{self.path.name}: the summary could not be read (damaged footer or summary); "
                              "read by scanning the records")
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

    def _indexed_raw(self, wanted, start_ns, end_ns, keep):
        """Messages of a finished file in log-time order, chunk by chunk through the chunk indexes.

        A chunk is decompressed only when its first log time is due (a merge over overlapping
        chunks); one that fails its checks is skipped and noted, and messages on channels the
        summary does not declare are skipped.
        """
        import heapq

        from mcap.data_stream import ReadDataStream
        from mcap.opcode import Opcode
        from mcap.records import Chunk, Message

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
                        if ci.chunk_length < 9 or ci.chunk_start_offset + ci.chunk_length > self._size:
                            raise ChunkSkipped("its index points past the end of the file")
                        f.seek(ci.chunk_start_offset)
                        opcode, length = struct.unpack("<BQ", f.read(9))
                        if opcode != Opcode.CHUNK or length != ci.chunk_length - 9:
                            raise ChunkSkipped("its index does not point at a chunk")
                        try:
                            chunk = Chunk.read(ReadDataStream(io.BytesIO(f.read(length))))
                        except damaged_data_errors() as e:
                            raise ChunkSkipped(f"the chunk record does not parse ({type(e).__name__})") from None
                        records = chunk_records(chunk)
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
            t = overrides[role]
            if t not in bag.topics:
                raise BagError(f"{bag.path.name}: no topic {t!r} (given for {role}); "
                               f"topics: {', '.join(sorted(bag.topics)) or 'none'}")
            if bag.topics[t].type not in (type_name, *_ALSO_TYPES.get(role, ())):
                raise BagError(f"{bag.path.name}: topic {t!r} is {bag.topics[t].type}; {role} needs {type_name}")
            bag.require_decodable([t])
            out[role] = t
            continue
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
        out[role] = named[0] if named else None
    return out
