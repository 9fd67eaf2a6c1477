"""`prsm-bag repair IN OUT`: rewrite what a damaged or unfinished MCAP file still holds as a finished one.

A recording killed mid-run has no summary or footer; readers that seek by the summary (Rerun's
`rerun mcap`, the mcap library's `make_reader`) then refuse it or see nothing. `repair` reads the
file as `prsm-bag` does (record by record when the summary is missing or damaged, skipping damaged
chunks, messages on undeclared channels and messages that do not decode with their schema) and
writes every message it recovered, with the same schemas, channels (QoS metadata included),
metadata records, profile and log/publish times, into a new file with chunk indexes, statistics
and a footer. Messages of topics whose schema cannot be decoded are copied as they are.

The output is written to a temporary file beside OUT and renamed into place when finished, so an
interrupted repair leaves no half-written OUT; OUT may not be IN.
"""

from __future__ import annotations

import os
from pathlib import Path

from prsm_ros.bag.reader import Bag, BagError


def repair(bag: Bag, out, *, progress: bool = False) -> dict:
    """Write `bag`'s recoverable content to `out` as a finished MCAP file; returns counts and notes."""
    from mcap.writer import CompressionType, IndexType, Writer

    from prsm_ros.mcap.recorder import DEFAULT_CHUNK_SIZE

    out = Path(out)
    if out.exists() and out.resolve() == bag.path.resolve():
        raise BagError(f"{out}: the output would overwrite the bag being repaired; give another path")
    if not out.parent.is_dir():
        raise BagError(f"{out.parent}: no such directory for the output")
    tmp = out.with_name(f".{out.name}.{os.getpid()}.part")
    written = 0
    try:
        with open(tmp, "wb") as f:
            w = Writer(f, chunk_size=DEFAULT_CHUNK_SIZE, compression=CompressionType.ZSTD, index_types=IndexType.ALL)
            w.start(profile=bag.profile, library=bag.library or "prsm-bag repair")
            for name, data in bag.metadata.items():
                w.add_metadata(name, data)
            schema_ids: dict[int, int] = {}
            channel_ids: dict[int, int] = {}
            for schema, channel, message in bag.raw_messages(progress=progress):
                cid = channel_ids.get(channel.id)
                if cid is None:
                    sid = 0
                    if schema is not None:
                        sid = schema_ids.get(schema.id)
                        if sid is None:
                            sid = schema_ids[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
                    cid = channel_ids[channel.id] = w.register_channel(channel.topic, channel.message_encoding, sid,
                                                                       dict(channel.metadata))
                w.add_message(cid, message.log_time, message.data, message.publish_time, message.sequence)
                written += 1
            w.finish()
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return {"input": str(bag.path), "output": str(out), "messages": written,
            "topics": len({c for c in channel_ids}), "notes": [*bag.notes, *bag.reading_notes()]}
