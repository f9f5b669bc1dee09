"""The index of a finished MCAP file, read with struct/numpy: footer, summary section (schemas,
channels, chunk and metadata indexes), chunk headers checked against their index, metadata records.

Used by accellog.store.fastread (the fast reader); anything outside the canonical layout raises
``NotFast`` and the generic reader decides; ``SummaryDamaged`` means the summary CRC failed.
"""

from __future__ import annotations

import mmap
import struct
from dataclasses import dataclass

import numpy as np
from mcap.records import Channel, Schema

from accellog.store.batch_decode import read_le
from accellog.store.collect import crc32, release_pages
from accellog.store.layout import MCAP_MAGIC

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
HEADER = 56  # bytes of a chunk header the index pass reads: opcode .. records length (name <= 4)
Bytes = bytes | mmap.mmap  # the file: mapped read-only (no copy) by fast_collect


class NotFast(Exception):
    """The fast reader met something outside the canonical layout: the generic reader decides."""


class Refuse(Exception):
    """Damage the reader cannot work around (e.g. the session metadata record): an InputError."""


class SummaryDamaged(Exception):
    """The summary section fails its CRC: its offsets cannot be trusted; scan the file instead."""


def summary_sound(data: Bytes, footer: int, summary_start: int) -> bool | None:
    """Footer summary CRC check: True/False, None when the writer stored none (0)."""
    want = U32.unpack_from(data, footer + 25)[0]
    if want == 0:
        return None
    return crc32(data[footer : footer + 25], crc32(memoryview(data)[summary_start:footer])) == want


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
    return Schema(id=sid, name=name, encoding=encoding, data=data[q + 4 : end]), end


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
    chunk_index_at: list[int] = []
    chunk_index_len: list[int] = []
    metadata_at: list[int] = []
    pos = summary_start
    while pos < footer:
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
    return schemas, channels, chunk_index_at, chunk_index_len, metadata_at


@dataclass
class ChunkTable:
    """Per chunk (summary order, arrays): chunk index offset ci and its message-index map length,
    chunk offset, time range, header content offset c, uncompressed size, CRC, compression name
    length, records range, and whether the header agrees with the index (sound)."""

    ci: np.ndarray
    map_len: np.ndarray
    chunk_at: np.ndarray
    t_first: np.ndarray
    t_last: np.ndarray
    c: np.ndarray
    usize: np.ndarray
    crc: np.ndarray
    name_len: np.ndarray
    rec_at: np.ndarray
    rec_end: np.ndarray
    sound: np.ndarray


def chunk_headers(data: Bytes, buf: np.ndarray, chunk_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The first HEADER bytes of every chunk copied into one array (flat, and each chunk's start
    in it), a few hundred chunks at a time with their mapped pages dropped after each batch: reading
    them in place faults in ~64 KiB of the file around every header (~30 % of a long file)."""
    out = np.zeros((chunk_at.shape[0], HEADER), np.uint8)
    span = np.arange(HEADER)
    for lo in range(0, chunk_at.shape[0], 256):
        at = chunk_at[lo : lo + 256]
        out[lo : lo + 256] = buf[np.minimum(at[:, None] + span, buf.shape[0] - 1)]
        release_pages(data, int(at.min()), int(at.max()) + HEADER)
    return out.ravel(), np.arange(chunk_at.shape[0], dtype=np.int64) * HEADER


def chunk_table(data: Bytes, footer: int, verified: bool | None, chunk_index_at: list[int],
                 chunk_index_len: list[int]) -> ChunkTable:  # fmt: skip
    """Every chunk index and chunk header read at once (numpy), checked against each other."""
    # chunk indexes (vectorised): start offset of each chunk, in summary order
    buf = np.frombuffer(data, np.uint8)
    ci = np.asarray(chunk_index_at, dtype=np.int64)
    map_len = read_le(buf, ci + 32, "<u4").astype(np.int64)
    comp_len = read_le(buf, ci + 44 + map_len, "<u4").astype(np.int64)
    if np.any(32 + 4 + map_len + 8 + 4 + comp_len + 16 != np.asarray(chunk_index_len)):
        raise NotFast("chunk index length")
    t_first = read_le(buf, ci, "<u8").astype(np.int64)
    t_last = read_le(buf, ci + 8, "<u8").astype(np.int64)
    chunk_at = read_le(buf, ci + 16, "<u8").astype(np.int64)
    chunk_len = read_le(buf, ci + 24, "<u8").astype(np.int64)
    idx_csize = read_le(buf, ci + 48 + map_len + comp_len, "<u8").astype(np.int64)
    idx_usize = read_le(buf, ci + 56 + map_len + comp_len, "<u8").astype(np.int64)
    if np.any(chunk_at > footer - 49) or np.any(chunk_at + chunk_len > footer):
        raise NotFast("chunk index does not point at a chunk")
    # chunk: start, end u64, uncompressed_size u64, crc u32, compression string, records (u64 length)
    c = chunk_at + 9
    hb, h = chunk_headers(data, buf, chunk_at)  # header bytes of chunk k at hb[h[k]:], copied
    usize = read_le(hb, h + 25, "<u8").astype(np.int64)
    crc = read_le(hb, h + 33, "<u4").astype(np.int64)
    if np.any(comp_len > 4):  # a compression other than zstd / lz4 / none: the generic reader decides
        raise NotFast("compression")
    name_len = np.minimum(read_le(hb, h + 37, "<u4").astype(np.int64), 4)  # > 4 only if damaged
    rec_len = read_le(hb, h + 41 + name_len, "<u8").astype(np.int64)
    rec_at = c + 40 + name_len
    rec_end = rec_at + np.clip(rec_len, 0, footer)
    # the header of every chunk must agree with its index (opcode, lengths, sizes, compression)
    sound = (hb[h] == OP_CHUNK) & (read_le(hb, h + 1, "<u8").astype(np.int64) == chunk_len - 9)
    sound &= (usize == idx_usize) & (rec_len == idx_csize) & (40 + name_len + rec_len == chunk_len - 9)
    sound &= (name_len == comp_len) & (rec_end <= footer)
    for k in np.flatnonzero(sound).tolist():
        if (
            data[ci[k] + 48 + map_len[k] : ci[k] + 48 + map_len[k] + comp_len[k]]
            != hb[h[k] + 41 : h[k] + 41 + name_len[k]].tobytes()
        ):
            sound[k] = False
    if not sound.all() and not verified:  # without a summary CRC the index itself may be the damage
        raise NotFast("chunk header disagrees with its index")
    return ChunkTable(ci, map_len, chunk_at, t_first, t_last, c, usize, crc, name_len, rec_at, rec_end, sound)


def chunks_with(
    data: Bytes, ci: np.ndarray, map_len: np.ndarray, channels, topics, stream
) -> np.ndarray | None:
    """Which chunks hold a message of a wanted topic, from each chunk index's message index offsets
    (map channel id u16 -> offset u64); None when every chunk is wanted (all topics, or a chunk
    index without that map: the writer stored no message indexes)."""
    if topics is None or stream is not None or np.any(map_len <= 0) or np.any(map_len % 10):
        return None
    wanted = {cid for cid, ch in channels.items() if ch.topic in set(topics)}
    if len(wanted) == len(channels):
        return None
    ids = {struct.pack("<H", cid) for cid in wanted}
    keep = np.zeros(ci.shape[0], bool)
    for k, (at, n) in enumerate(zip((ci + 36).tolist(), map_len.tolist(), strict=True)):
        entries = data[at : at + n]
        keep[k] = any(entries[j : j + 2] in ids for j in range(0, n, 10))
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
