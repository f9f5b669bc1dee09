"""The Metadata records of a finished MCAP file whose summary has no metadata index.

mcap's reader (and the fast reader's summary pass) find metadata records through the summary's
metadata index. Another writer may leave that index out (the official ``mcap`` Writer with
``index_types`` without ``IndexType.METADATA``, a rewritten or recovered file): the session record is
still in the data section, between the chunks. ``metadata_between_chunks`` walks the data section's
top-level records by their 9-byte prefixes (opcode u8, length u64), jumping over each chunk whole, so
the work is one prefix per record (a chunk, its message indexes, metadata, attachments), never the
chunks' bytes. Anything that is not a chain of data-section records ending at ``end`` or at the
DataEnd record raises ValueError.
"""

from __future__ import annotations

import io
import mmap
import struct
from pathlib import Path

from mcap.data_stream import ReadDataStream
from mcap.records import Metadata

from accellog.store.layout import MCAP_MAGIC

_PREFIX = struct.Struct("<BQ")
_OP_HEADER, _OP_METADATA, _OP_DATA_END = 0x01, 0x0C, 0x0F
_FOOTER_BYTES = 9 + 20  # footer record: prefix, summary start u64, summary offset start u64, crc u32


def metadata_between_chunks(data, end: int) -> list[int]:
    """Offsets (file order) of the Metadata records between the header and ``end`` (the summary
    start, or the footer) of the mapped file ``data`` (module doc)."""
    magic = len(MCAP_MAGIC)
    op, ln = _PREFIX.unpack_from(data, magic)
    if data[:magic] != MCAP_MAGIC or op != _OP_HEADER:
        raise ValueError("no MCAP header record")
    pos = magic + 9 + ln
    found: list[int] = []
    while pos + 9 <= end:
        op, ln = _PREFIX.unpack_from(data, pos)
        if op == _OP_DATA_END:
            return found
        if not 0x03 <= op <= 0x0E or pos + 9 + ln > end:
            raise ValueError(f"data section record {op:#x} at byte {pos}")
        if op == _OP_METADATA:
            found.append(pos)
        pos += 9 + ln
    if pos != end:
        raise ValueError(f"the data section ends inside a record (byte {pos})")
    return found


def scanned_metadata(path: str | Path) -> list[Metadata]:
    """The Metadata records of a finished file found by ``metadata_between_chunks`` (for a summary
    without a metadata index), parsed by mcap's own record parser."""
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        footer = len(data) - len(MCAP_MAGIC) - _FOOTER_BYTES
        if footer < len(MCAP_MAGIC) or data[footer] != 0x02:
            raise ValueError("no MCAP footer")
        start = int.from_bytes(data[footer + 9 : footer + 17], "little")
        end = start if 0 < start <= footer else footer
        out = []
        for at in metadata_between_chunks(data, end):
            ln = _PREFIX.unpack_from(data, at)[1]
            out.append(Metadata.read(ReadDataStream(io.BytesIO(data[at + 9 : at + 9 + ln]))))
        return out
