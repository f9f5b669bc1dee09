"""The summary section of a finished MCAP file without its chunk indexes.

mcap's ``SeekingReader.get_summary`` makes a Python object of every chunk index: a day of live
recording (0.5 s chunks) has ~170 k of them, ~75 MB and ~2 s. Asking whether a file is a ROS 2 bag,
listing its statistics or attachments does not need them. ``summary_of`` walks the summary records
(``index.read_summary``, which keeps only the chunk index offsets, 8 bytes each) and parses the
statistics, attachment index and metadata records with mcap's own record parsers. Raises
``index.NotFast`` (or ``SummaryDamaged``) where the file is not one it takes: the callers then
use mcap's reader.
"""

from __future__ import annotations

import io
import mmap
from dataclasses import dataclass
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.records import Attachment, AttachmentIndex, Channel, Schema, Statistics

from accellog.store.collect import release_pages
from accellog.store.mcap.index import PAGES_AT_ONCE, REC, read_footer, read_metadata, read_summary
from accellog.store.mcap.records import metadata_between_chunks

OP_ATTACHMENT, OP_ATTACHMENT_INDEX, OP_STATISTICS = 0x09, 0x0A, 0x0B


@dataclass
class SummaryFacts:
    schemas: dict[int, Schema]
    channels: dict[int, Channel]
    statistics: Statistics | None
    attachment_indexes: list[AttachmentIndex]
    metadata: dict[str, dict[str, str]]
    """Every metadata record, by name."""


def _record(data, at: int, ln: int, kind):
    return kind.read(ReadDataStream(io.BytesIO(data[at + 9 : at + 9 + ln])))


def summary_of(path: str | Path) -> SummaryFacts:
    """The summary of a finished file, chunk indexes left out (module doc)."""
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        footer, start, _verified = read_footer(data)
        schemas, channels, _at, _len, metadata_at = read_summary(data, footer, start)
        stats, attach, pos, released = None, [], start, start
        while pos < footer:
            if pos - released > PAGES_AT_ONCE:  # a day's summary is ~14 MB: drop what was read
                release_pages(data, released, pos)
                released = pos
            op, ln = REC.unpack_from(data, pos)
            if op == OP_STATISTICS:
                stats = _record(data, pos, ln, Statistics)
            elif op == OP_ATTACHMENT_INDEX:
                attach.append(_record(data, pos, ln, AttachmentIndex))
            pos += 9 + ln
        if not metadata_at:  # written without a metadata index: walk the records between chunks
            metadata_at = metadata_between_chunks(data, start)
        metadata = dict(read_metadata(data, at) for at in metadata_at)
    return SummaryFacts(schemas, channels, stats, attach, metadata)


def attachments_of(path: str | Path, indexes: list[AttachmentIndex]) -> list[Attachment]:
    """The attachment records the indexes point at (each must be an attachment record)."""
    out = []
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        for ix in indexes:
            op, ln = REC.unpack_from(data, ix.offset)
            if op != OP_ATTACHMENT or 9 + ln != ix.length:
                raise ValueError(f"attachment index does not point at an attachment (byte {ix.offset})")
            out.append(_record(data, ix.offset, ln, Attachment))
    return out
