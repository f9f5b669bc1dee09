"""The index of a finished MCAP file, read with struct/numpy: footer, summary section (schemas,
channels, chunk and metadata indexes), chunk headers checked against their index, metadata records.

Used by accellog.store.mcap.fastread (the fast reader); anything outside the canonical layout raises
``NotFast`` and the generic reader decides; ``SummaryDamaged`` means the summary CRC failed.
"""

from __future__ import annotations

import mmap
import struct
from array import array
from dataclasses import dataclass

import numpy as np
from mcap.records import Channel, Schema

from accellog.store.collect import crc32, release_pages
from accellog.store.layout import MCAP_MAGIC
from accellog.store.mcap.byte_views import read_le

REC = struct.Struct("<BQ")  # record prefix: opcode u8, content length u64
U16, U32, U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
OP_CHUNK_INDEX, OP_METADATA, OP_METADATA_INDEX = 0x08, 0x0C, 0x0D
SUMMARY_OPS = {
    0x03,
    0x04,
    0x08,
    0x0A,
    0x0B,
    0x0D,
    0x0E,
}  # schema, channel, chunk/attachment/metadata index, ...
FOOTER_SIZE = 9 + 20
MESSAGE_HEADER = 2 + 4 + 8 + 8  # channel_id u16, sequence u32, log_time u64, publish_time u64
Bytes = (
    bytes | bytearray | mmap.mmap
)  # the file mapped read-only (no copy) by fast_collect, or decompressed records


class NotFast(Exception):
    """The fast reader met something outside the canonical layout: the generic reader decides."""


class Refuse(Exception):
    """Damage the reader cannot work around (e.g. the session metadata record): an InputError."""


class SummaryDamaged(Exception):
    """The summary section fails its CRC: its offsets cannot be trusted; scan the file instead."""


PAGES_AT_ONCE = 1 << 20  # bytes of summary mapped at a time by the index pass (then released)


def summary_sound(data: Bytes, footer: int, summary_start: int) -> bool | None:
    """Footer summary CRC check: True/False, None when the writer stored none (0)."""
    want = U32.unpack_from(data, footer + 25)[0]
    if want == 0:
        return None
    crc, view = 0, memoryview(data)
    for lo in range(summary_start, footer, PAGES_AT_ONCE):  # a day's summary is ~14 MB: a MB at a time
        hi = min(lo + PAGES_AT_ONCE, footer)
        crc = crc32(view[lo:hi], crc)
        release_pages(data, lo, hi)
    return crc32(data[footer : footer + 25], crc) == want


def str_at(data: Bytes, pos: int) -> tuple[str, int]:
    n = U32.unpack_from(data, pos)[0]
    end = pos + 4 + n
    if end > len(data):
        raise NotFast("string past the end")
    return str(data[pos + 4 : end], "utf-8"), end


def map_end(data: Bytes, pos: int) -> int:
    return pos + 4 + U32.unpack_from(data, pos)[0]


def schema_at(data: Bytes, c: int) -> tuple[Schema, int]:
    sid = U16.unpack_from(data, c)[0]
    name, q = str_at(data, c + 2)
    encoding, q = str_at(data, q)
    end = map_end(data, q)
    return Schema(id=sid, name=name, encoding=encoding, data=bytes(data[q + 4 : end])), end


def channel_at(data: Bytes, c: int) -> tuple[Channel, int]:
    cid, sid = struct.unpack_from("<HH", data, c)
    topic, q = str_at(data, c + 4)
    encoding, q = str_at(data, q)
    return Channel(id=cid, topic=topic, message_encoding=encoding, schema_id=sid, metadata={}), map_end(
        data, q
    )


def read_footer(data: Bytes) -> tuple[int, int, bool | None]:
    """(footer offset, summary start, summary CRC verdict) of a finished file."""
    size = len(data)
    if size < 2 * len(MCAP_MAGIC) + FOOTER_SIZE or data[-len(MCAP_MAGIC) :] != MCAP_MAGIC:
        raise NotFast("no footer magic: unfinished file")
    footer = size - len(MCAP_MAGIC) - FOOTER_SIZE
    if REC.unpack_from(data, footer) != (OP_FOOTER, 20):
        raise NotFast("no footer")
    summary_start = U64.unpack_from(data, footer + 9)[0]
    if summary_start == 0 or summary_start >= footer:
        raise NotFast("no summary section")
    verified = summary_sound(data, footer, summary_start)
    if verified is False:
        raise SummaryDamaged("summary section CRC mismatch")
    return footer, summary_start, verified


def read_summary(data: Bytes, footer: int, summary_start: int):
    """Schemas, channels, chunk index offsets and lengths, metadata offsets of the summary section
    (every record parsed must fill its declared length exactly)."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    chunk_index_at, chunk_index_len = array("q"), array("q")  # 8 bytes a chunk, not two int objects
    metadata_at: list[int] = []
    pos = released = summary_start
    while pos < footer:
        if pos - released > PAGES_AT_ONCE:
            release_pages(data, released, pos)
            released = pos
        op, ln = REC.unpack_from(data, pos)
        c, e = pos + 9, pos + 9 + ln
        if op not in SUMMARY_OPS or e > footer:
            raise NotFast(f"summary record {op:#x}")
        if op == OP_SCHEMA:
            sch, q = schema_at(data, c)
            schemas[sch.id] = sch
        elif op == OP_CHANNEL:
            ch, q = channel_at(data, c)
            channels[ch.id] = ch
        elif op == OP_CHUNK_INDEX:
            chunk_index_at.append(c)
            chunk_index_len.append(ln)
            q = e
        elif op == OP_METADATA_INDEX:
            metadata_at.append(U64.unpack_from(data, c)[0])
            q = str_at(data, c + 16)[1]
        else:
            q = e
        if q != e:
            raise NotFast(f"summary record {op:#x} length")
        pos = e
    if pos != footer or not chunk_index_at:
        raise NotFast("summary without chunk indexes")
    if len({ch.topic for ch in channels.values()}) != len(channels):
        raise NotFast("topic on several channels")
    return (
        schemas,
        channels,
        np.frombuffer(chunk_index_at, np.int64),
        np.frombuffer(chunk_index_len, np.int64),
        metadata_at,
    )


@dataclass
class ChunkTable:
    """Per chunk (summary order, arrays, from the chunk indexes alone): chunk index offset ci and
    its message-index map length, chunk offset and length, time range, uncompressed and compressed
    (records) sizes, compression name offset (in the index) and length, records range. The chunk
    headers are checked against these as the chunks are decompressed (``header_agrees``)."""

    ci: np.ndarray
    map_len: np.ndarray
    chunk_at: np.ndarray
    chunk_len: np.ndarray
    t_first: np.ndarray
    t_last: np.ndarray
    usize: np.ndarray
    csize: np.ndarray
    name_at: np.ndarray
    name_len: np.ndarray
    rec_at: np.ndarray
    rec_end: np.ndarray


def chunk_table(
    data: Bytes, footer: int, chunk_index_at: np.ndarray, chunk_index_len: np.ndarray
) -> ChunkTable:
    """Every chunk index read at once (numpy); each must point at a chunk inside the data section."""
    buf = np.frombuffer(data, np.uint8)
    ci = np.asarray(chunk_index_at, dtype=np.int64)
    map_len = read_le(buf, ci + 32, "<u4").astype(np.int64)
    comp_len = read_le(buf, ci + 44 + map_len, "<u4").astype(np.int64)
    if np.any(32 + 4 + map_len + 8 + 4 + comp_len + 16 != np.asarray(chunk_index_len)):
        raise NotFast("chunk index length")
    if np.any(comp_len > 4):  # a compression other than zstd / lz4 / none: the generic reader decides
        raise NotFast("compression")
    t_first = read_le(buf, ci, "<u8").astype(np.int64)
    t_last = read_le(buf, ci + 8, "<u8").astype(np.int64)
    chunk_at = read_le(buf, ci + 16, "<u8").astype(np.int64)
    chunk_len = read_le(buf, ci + 24, "<u8").astype(np.int64)
    csize = read_le(buf, ci + 48 + map_len + comp_len, "<u8").astype(np.int64)
    usize = read_le(buf, ci + 56 + map_len + comp_len, "<u8").astype(np.int64)
    if np.any(chunk_at > footer - 49) or np.any(chunk_at + chunk_len > footer) or np.any(chunk_len < 49):
        raise NotFast("chunk index does not point at a chunk")
    # chunk: opcode, length, start, end u64, uncompressed size u64, crc u32, compression, records (u64 length)
    rec_at = chunk_at + 9 + 40 + comp_len
    return ChunkTable(ci, map_len, chunk_at, chunk_len, t_first, t_last, usize, csize, ci + 48 + map_len,
                      comp_len, rec_at, chunk_at + chunk_len)  # fmt: skip


@dataclass
class ChunkIndex:
    """What a walk keeps of every chunk, 8 bytes a chunk (a day of 0.5 s recorder chunks: 1.4 MB, where
    the whole ChunkTable is ~17 MB): the offset of its chunk index record in the summary. ``rows``
    reads the ChunkTable of some chunks again (record lengths from their prefixes) when needed."""

    footer: int
    ci: np.ndarray

    def rows(self, data: Bytes, which: np.ndarray) -> ChunkTable:
        """The ChunkTable of the chunks `which` (indexes into the summary order)."""
        ci = self.ci[which]
        ln = read_le(np.frombuffer(data, np.uint8), ci - 8, "<u8").astype(np.int64)  # record prefix
        return chunk_table(data, self.footer, ci, ln)


_INDEX_WINDOW = 1 << 15  # chunk_index: chunks checked at a time (bounded temporaries)


def chunk_index(
    data: Bytes, footer: int, chunk_index_at: np.ndarray, chunk_index_len: np.ndarray
) -> tuple[ChunkIndex, np.ndarray]:
    """(index, uncompressed size of every chunk): every chunk index checked as chunk_table checks
    it, _INDEX_WINDOW at a time; NotFast as there."""
    usize = np.empty(chunk_index_at.shape[0], np.int64)
    for lo in range(0, usize.shape[0], _INDEX_WINDOW):
        hi = lo + _INDEX_WINDOW
        usize[lo:hi] = chunk_table(data, footer, chunk_index_at[lo:hi], chunk_index_len[lo:hi]).usize
        _release_indexes(data, chunk_index_at[lo:hi], chunk_index_len[lo:hi])
    return ChunkIndex(footer, chunk_index_at), usize


def _release_indexes(data: Bytes, at: np.ndarray, ln: np.ndarray) -> None:
    """Release the summary pages of these chunk index records (read; ~14 MB a day in all)."""
    if at.shape[0]:
        release_pages(data, int(at.min()), int((at + ln).max()))


CHUNK_HEAD = struct.Struct("<BQQQQII")  # opcode, length, start, end, uncompressed size, crc, name length


def header_agrees(data: Bytes, at: int, chunk_len: int, usize: int, csize: int, name_at: int, name_len: int):
    """The uncompressed CRC of the chunk at byte ``at`` if its header agrees with its chunk index
    (opcode, lengths, sizes, compression), else None."""
    op, ln, _, _, u, crc, nl = CHUNK_HEAD.unpack_from(data, at)
    if op != OP_CHUNK or ln != chunk_len - 9 or u != usize or nl != name_len:
        return None
    q = at + CHUNK_HEAD.size + nl
    if U64.unpack_from(data, q)[0] != csize or data[q - nl : q] != data[name_at : name_at + nl]:
        return None
    return crc if 40 + nl + csize == ln else None


def chunks_with(data: Bytes, ci: np.ndarray, channels, topics, stream) -> np.ndarray | None:
    """Which chunks hold a message of a wanted topic, from each chunk index's message index offsets
    (map channel id u16 -> offset u64); None when every chunk is wanted (all topics, or a chunk
    index without that map: the writer stored no message indexes)."""
    if topics is None or stream is not None:
        return None
    wanted = {cid for cid, ch in channels.items() if ch.topic in set(topics)}
    if len(wanted) == len(channels):
        return None
    wanted_ids = np.fromiter(wanted, np.int64, len(wanted))
    buf = np.frombuffer(data, np.uint8)
    keep = np.zeros(ci.shape[0], bool)
    for lo in range(0, ci.shape[0], _INDEX_WINDOW):  # bounded temporaries and mapped pages
        at = ci[lo : lo + _INDEX_WINDOW]
        map_len = read_le(buf, at + 32, "<u4").astype(np.int64)
        if np.any(map_len <= 0) or np.any(map_len % 10):
            return None
        # every map entry at once: chunk k's entries at at[k] + 36 + 10 j, j < map_len[k] / 10
        count = map_len // 10
        chunk = np.repeat(np.arange(at.shape[0]), count)
        j = np.arange(chunk.shape[0]) - np.repeat(np.cumsum(count) - count, count)
        ids = read_le(buf, at[chunk] + 36 + 10 * j, "<u2")
        keep[lo + chunk[np.isin(ids, wanted_ids)]] = True
        _release_indexes(data, at, 36 + map_len)
    return keep


def read_metadata(data: Bytes, at: int) -> tuple[str, dict[str, str]]:
    """Name and key-values of the Metadata record at byte at (its length must add up)."""
    op, ln = REC.unpack_from(data, at)
    if op != OP_METADATA:
        raise NotFast("metadata index does not point at metadata")
    name, q = str_at(data, at + 9)
    end = map_end(data, q)
    kv: dict[str, str] = {}
    q += 4
    while q < end:
        k, q = str_at(data, q)
        kv[k], q = str_at(data, q)
    if q != end or end != at + 9 + ln:
        raise NotFast("metadata record length")
    return name, kv


def equal_records(rb: np.ndarray, pos: np.ndarray, end: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """``record_starts.chunkwise_starts``' guess for all chunks at once: each chunk (records rb[pos[k]:end[k]])
    holds Message records of the length of its first one only (recorder files: equal FIFO reads).
    Every guessed record's opcode and length are checked, so a chunk that passes is exactly that
    chain. ([Message offsets of the chunks that pass], mask of the chunks left to walk)."""
    room = end - pos - 9
    if not pos.shape[0] or np.any(room < 0):
        return [], np.ones(pos.shape[0], bool)
    ln = read_le(rb, pos + 1, "<u8")
    fits = (rb[pos] == OP_MESSAGE) & (ln <= room.astype(np.uint64))
    stride = np.where(fits, ln.astype(np.int64) + 9, 1)
    fits &= (end - pos) % stride == 0
    k = np.where(fits, (end - pos) // stride, 0)
    if not k.any():
        return [], np.ones(pos.shape[0], bool)
    first = np.cumsum(k) - k  # each chunk's first guess in the flat list
    chunk = np.repeat(np.arange(pos.shape[0]), k)
    guess = pos[chunk] + (np.arange(chunk.shape[0]) - first[chunk]) * stride[chunk]
    bad = (rb[guess] != OP_MESSAGE) | (read_le(rb, guess + 1, "<u8") != ln[chunk])
    fits[chunk[bad]] = False
    return [guess[fits[chunk]]], ~fits
