"""The MCAP writer's per-message work for CDR bytes, with one struct call per message.

`mcap.writer.Writer.add_message` builds a `Message` record object per message, writes it field
by field (six struct calls and a seek back for its length), and keeps each chunk's message index
as a list of tuples that it writes, when the chunk closes, with two struct calls per entry while
holding the interpreter lock the node's step thread needs. Profiled in the node at 1 kHz
(jones2016, recording on) the recorder thread was the second largest cost of the process, most of
it in that Python. `FastMessages.add_many` does the same work on the writer's own state for a batch (the node's
step): a record header in one `struct.pack`, the index entries in an `array` written in one piece,
the batch's records in one write and its time spans widened once; the file is the same bytes
(`tests/test_recorder.py` compares both paths byte for byte), including where chunks close.

It reaches into the writer's private state (mcap 1.x); `FastMessages.attach` returns None when
that state is not laid out as expected (another mcap version), and the caller keeps
`Writer.add_message`.
"""

from __future__ import annotations

import struct
import sys
from array import array
from collections import defaultdict
from io import BytesIO

MESSAGE_OPCODE = 0x05  # MCAP record opcodes (mcap.opcode.Opcode)
MESSAGE_INDEX_OPCODE = 0x07
# opcode, record length, channel id, sequence, log time, publish time (the MCAP Message record's header)
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = 2 + 4 + 8 + 8  # record bytes besides the data


def _extend_span(record, first: bool, log_time: int) -> None:
    """A record's message start and end times (statistics, chunk) widened to `log_time`, as mcap does."""
    if first or log_time < record.message_start_time:
        record.message_start_time = log_time
    if log_time > record.message_end_time:
        record.message_end_time = log_time


class PackedMessageIndex:
    """A chunk's message index for one channel: (log time, offset) pairs in one `array('Q')`, written
    as `mcap.records.MessageIndex` writes its list of tuples (same bytes)."""

    __slots__ = ("channel_id", "entries")

    def __init__(self, channel_id: int) -> None:
        self.channel_id = channel_id
        self.entries = array("Q")

    @property
    def records(self) -> list[tuple[int, int]]:
        e = self.entries
        return list(zip(e[0::2], e[1::2], strict=True))

    def write(self, stream) -> None:
        body = self.entries.tobytes()
        stream.write(struct.pack("<BQHI", MESSAGE_INDEX_OPCODE, 2 + 4 + len(body), self.channel_id, len(body)))
        stream.write(body)


class FastMessages:
    """`Writer.add_message` for bytes, on one writer's state (see the module doc)."""

    def __init__(self, writer, chunk_builder, statistics, chunk_size: int) -> None:
        self._writer = writer
        self._builder = chunk_builder
        self._stats = statistics
        self._chunk_size = chunk_size
        self._finalize = writer._Writer__finalize_chunk

    @classmethod
    def attach(cls, writer, chunk_size: int) -> FastMessages | None:
        """The fast path for `writer` (mcap.writer.Writer, chunked), or None when its private state is not
        the one this was written for (another mcap version, no chunking, a big-endian machine)."""
        builder = getattr(writer, "_Writer__chunk_builder", None)
        stats = getattr(writer, "_Writer__statistics", None)
        record_writer = getattr(builder, "record_writer", None)
        if (sys.byteorder != "little" or array("Q").itemsize != 8 or builder is None or stats is None
                or not isinstance(getattr(record_writer, "_buffer", None), BytesIO)
                or type(getattr(builder, "message_indices", None)) is not dict
                or not isinstance(getattr(stats, "channel_message_counts", None), defaultdict)
                or not callable(getattr(writer, "_Writer__finalize_chunk", None))
                or getattr(writer, "_Writer__chunk_size", None) != chunk_size
                or not all(hasattr(builder, a) for a in ("num_messages", "message_start_time", "message_end_time"))
                or not all(hasattr(stats, a) for a in ("message_count", "message_start_time", "message_end_time"))):
            return None
        return cls(writer, builder, stats, chunk_size)

    def add(self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int) -> None:
        """As `Writer.add_message(channel_id, log_time, data, publish_time, sequence)`."""
        self.add_many([(channel_id, log_time, data, publish_time, sequence)])

    def add_many(self, messages: list[tuple[int, int, bytes, int, int]]) -> None:
        """As `Writer.add_message(*m)` for each `m` = (channel_id, log_time, data, publish_time, sequence), in order.

        Per message only the record header, its index entry and the channel's count are Python; the
        records go into the chunk in one write, and the time spans are widened once per chunk
        segment. A chunk still closes right after the message that takes it past `chunk_size`.
        """
        i, n = 0, len(messages)
        while i < n:
            i = self._fill(messages, i)

    def _fill(self, messages, start: int) -> int:
        """Add messages from `start` until the chunk is full or none are left; returns the next index."""
        st, cb = self._stats, self._builder
        buf = cb.record_writer._buffer
        indices, counts, pack = cb.message_indices, st.channel_message_counts, _MESSAGE_HEAD.pack
        limit = self._chunk_size
        pos = buf.tell()
        parts: list[bytes] = []
        end = len(messages)
        for k in range(start, end):
            channel_id, log_time, data, publish_time, sequence = messages[k]
            index = indices.get(channel_id)
            if index is None:
                index = indices[channel_id] = PackedMessageIndex(channel_id)
            entries = index.entries
            entries.append(log_time)
            entries.append(pos)
            counts[channel_id] += 1
            parts.append(pack(MESSAGE_OPCODE, _MESSAGE_FIXED + len(data), channel_id, sequence, log_time,
                              publish_time))
            parts.append(data)
            pos += _MESSAGE_HEAD.size + len(data)
            if pos > limit:
                end = k + 1
                break
        buf.write(b"".join(parts))
        added = end - start
        times = [m[1] for m in messages[start:end]]
        lo, hi = min(times), max(times)
        _extend_span(st, st.message_count == 0, lo)  # the file's statistics
        _extend_span(st, False, hi)
        st.message_count += added
        _extend_span(cb, cb.num_messages == 0, lo)  # the chunk's
        _extend_span(cb, False, hi)
        cb.num_messages += added
        if pos > limit:
            self._finalize()
        return end
