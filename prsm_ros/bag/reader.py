"""Reading ROS 2 MCAP files for `prsm-bag`: ours or recorded elsewhere, finished or not.

A finished file is read through its summary (schemas, channels, statistics, chunk and metadata
indexes) with the mcap library's seeking reader. A file without a summary or footer — a recording
killed mid-run — is read by `scan_records`, which walks the records from the start and keeps every
complete one, chunks included, stopping at the first truncated record; `Bag.note` then says what
was recovered. Messages are decoded with mcap_ros2's CDR decoder from the file's own `ros2msg`
schemas, so no ROS package needs to be installed to read a bag.

`resolve_topics` finds the topics `prsm-bag` works with by type and name (DESIGN.md topic table),
so a bag from another recorder with standard JointState / WrenchStamped topics works too.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

from prsm_sim.errors import PrsmError

from prsm_ros.interface import TOPIC_DEFS

MAGIC = b"\x89MCAP0\r\n"


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


@dataclass
class Scan:
    """What a record walk found: header, schemas, channels, metadata, whether the file ended properly."""

    header: object | None = None
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    metadata: list = field(default_factory=list)
    complete: bool = False
    chunks: int = 0
    stopped_at: int | None = None
    problem: str | None = None


def scan_records(path, on_message=None) -> Scan:
    """Walk an MCAP file record by record, keeping every complete record; stop at a truncated one.

    The recovery routine for unfinished files (MCAP spec: records are length-prefixed, chunks are
    self-contained): schemas, channels and metadata are collected into the returned `Scan`, and
    each message (in complete chunks or bare) is passed to `on_message(schema, channel, message)`
    in file order.
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
    from mcap.stream_reader import breakup_chunk

    def take(rec):
        if isinstance(rec, Schema):
            scan.schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            scan.channels[rec.id] = rec
        elif isinstance(rec, Message):
            ch = scan.channels.get(rec.channel_id)
            if ch is not None:
                return scan.schemas.get(ch.schema_id), ch, rec
        return None

    damaged = damaged_data_errors()
    with open(path, "rb") as f:
        _require_magic(f, path)
        pos = 8
        while True:
            head = f.read(9)
            if len(head) < 9:
                scan.stopped_at = pos
                break
            opcode, length = struct.unpack("<BQ", head)
            body = f.read(length) if length < (1 << 34) else b""
            if len(body) < length:
                scan.stopped_at = pos
                break
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
                    found = [take(rec) for rec in breakup_chunk(Chunk.read(stream))]
                    scan.chunks += 1
                elif opcode == Opcode.FOOTER:
                    scan.complete = f.read(8) == MAGIC
                    break
            except damaged as e:  # a damaged record: keep what came before it
                scan.stopped_at = pos
                scan.problem = f"damaged record at byte {pos} ({type(e).__name__})"
                break
            yield from (item for item in found if item is not None)
            pos += 9 + length


class Bag:
    """One MCAP file opened for reading: topics, run metadata, decoded messages.

    `complete` is False for a file without footer (unfinished recording); `note` says what was
    recovered then. Raises BagError for a file that is not MCAP.
    """

    def __init__(self, path) -> None:
        self.path = resolve_path(path)
        self.complete = True
        self.note: str | None = None
        self.profile = ""
        self.library = ""
        self.metadata: dict[str, dict[str, str]] = {}
        self.topics: dict[str, TopicInfo] = {}
        self._schemas: dict = {}
        self._channels: dict = {}
        self._decoders: dict[int, object] = {}
        self._indexed = False  # finished file with chunk indexes: read through the seeking reader
        with open(self.path, "rb") as f:
            _require_magic(f, self.path)
        summary = self._read_summary()
        if summary is None:
            self._load_by_scan()

    # ---- loading -----------------------------------------------------------------------------

    def _read_summary(self):
        """Header, summary and metadata of a finished file; None when the file must be scanned."""
        from mcap.reader import SeekingReader
        try:
            with open(self.path, "rb") as f:
                reader = SeekingReader(f)
                header = reader.get_header()
                summary = reader.get_summary()
                if summary is None or summary.statistics is None or not summary.chunk_indexes:
                    return None  # nothing to seek by: scanning gives the per-topic times too
                metadata = list(reader.iter_metadata())
                message_index_times = self._channel_time_ranges(f, summary)
        except damaged_data_errors():  # no footer, damaged summary: fall back to scanning the records
            return None
        self.profile, self.library = header.profile, header.library
        self._schemas, self._channels = dict(summary.schemas), dict(summary.channels)
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
            self.note = (f"{self.path.name}: unfinished MCAP file ({why}); recovered {scan.chunks} complete "
                         f"chunk(s), {n} message(s){upto}; data after byte {scan.stopped_at} was lost")

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

    def require_topics(self, topics) -> None:
        """BagError naming the topics the bag has when one of `topics` is not in it."""
        for t in topics:
            if t not in self.topics:
                raise BagError(f"{self.path.name}: no topic {t!r}; topics: {', '.join(sorted(self.topics)) or 'none'}")

    def window_ns(self, start_s: float | None, end_s: float | None) -> tuple[int | None, int | None]:
        """Log-time bounds (ns) for a range given in seconds from the bag's first message; None = open.

        BagError when `end_s` is before `start_s`.
        """
        if start_s is not None and end_s is not None and end_s < start_s:
            raise BagError(f"--end {end_s} is before --start {start_s}")
        base = self.start_ns or 0
        return (None if start_s is None else base + int(round(start_s * 1e9)),
                None if end_s is None else base + int(round(end_s * 1e9)))

    def topics_of_type(self, type_name: str) -> list[str]:
        t = normalise_type(type_name)
        return [name for name, info in self.topics.items() if info.type == t]

    def _decode(self, schema, channel, message):
        dec = self._decoders.get(channel.id, False)
        if dec is False:
            from mcap_ros2.decoder import DecoderFactory
            try:
                dec = DecoderFactory().decoder_for(channel.message_encoding, schema)
            # a schema mcap_ros2 cannot parse or does not implement (wstring): the raw bytes are still available
            except (ValueError, NotImplementedError, *damaged_data_errors()):
                dec = None
            except Exception as e:  # its schema parser's own errors, whose classes only a private module exports
                if not type(e).__module__.startswith("mcap_ros2."):
                    raise
                dec = None
            self._decoders[channel.id] = dec
        if dec is None:
            return None
        try:
            return dec(message.data)
        except (IndexError, *damaged_data_errors()) as e:  # CDR cut short or not matching its schema
            raise BagError(f"{self.path.name}: a message on {channel.topic} at log time {message.log_time} ns "
                           f"does not decode with its schema {schema.name if schema else '(none)'} "
                           f"({type(e).__name__}: {e})") from None

    def messages(self, topics=None, start_ns: int | None = None, end_ns: int | None = None, *,
                 decode: bool = True, progress: bool = False, desc: str = "reading") -> Iterator[BagMessage]:
        """Messages of `topics` (all when None) with start_ns <= log time <= end_ns, in log-time order.

        Unfinished files are read in file order (the order their writer appended, which for our
        recorder is log-time order).
        """
        from tqdm import tqdm

        wanted = None if topics is None else set(topics)
        self.require_topics(sorted(wanted or ()))
        total = sum(i.count for n, i in self.topics.items() if wanted is None or n in wanted)
        bar = tqdm(total=total, desc=desc, unit="msg", disable=(not progress) or None, mininterval=0.5, leave=False)
        try:
            for schema, channel, message in self._raw(wanted, start_ns, end_ns):
                bar.update(1)
                yield BagMessage(channel.topic, normalise_type(schema.name) if schema else "",
                                 message.log_time, message.publish_time, message.data,
                                 self._decode(schema, channel, message) if decode else None)
        finally:
            bar.close()

    def _raw(self, wanted, start_ns, end_ns):
        def keep(channel, message) -> bool:
            return ((wanted is None or channel.topic in wanted)
                    and (start_ns is None or message.log_time >= start_ns)
                    and (end_ns is None or message.log_time <= end_ns))

        if self._indexed:
            from mcap.reader import SeekingReader
            with open(self.path, "rb") as f:
                reader = SeekingReader(f)
                try:
                    for schema, channel, message in reader.iter_messages(
                            topics=None if wanted is None else sorted(wanted), log_time_order=True):
                        if keep(channel, message):
                            yield schema, channel, message
                except damaged_data_errors() as e:  # a finished file whose chunk was damaged after writing
                    raise BagError(f"{self.path.name}: damaged chunk data ({type(e).__name__}: {e})") from None
            return
        for schema, channel, message in walk_records(self.path, Scan()):
            if keep(channel, message):
                yield schema, channel, message

    def read_topic(self, topic: str, start_ns: int | None = None, end_ns: int | None = None,
                   progress: bool = False) -> list[BagMessage]:
        return list(self.messages([topic], start_ns, end_ns, progress=progress, desc=topic))


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
            if bag.topics[t].type != type_name:
                raise BagError(f"{bag.path.name}: topic {t!r} is {bag.topics[t].type}; {role} needs {type_name}")
            out[role] = t
            continue
        typed = bag.topics_of_type(type_name)
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
