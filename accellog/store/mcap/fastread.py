"""Fast path of the MCAP reader: walk a finished file with struct/numpy, decode every batch channel at once.

The file is mapped, footer and summary parsed with struct, chunks decompressed 4-8 MiB at a time into
reused buffers (store.mcap.decompress; the next groups on worker threads while this one is decoded),
records walked by checked guesses (runs of equal-length messages) or, in groups of many small chunks,
all chunks side by side (store.mcap.record_starts), and every channel's payloads decoded at once by
``batch_decode.decode_batch`` straight into arrays sized once (a channel's accumulator may convert each
group as it comes: store.reader.ImuAccumulator). Anything unexpected raises ``NotFast`` and the generic reader
decides.

Integrity (see accellog.store.collect): the summary CRC is checked first (a damaged summary is not
trusted: the file is scanned instead); with a sound summary each chunk header must agree with its
chunk index (checked on the decompression thread as the chunk is read; without a summary CRC a
disagreement is NotFast), decompress to the indexed size and match its uncompressed CRC, else the
chunk is skipped and named (Damage); the data section CRC, computed on a worker thread, catches
damage anywhere else. A whole read of a file that stored that CRC trusts it for the chunks (it covers
every chunk byte) and, if it fails, reads the file again checking each chunk's CRC.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import mmap
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
from mcap.records import Channel, Schema

from accellog.core.errors import InputError
from accellog.core.threads import pool as thread_pool
from accellog.store.collect import (
    Collected,
    Damage,
    Sink,
    data_section_damage,
    recover,
    release_pages,
    stored_data_crc,
)
from accellog.store.mcap.batch_decode import BatchAccumulator, decode_batch
from accellog.store.mcap.byte_views import read_le
from accellog.store.mcap.decompress import PAD, SMALL_CHUNK, GroupDecompressor
from accellog.store.mcap.index import (
    MESSAGE_HEADER,
    Bytes,
    NotFast,
    Refuse,
    SummaryDamaged,
    chunk_index,
    chunks_with,
    read_footer,
    read_metadata,
    read_summary,
)
from accellog.store.mcap.record_starts import MANY_CHUNKS, chunkwise_starts, message_starts
from accellog.store.mcap.records import metadata_between_chunks

# ---------------------------------------------------------------------------------------------
# fast path: walk the MCAP file with struct/numpy, decode every batch channel at once


MakeAccumulator = Callable[[str, str, dict[str, str]], BatchAccumulator | None]
_GROUP_BYTES = 4 << 20  # decompressed bytes a stream decodes at a time (fits in the L3 cache)
_WHOLE_GROUPS = 2  # a whole read's groups are this many times larger: its Python work per group is
# spread over more samples (1 h recorder file with reads of 30-42 samples: 0.287 -> 0.261 s, best of 7)


def fast_collect(
    path: Path, topics: Iterable[str] | None = None, accumulator: MakeAccumulator | None = None
) -> Collected | None:
    """``_collect`` of a finished file without per-message Python; None if the generic path must decide.

    Reads the footer and summary section (schemas, channels, chunk and metadata indexes) with struct,
    decompresses every chunk in summary order (zstd, lz4 or none) into one buffer, walks its records,
    and decodes each accellog channel with ``batch_decode.decode_batch``: the same chunks, messages, order
    and bytes as mcap's SeekingReader with ``iter_messages(log_time_order=False)``. Unfinished files
    (no footer magic or no summary) and anything unexpected return None. ``accumulator(topic,
    message, session metadata)`` may give a channel's BatchAccumulator (e.g. one that converts units
    group by group); None: a plain one.
    """
    try:
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return _fast_parse(data, topics, accumulator)
    except SummaryDamaged as exc:
        return recover(path, topics, exc)
    except Refuse as exc:
        raise InputError(str(exc), where=str(path)) from None
    except Exception:  # an optimisation only: on any surprise the generic reader decides
        return None


class _ChunksUnverified(Exception):
    """The data section CRC failed after a walk that trusted it for the chunks: walk again, checking
    every chunk's CRC, to leave out and name the damaged ones."""


def _fast_parse(data: Bytes, topics: Iterable[str] | None, accumulator=None) -> Collected:
    """The whole file at once: fast_walk drained (again with every chunk's CRC if damage shows)."""
    try:
        return _drained(fast_walk(data, topics, accumulator=accumulator, check_chunks=False))
    except _ChunksUnverified:
        return _drained(fast_walk(data, topics, accumulator=accumulator))


def _drained(walk) -> Collected:
    while True:
        try:
            next(walk)
        except StopIteration as end:
            return end.value


def fast_walk(
    data: Bytes,
    topics: Iterable[str] | None,
    stream: str | None = None,
    accumulator: MakeAccumulator | None = None,
    check_chunks: bool = True,
):
    """Generator over the chunk groups of a finished file; returns the Collected at the end.

    stream: a topic whose messages are handed out group by group instead of accumulated: after
    each group it yields (metadata, DecodedBatch of that topic's messages in the group, or None),
    so memory stays bounded by one group. Without stream it yields nothing until the end.
    check_chunks=False: a whole read of a file with a data section CRC skips the chunks' own CRCs
    (that CRC covers every chunk byte and is checked on a worker thread: 1 h recorder file, 0.04 s
    less CPU) and raises _ChunksUnverified if it fails, so that the caller walks again with them."""
    footer, summary_start, verified = read_footer(data)
    schemas, channels, chunk_index_at, chunk_index_len, metadata_at = read_summary(
        data, footer, summary_start
    )
    (idx, usize), damaged = chunk_index(data, footer, chunk_index_at, chunk_index_len), list[Damage]()
    del chunk_index_at, chunk_index_len  # idx keeps 8 B a chunk: a day of recorder chunks, 1.4 MB
    keep = chunks_with(data, idx.ci, channels, topics, stream)
    release_pages(data, 0, len(data))  # what the index pass touched (the summary: ~14 MB at 24 h)
    if keep is not None:  # only chunks that hold a wanted channel are decompressed
        usize = np.where(keep, usize, 0)
    # the session metadata (LSB scales) first: a stream needs it before the first group
    meta_kv, meta_error = _session_metadata(data, metadata_at, stream, summary_start)
    # chunks in groups of a few MiB decompressed: each group is decoded while in the CPU cache
    sink = Sink(topics)
    message_of: dict[int, str | None] = {}  # channel id -> accellog message type (None: not decoded)
    parts: dict[int, BatchAccumulator] = {}

    def new_part(cid: int, msg: str) -> BatchAccumulator:
        made = None if accumulator is None else accumulator(channels[cid].topic, msg, meta_kv)
        return BatchAccumulator(msg) if made is None else made

    ahead = _ahead(data, idx, usize)
    # trust the data section CRC for the chunks only where its verdict comes before anything is
    # handed out: a whole read of every chunk, of a file that stored it
    trust = not check_chunks and stream is None and keep is None and stored_data_crc(data, summary_start) != 0
    chunks = GroupDecompressor(data, idx, keep, verified, damaged, ahead + 1, check_crcs=not trust)
    groups = _groups(usize, stream is None)
    read = np.concatenate([[0], np.cumsum(usize)])
    done = read[[e for _b, e in groups]] / max(1, int(read[-1]))  # fraction read after group i
    del usize, read  # per chunk only idx is kept; the rest is read again per group

    def decompress(i: int) -> tuple[bytearray, int, list[int]]:
        return chunks.records(*groups[i], i % (ahead + 1))

    # the next `ahead` groups are decompressed, each on its own thread (lz4/zstd release the GIL),
    # while group i is decoded; leaving the with-block (also on an exception) waits for them, before
    # the file is unmapped. A file of one group has nothing to overlap: no threads (core.threads)
    threaded = len(groups) > 1
    with thread_pool(ahead, threaded) as pool, thread_pool(1, threaded) as crc_pool, _closed_on_error(parts):
        pending = [pool.submit(decompress, i) for i in range(min(ahead, len(groups)))]
        # the data section CRC (crc32 releases the GIL); a read of some chunks only (labels) skips it
        # unless the metadata needs its verdict
        data_crc = None if keep is not None else crc_pool.submit(data_section_damage, data, summary_start)
        try:
            for i in range(len(groups)):
                records, used, sizes = pending.pop(0).result()
                if i + ahead < len(groups):  # into the slot of group i - 1, decoded by now
                    pending.append(pool.submit(decompress, i + ahead))
                frac = 1.0 if stream else float(done[i])
                _decode_group(
                    records, used, sizes, frac, channels, schemas, sink, message_of, parts, new_part
                )
                if stream is not None:
                    yield meta_kv, _handed_out(parts, channels, stream)
        except NotFast:  # unchecked chunks may be the cause: with damage, walk again checking them
            if trust and data_crc is not None and data_crc.result() is not None:
                raise _ChunksUnverified() from None
            raise
        outside = None if data_crc is None else data_crc.result()
        if trust and outside is not None:
            raise _ChunksUnverified()
    if data_crc is None and meta_error is not None:
        outside = data_section_damage(data, summary_start)
    if outside is not None and not damaged:
        damaged.append(outside)
    return _finish(sink, schemas, channels, message_of, parts, meta_kv, meta_error, outside, damaged)


def _handed_out(parts: dict[int, BatchAccumulator], channels, stream: str):
    """The streamed topic's DecodedBatch of the group just decoded (None: none in it), taken out of
    parts so that the next group starts a new one."""
    part = next((parts.pop(c) for c, ch in channels.items() if ch.topic == stream and c in parts), None)
    return None if part is None else part.finish()


@contextlib.contextmanager
def _closed_on_error(parts: dict[int, BatchAccumulator]):
    """If the walk fails (or a stream is closed early), the accumulators' worker threads are stopped
    at once (finish() stops them otherwise), not left to the garbage collector."""
    try:
        yield
    except BaseException:
        for part in parts.values():
            part.close()
        raise


def _session_metadata(data: Bytes, at_list: list[int], stream: str | None, summary_start: int):
    """(key-values of the 'session' metadata record, (byte, error) of a damaged one or None); a
    stream cannot wait for the data section CRC's verdict, so damage there is NotFast at once.
    at_list: the metadata index's offsets; without a metadata index (another writer's choice) the
    records between the chunks are walked (records.metadata_between_chunks)."""
    meta_kv: dict[str, str] = {}
    meta_error: tuple[int, str] | None = None
    for at in at_list or metadata_between_chunks(data, summary_start):
        try:
            name, kv = read_metadata(data, at)
        except Exception as exc:
            meta_error = (at, str(exc))
            if stream is not None:
                raise NotFast(str(exc)) from None
            continue
        if name == "session":
            meta_kv = kv
    return meta_kv, meta_error


def _finish(
    sink: Sink, schemas, channels, message_of, parts, meta_kv, meta_error, outside, damaged
) -> Collected:
    """The Collected of a walk: decoded channels handed to the sink, damage sorted by offset; a damaged
    session metadata record is Refuse when the data section CRC confirms it, else NotFast."""
    for cid, msg in message_of.items():
        if msg is not None and cid in parts:
            sink.decoders[channels[cid].topic] = parts[cid].finish()
    for ch in channels.values():
        sink.channel(schemas.get(ch.schema_id), ch)
    if meta_error is not None:
        if outside is not None:  # the bytes outside the chunks are damaged, and here is where
            raise Refuse(
                f"the session metadata record at byte {meta_error[0]} is damaged (data section CRC mismatch)"
            )
        raise NotFast(meta_error[1])
    sink.metadata = meta_kv
    return Collected(sink.metadata, sink.topics, sink.decoders, None, sorted(damaged, key=lambda d: d.offset))


def _decode_group(
    records: bytearray,
    used: int,
    usize: list[int],
    done: float,
    channels: dict[int, Channel],
    schemas: dict[int, Schema],
    sink: Sink,
    message_of: dict[int, str | None],
    parts: dict[int, BatchAccumulator],
    new_part: Callable[[int, str], BatchAccumulator],
) -> None:
    """Decode the messages of one group of decompressed chunks into the channels' accumulators
    (new_part(channel id, message type) makes one)."""
    messages = chunkwise_starts(records, usize) if len(usize) >= MANY_CHUNKS else None
    if messages is None:
        messages = message_starts(records, usize)
    if not messages.shape[0]:
        return
    rb = np.frombuffer(records, np.uint8, used + PAD)
    msg_len = read_le(rb, messages + 1, "<u8")
    if np.any(msg_len < MESSAGE_HEADER):
        raise NotFast("short message record")
    channel_id = read_le(rb, messages + 9, "<u2")
    payload_at = messages + 9 + MESSAGE_HEADER
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
            parts[cid] = new_part(cid, msg)
        sel = slice(None) if ids.shape[0] == 1 else np.flatnonzero(channel_id == cid)
        acc, frac = parts[cid], done
        dec = decode_batch(
            msg,
            rb,
            payload_at[sel],
            payload_end[sel],
            functools.partial(acc.reserve, done=frac),
            acc.scalar_arrays,
        )
        if dec is None:
            raise NotFast(f"{channels[cid].topic}: not canonical protobuf")
        acc.add(dec, frac)


def _ahead(data: Bytes, idx, usize: np.ndarray) -> int:
    """Groups decompressed ahead of the decoder, each on its own thread: 2 for zstd chunks under
    SMALL_CHUNK (recorder: ~18 kB / 0.5 s; a 1 h file, best of 7: 0.28 s with 1, 0.23 s with 2);
    else 1 (lz4, large chunks: a second thread takes the decoder's core)."""
    sound = np.flatnonzero(usize)
    if not sound.shape[0] or np.median(usize[sound]) >= SMALL_CHUNK:
        return 1
    tab = idx.rows(data, sound[:1])
    at = int(tab.name_at[0])
    return 2 if bytes(data[at : at + int(tab.name_len[0])]) == b"zstd" else 1


def _groups(usize: np.ndarray, whole: bool = True) -> list[tuple[int, int]]:
    """Runs of chunks of about _GROUP_BYTES of records (a whole read: _WHOLE_GROUPS times that): a run
    ends before the chunk that would take it past the cap, once it holds bytes; a whole read's first
    and last runs are ~1/8 of it, so the pipeline (decompress | decode | convert) fills and drains
    sooner (a stream keeps even blocks). A whole read of at most that 1/8 (1 MiB of records) is one
    group, read without threads: a 250 kB fleet session 5.8 ms instead of 8.6 with them."""
    n = usize.shape[0]
    if n == 0:
        return [(0, 0)]
    cs = np.zeros(n + 1, np.int64)
    np.cumsum(usize, out=cs[1:])
    big = _GROUP_BYTES * (_WHOLE_GROUPS if whole else 1)
    small = big // 8 if whole else big
    if whole and cs[n] <= small:  # a short file: one group, read without threads (fast_walk)
        return [(0, n)]
    bounds, cap = [0], small
    while bounds[-1] < n:
        b = bounds[-1]
        fits = int(np.searchsorted(cs, cs[b] + cap, "right")) - 1  # chunks [b, fits) within the cap
        first_bytes = int(np.searchsorted(cs, cs[b], "right"))  # [b, first_bytes) holds some bytes
        bounds.append(min(n, max(fits, first_bytes)))
        cap = big
    if whole:  # split the tail off the last group
        last = max(bounds[-2] + 1, int(np.searchsorted(cs, cs[n] - small, "left")))
        if last < n:
            bounds.insert(-1, last)
    return list(itertools.pairwise(bounds))
