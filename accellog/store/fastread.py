"""Fast path of the MCAP reader: walk a finished file with struct/numpy, decode every batch channel at once.

The file is mapped, footer and summary parsed with struct, chunks decompressed ~4 MiB at a time into two
reused buffers (the next group on a worker thread while this one is decoded), records walked by checked
guesses (runs of equal-length messages), and every channel's payloads decoded at once by
``batch_decode.decode_batch`` straight into arrays sized once. Anything unexpected raises ``_NotFast``
and the generic reader decides.

Integrity (see accellog.store.collect): the summary CRC is checked first (a damaged summary is not
trusted: the file is scanned instead); with a sound summary each chunk header must agree with its
chunk index, decompress to the indexed size and match its uncompressed CRC, else the chunk is
skipped and named (Damage); the data section CRC, computed on a worker thread, catches damage
anywhere else.
"""

from __future__ import annotations

import itertools
import mmap
import struct
import zlib
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.records import Channel, Schema

from accellog.core.errors import InputError
from accellog.store.batch_decode import BatchAccumulator, decode_batch, read_le
from accellog.store.collect import Collected, Damage, _Sink, data_section_damage, recover, release_pages
from accellog.store.layout import MCAP_MAGIC

# ---------------------------------------------------------------------------------------------
# fast path: walk the MCAP file with struct/numpy, decode every batch channel at once


class _NotFast(Exception):
    """The fast reader met something outside the canonical layout: the generic reader decides."""


class _Refuse(Exception):
    """Damage the reader cannot work around (e.g. the session metadata record): an InputError."""


class _SummaryDamaged(Exception):
    """The summary section fails its CRC: its offsets cannot be trusted; scan the file instead."""


_REC = struct.Struct("<BQ")  # record prefix: opcode u8, content length u64
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x02, 0x03, 0x04, 0x05, 0x06
_OP_CHUNK_INDEX, _OP_METADATA, _OP_METADATA_INDEX = 0x08, 0x0C, 0x0D
_SUMMARY_OPS = {
    0x03,
    0x04,
    0x08,
    0x0A,
    0x0B,
    0x0D,
    0x0E,
}  # schema, channel, chunk/attachment/metadata index, ...
_FOOTER_SIZE = 9 + 20
_MESSAGE_HEADER = 2 + 4 + 8 + 8  # channel_id u16, sequence u32, log_time u64, publish_time u64
_Bytes = bytes | mmap.mmap  # the file: mapped read-only (no copy) by fast_collect
_GROUP_BYTES = 4 << 20  # decompressed bytes decoded at a time (fits in L2/L3 cache)
_PAD = 16  # zero bytes after the decompressed records (vectorised reads may look a few bytes ahead)


def fast_collect(path: Path, topics: Iterable[str] | None = None) -> Collected | None:
    """``_collect`` of a finished file without per-message Python; None if the generic path must decide.

    Reads the footer and summary section (schemas, channels, chunk and metadata indexes) with struct,
    decompresses every chunk in summary order (zstd, lz4 or none) into one buffer, walks its records,
    and decodes each accellog channel with ``messages.decode_batch``: the same chunks, messages, order
    and bytes as mcap's SeekingReader with ``iter_messages(log_time_order=False)``. Unfinished files
    (no footer magic or no summary) and anything unexpected return None.
    """
    try:
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return _fast_parse(data, topics)
    except _SummaryDamaged as exc:
        return recover(path, topics, exc)
    except _Refuse as exc:
        raise InputError(str(exc), where=str(path)) from None
    except Exception:  # an optimisation only: on any surprise the generic reader decides
        return None


def summary_sound(data: _Bytes, footer: int, summary_start: int) -> bool | None:
    """Footer summary CRC check: True/False, None when the writer stored none (0)."""
    want = _U32.unpack_from(data, footer + 25)[0]
    if want == 0:
        return None
    return zlib.crc32(data[footer : footer + 25], zlib.crc32(memoryview(data)[summary_start:footer])) == want


def _str_at(data: _Bytes, pos: int) -> tuple[str, int]:
    n = _U32.unpack_from(data, pos)[0]
    end = pos + 4 + n
    if end > len(data):
        raise _NotFast("string past the end")
    return str(data[pos + 4 : end], "utf-8"), end


def _map_end(data: _Bytes, pos: int) -> int:
    return pos + 4 + _U32.unpack_from(data, pos)[0]


def _schema_at(data: _Bytes, c: int) -> tuple[Schema, int]:
    sid = _U16.unpack_from(data, c)[0]
    name, q = _str_at(data, c + 2)
    encoding, q = _str_at(data, q)
    end = _map_end(data, q)
    return Schema(id=sid, name=name, encoding=encoding, data=data[q + 4 : end]), end


def _channel_at(data: _Bytes, c: int) -> tuple[Channel, int]:
    cid, sid = struct.unpack_from("<HH", data, c)
    topic, q = _str_at(data, c + 4)
    encoding, q = _str_at(data, q)
    return Channel(id=cid, topic=topic, message_encoding=encoding, schema_id=sid, metadata={}), _map_end(
        data, q
    )


def _fast_parse(data: _Bytes, topics: Iterable[str] | None) -> Collected:
    """The whole file at once: _fast_walk drained."""
    walk = _fast_walk(data, topics)
    while True:
        try:
            next(walk)
        except StopIteration as end:
            return end.value


def _footer(data: _Bytes) -> tuple[int, int, bool | None]:
    """(footer offset, summary start, summary CRC verdict) of a finished file."""
    size = len(data)
    if size < 2 * len(MCAP_MAGIC) + _FOOTER_SIZE or data[-len(MCAP_MAGIC) :] != MCAP_MAGIC:
        raise _NotFast("no footer magic: unfinished file")
    footer = size - len(MCAP_MAGIC) - _FOOTER_SIZE
    if _REC.unpack_from(data, footer) != (_OP_FOOTER, 20):
        raise _NotFast("no footer")
    summary_start = _U64.unpack_from(data, footer + 9)[0]
    if summary_start == 0 or summary_start >= footer:
        raise _NotFast("no summary section")
    verified = summary_sound(data, footer, summary_start)
    if verified is False:
        raise _SummaryDamaged("summary section CRC mismatch")
    return footer, summary_start, verified


def _summary(data: _Bytes, footer: int, summary_start: int):
    """Schemas, channels, chunk index offsets and lengths, metadata offsets of the summary section
    (every record parsed must fill its declared length exactly)."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    chunk_index_at: list[int] = []
    chunk_index_len: list[int] = []
    metadata_at: list[int] = []
    pos = summary_start
    while pos < footer:
        op, ln = _REC.unpack_from(data, pos)
        c, e = pos + 9, pos + 9 + ln
        if op not in _SUMMARY_OPS or e > footer:
            raise _NotFast(f"summary record {op:#x}")
        if op == _OP_SCHEMA:
            sch, q = _schema_at(data, c)
            schemas[sch.id] = sch
        elif op == _OP_CHANNEL:
            ch, q = _channel_at(data, c)
            channels[ch.id] = ch
        elif op == _OP_CHUNK_INDEX:
            chunk_index_at.append(c)
            chunk_index_len.append(ln)
            q = e
        elif op == _OP_METADATA_INDEX:
            metadata_at.append(_U64.unpack_from(data, c)[0])
            q = _str_at(data, c + 16)[1]
        else:
            q = e
        if q != e:
            raise _NotFast(f"summary record {op:#x} length")
        pos = e
    if pos != footer or not chunk_index_at:
        raise _NotFast("summary without chunk indexes")
    if len({ch.topic for ch in channels.values()}) != len(channels):
        raise _NotFast("topic on several channels")
    return schemas, channels, chunk_index_at, chunk_index_len, metadata_at


@dataclass
class _ChunkTable:
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


_HEADER = 56  # bytes of a chunk header the index pass reads: opcode .. records length (name <= 4)


def _chunk_headers(data: _Bytes, buf: np.ndarray, chunk_at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The first _HEADER bytes of every chunk copied into one array (flat, and each chunk's start
    in it), a few hundred chunks at a time with their mapped pages dropped after each batch: reading
    them in place faults in ~64 KiB of the file around every header (~30 % of a long file)."""
    out = np.zeros((chunk_at.shape[0], _HEADER), np.uint8)
    span = np.arange(_HEADER)
    for lo in range(0, chunk_at.shape[0], 256):
        at = chunk_at[lo : lo + 256]
        out[lo : lo + 256] = buf[np.minimum(at[:, None] + span, buf.shape[0] - 1)]
        release_pages(data, int(at.min()), int(at.max()) + _HEADER)
    return out.ravel(), np.arange(chunk_at.shape[0], dtype=np.int64) * _HEADER


def _chunk_table(data: _Bytes, footer: int, verified: bool | None, chunk_index_at: list[int],
                 chunk_index_len: list[int]) -> _ChunkTable:  # fmt: skip
    """Every chunk index and chunk header read at once (numpy), checked against each other."""
    # chunk indexes (vectorised): start offset of each chunk, in summary order
    buf = np.frombuffer(data, np.uint8)
    ci = np.asarray(chunk_index_at, dtype=np.int64)
    map_len = read_le(buf, ci + 32, "<u4").astype(np.int64)
    comp_len = read_le(buf, ci + 44 + map_len, "<u4").astype(np.int64)
    if np.any(32 + 4 + map_len + 8 + 4 + comp_len + 16 != np.asarray(chunk_index_len)):
        raise _NotFast("chunk index length")
    t_first = read_le(buf, ci, "<u8").astype(np.int64)
    t_last = read_le(buf, ci + 8, "<u8").astype(np.int64)
    chunk_at = read_le(buf, ci + 16, "<u8").astype(np.int64)
    chunk_len = read_le(buf, ci + 24, "<u8").astype(np.int64)
    idx_csize = read_le(buf, ci + 48 + map_len + comp_len, "<u8").astype(np.int64)
    idx_usize = read_le(buf, ci + 56 + map_len + comp_len, "<u8").astype(np.int64)
    if np.any(chunk_at > footer - 49) or np.any(chunk_at + chunk_len > footer):
        raise _NotFast("chunk index does not point at a chunk")
    # chunk: start, end u64, uncompressed_size u64, crc u32, compression string, records (u64 length)
    c = chunk_at + 9
    hb, h = _chunk_headers(data, buf, chunk_at)  # header bytes of chunk k at hb[h[k]:], copied
    usize = read_le(hb, h + 25, "<u8").astype(np.int64)
    crc = read_le(hb, h + 33, "<u4").astype(np.int64)
    if np.any(comp_len > 4):  # a compression other than zstd / lz4 / none: the generic reader decides
        raise _NotFast("compression")
    name_len = np.minimum(read_le(hb, h + 37, "<u4").astype(np.int64), 4)  # > 4 only if damaged
    rec_len = read_le(hb, h + 41 + name_len, "<u8").astype(np.int64)
    rec_at = c + 40 + name_len
    rec_end = rec_at + np.clip(rec_len, 0, footer)
    # the header of every chunk must agree with its index (opcode, lengths, sizes, compression)
    sound = (hb[h] == _OP_CHUNK) & (read_le(hb, h + 1, "<u8").astype(np.int64) == chunk_len - 9)
    sound &= (usize == idx_usize) & (rec_len == idx_csize) & (40 + name_len + rec_len == chunk_len - 9)
    sound &= (name_len == comp_len) & (rec_end <= footer)
    for k in np.flatnonzero(sound).tolist():
        if (
            data[ci[k] + 48 + map_len[k] : ci[k] + 48 + map_len[k] + comp_len[k]]
            != hb[h[k] + 41 : h[k] + 41 + name_len[k]].tobytes()
        ):
            sound[k] = False
    if not sound.all() and not verified:  # without a summary CRC the index itself may be the damage
        raise _NotFast("chunk header disagrees with its index")
    return _ChunkTable(
        ci, map_len, chunk_at, t_first, t_last, c, usize, crc, name_len, rec_at, rec_end, sound
    )


def _fast_walk(data: _Bytes, topics: Iterable[str] | None, stream: str | None = None):
    """Generator over the chunk groups of a finished file; returns the Collected at the end.

    stream: a topic whose messages are handed out group by group instead of accumulated: after
    each group it yields (metadata, DecodedBatch of that topic's messages in the group, or None),
    so memory stays bounded by one group. Without stream it yields nothing until the end."""
    footer, summary_start, verified = _footer(data)
    schemas, channels, chunk_index_at, chunk_index_len, metadata_at = _summary(data, footer, summary_start)
    tab = _chunk_table(data, footer, verified, chunk_index_at, chunk_index_len)
    sound, usize, crc = tab.sound, tab.usize, tab.crc
    damaged = [
        Damage(
            int(tab.chunk_at[k]),
            int(tab.t_first[k]),
            int(tab.t_last[k]),
            "chunk header disagrees with its index",
        )
        for k in np.flatnonzero(~sound).tolist()
    ]
    usize = np.where(sound, usize, 0)
    crc = np.where(sound, crc, 0)
    release_pages(data, 0, summary_start)  # whatever the index pass touched: read again on demand
    keep = _chunks_with(data, tab.ci, tab.map_len, channels, topics, stream)
    if keep is not None:  # only chunks that hold a wanted channel are decompressed
        sound &= keep
        usize = np.where(keep, usize, 0)
    # the session metadata (LSB scales) first: a stream needs it before the first group
    meta_kv: dict[str, str] = {}
    meta_error: tuple[int, str] | None = None
    for at in metadata_at:
        try:
            name, kv = _metadata_at(data, at)
        except Exception as exc:
            meta_error = (at, str(exc))
            if stream is not None:
                raise _NotFast(str(exc)) from None
            continue
        if name == "session":
            meta_kv = kv
    # chunks in groups of about _GROUP_BYTES decompressed: each group is decoded while in the CPU cache
    sink = _Sink(topics)
    message_of: dict[int, str | None] = {}  # channel id -> accellog message type (None: not decoded)
    parts: dict[int, BatchAccumulator] = {}
    name_at, name_len, rec_at, rec_end = (
        (tab.c + 32).tolist(),
        np.where(sound, tab.name_len, -1).tolist(),  # -1: skip (damaged header)
        tab.rec_at.tolist(),
        tab.rec_end.tolist(),
    )
    chunk_info = (tab.chunk_at.tolist(), tab.t_first.tolist(), tab.t_last.tolist(), crc.tolist())
    chunks = _Decompressor(data, chunk_info, damaged)
    usize_list = usize.tolist()
    done = (np.cumsum(usize) / max(1, int(usize.sum()))).tolist()  # fraction read after each chunk
    groups = _groups(usize)

    def decompress(i: int) -> tuple[bytearray, int, list[int]]:
        g0, g1 = groups[i]
        out = chunks.records(
            g0, name_at[g0:g1], name_len[g0:g1], rec_at[g0:g1], rec_end[g0:g1], usize_list[g0:g1], i % 2
        )
        release_pages(data, min(rec_at[g0:g1]), max(rec_end[g0:g1]))  # read once: drop them
        return out

    # group i + 1 is decompressed in a thread (lz4/zstd release the GIL) while group i is decoded;
    # leaving the with-block (also on an exception) waits for it, before the file is unmapped
    with ThreadPoolExecutor(1) as pool, ThreadPoolExecutor(1) as crc_pool:
        pending = pool.submit(decompress, 0)
        # the data section CRC (zlib releases the GIL); a read of some chunks only (labels) skips it
        # unless the metadata needs its verdict
        data_crc = None if keep is not None else crc_pool.submit(data_section_damage, data, summary_start)
        for i in range(len(groups)):
            records, used, sizes = pending.result()
            if i + 1 < len(groups):
                pending = pool.submit(decompress, i + 1)
            frac = 1.0 if stream else done[groups[i][1] - 1]
            _decode_group(records, used, sizes, frac, channels, schemas, sink, message_of, parts)
            if stream is not None:
                part = next(
                    (parts.pop(c) for c, ch in channels.items() if ch.topic == stream and c in parts), None
                )
                yield meta_kv, None if part is None else part.finish()
        outside = None if data_crc is None else data_crc.result()
    if data_crc is None and meta_error is not None:
        outside = data_section_damage(data, summary_start)
    if outside is not None and not damaged:
        damaged.append(outside)
    for cid, msg in message_of.items():
        if msg is not None and cid in parts:
            sink.decoders[channels[cid].topic] = parts[cid].finish()
    for ch in channels.values():
        sink.channel(schemas.get(ch.schema_id), ch)

    if meta_error is not None:
        if outside is not None:  # the bytes outside the chunks are damaged, and here is where
            raise _Refuse(
                f"the session metadata record at byte {meta_error[0]} is damaged (data section CRC mismatch)"
            )
        raise _NotFast(meta_error[1])
    sink.metadata = meta_kv
    return Collected(sink.metadata, sink.topics, sink.decoders, None, sorted(damaged, key=lambda d: d.offset))


def _chunks_with(
    data: _Bytes, ci: np.ndarray, map_len: np.ndarray, channels, topics, stream
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


def _metadata_at(data: _Bytes, at: int) -> tuple[str, dict[str, str]]:
    """Name and key-values of the Metadata record at byte at (its length must add up)."""
    op, ln = _REC.unpack_from(data, at)
    if op != _OP_METADATA:
        raise _NotFast("metadata index does not point at metadata")
    name, q = _str_at(data, at + 9)
    end = _map_end(data, q)
    kv: dict[str, str] = {}
    q += 4
    while q < end:
        k, q = _str_at(data, q)
        kv[k], q = _str_at(data, q)
    if q != end or end != at + 9 + ln:
        raise _NotFast("metadata record length")
    return name, kv


def _decode_group(
    records: bytearray,
    used: int,
    usize: list[int],
    done: float,
    channels: dict[int, Channel],
    schemas: dict[int, Schema],
    sink: _Sink,
    message_of: dict[int, str | None],
    parts: dict[int, BatchAccumulator],
) -> None:
    """Decode the messages of one group of decompressed chunks into the channels' accumulators."""
    messages = _message_starts(records, usize)
    if not messages.shape[0]:
        return
    rb = np.frombuffer(records, np.uint8, used + _PAD)
    msg_len = read_le(rb, messages + 1, "<u8")
    if np.any(msg_len < _MESSAGE_HEADER):
        raise _NotFast("short message record")
    channel_id = read_le(rb, messages + 9, "<u2")
    payload_at = messages + 9 + _MESSAGE_HEADER
    payload_end = messages + 9 + msg_len.astype(np.int64)
    ids, first = np.unique(channel_id, return_index=True)
    for cid in ids[np.argsort(first)].tolist():
        if cid not in message_of:  # first message of the channel, as the generic sink sees it
            ch = channels[cid]
            wanted = sink.want is None or ch.topic in sink.want
            schema = None if ch.schema_id == 0 else schemas[ch.schema_id]
            message_of[cid] = sink.channel(schema, ch) if wanted else None
        msg = message_of[cid]
        if msg is None:
            continue
        if cid not in parts:  # first message, or a streamed topic handed out after the last group
            parts[cid] = BatchAccumulator(msg)
        sel = slice(None) if ids.shape[0] == 1 else np.flatnonzero(channel_id == cid)
        acc, frac = parts[cid], done
        dec = decode_batch(
            msg,
            rb,
            payload_at[sel],
            payload_end[sel],
            lambda nm, dt, k, a=acc, f=frac: a.reserve(nm, dt, k, f),
        )
        if dec is None:
            raise _NotFast(f"{channels[cid].topic}: not canonical protobuf")
        acc.add(dec, frac)


def _groups(usize: np.ndarray) -> list[tuple[int, int]]:
    """Consecutive runs of chunks holding about _GROUP_BYTES of records each (at least one chunk)."""
    bounds = [0]
    total = 0
    for i, u in enumerate(usize.tolist()):
        if total and total + u > _GROUP_BYTES:
            bounds.append(i)
            total = 0
        total += u
    bounds.append(usize.shape[0])
    return list(itertools.pairwise(bounds))


class _Decompressor:
    """Decompresses runs of chunks into one reused buffer (fresh memory per group would cost page faults);
    a chunk that does not decompress, has the wrong size or fails its CRC is left out and noted."""

    def __init__(
        self, data: _Bytes, chunk_info: tuple[list, list, list, list], damaged: list[Damage]
    ) -> None:
        import lz4.frame
        import zstandard

        self.data = data
        self.zstd = zstandard.ZstdDecompressor().decompress
        self.lz4 = lz4.frame.decompress
        self.bufs = [bytearray(), bytearray()]
        self.at, self.t0, self.t1, self.crc = chunk_info
        self.damaged = damaged  # appended to (list.append is atomic)

    def _one(self, comp: bytes, raw, u: int):
        """Decompressed chunk records, or a reason why not."""
        try:
            if comp == b"zstd":
                out = self.zstd(raw, max_output_size=u)
            elif comp == b"lz4":
                out = self.lz4(raw)
            elif comp == b"":
                out = raw
            else:
                raise _NotFast(f"compression {comp!r}")
        except _NotFast:
            raise
        except Exception as exc:
            return f"does not decompress ({type(exc).__name__})"
        if len(out) != u:
            return f"decompresses to {len(out)} bytes, not {u}"
        return out

    def records(
        self,
        first: int,
        name_at: list[int],
        name_len: list[int],
        at: list[int],
        end: list[int],
        usize: list[int],
        slot: int = 0,
    ) -> tuple[bytearray, int, list[int]]:
        """(buffer, n, sizes): the sound chunks' records back to back in buffer[:n], then _PAD zero
        bytes; sizes[k] is what chunk first + k contributed (0: damaged, skipped).

        Two buffers (slot 0 or 1): one is filled while the other is decoded."""
        total = sum(usize)
        if len(self.bufs[slot]) < total + _PAD:
            self.bufs[slot] = bytearray(total + _PAD)
        buf, data, mv = self.bufs[slot], self.data, memoryview(self.data)  # released on return
        pos = 0
        sizes = []
        for k, (na, nl, a, b, u) in enumerate(zip(name_at, name_len, at, end, usize, strict=True)):
            if nl < 0:  # header already found damaged
                sizes.append(0)
                continue
            out = self._one(data[na : na + nl], mv[a:b], u)
            j = first + k
            if not isinstance(out, str) and self.crc[j] and zlib.crc32(out) != self.crc[j]:
                out = "CRC mismatch"
            if isinstance(out, str):
                self.damaged.append(Damage(self.at[j], self.t0[j], self.t1[j], out))
                sizes.append(0)
                continue
            buf[pos : pos + u] = out
            pos += u
            sizes.append(u)
        buf[pos : pos + _PAD] = bytes(_PAD)
        return buf, pos, sizes


def _message_starts(records: bytes | bytearray, usize: list[int]) -> np.ndarray:
    """Offsets of the Message records in the concatenated chunk records (each chunk must be whole).

    Walks the record chain; at a Message record of length L it guesses that the records that follow
    are Messages of the same length (the usual case: same fields, same varint sizes) and checks all
    those guesses at once with numpy (opcode, length, no record across a chunk end), keeping the run
    up to the first miss, so the Python walk only steps where the record layout changes.
    """
    unpack = _REC.unpack_from
    ends = list(itertools.accumulate(usize))
    total = ends[-1] if ends else 0
    ends_arr = np.asarray(ends, dtype=np.int64)
    rb = np.frombuffer(records, np.uint8)
    runs: list[np.ndarray] = []
    pos, k = 0, 0
    while pos < total:
        while pos >= ends[k]:  # next chunk (a record never crosses a chunk end)
            k += 1
        op, ln = unpack(records, pos)
        nxt = pos + 9 + ln
        if nxt > ends[k]:
            raise _NotFast("record across a chunk boundary")
        if op == _OP_MESSAGE:
            stride = 9 + ln
            guess = np.arange(pos, total - stride + 1, stride, dtype=np.int64)  # guess[0] == pos: checked
            ok = (rb[guess] == _OP_MESSAGE) & (read_le(rb, guess + 1, "<u8") == ln)
            ok &= np.searchsorted(ends_arr, guess, "right") == np.searchsorted(
                ends_arr, guess + (stride - 1), "right"
            )
            m = guess.shape[0] if ok.all() else int(np.argmin(ok))
            runs.append(guess[:m])
            pos = int(guess[m - 1]) + stride
            continue
        if op in (_OP_SCHEMA, _OP_CHANNEL):  # read by content in mcap: length must agree
            q = (_schema_at if op == _OP_SCHEMA else _channel_at)(records, pos + 9)[1]
            if q != nxt:
                raise _NotFast("schema/channel record length in a chunk")
        pos = nxt
    return np.concatenate(runs) if runs else np.zeros(0, np.int64)
