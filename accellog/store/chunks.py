"""Read the IMU samples of an accellog MCAP file chunk by chunk (bounded memory, for hour-long sessions).

``iter_imu_chunks`` yields ``ImuChunk`` s of about ``chunk_bytes`` encoded /imu bytes each, in file order
and in the units ``read_session`` gives (g, deg/s, degC), with their raw counts. Only the current messages
are held in memory. Three paths, fastest first:

1. a finished file: its chunk index (mcap's summary) gives every MCAP chunk; each is read, decompressed
   (zstd, lz4 or none), its records walked with struct and the /imu payloads decoded all at once by
   ``batch_decode.decode_batch`` (``BatchDecoder`` when a payload is not canonical);
2. anything unusual on the way (before a sample was yielded): mcap's ``iter_messages``, one message at a time;
3. a file without a summary (unfinished): salvaged whole by ``read_session``, then cut into chunks.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader

from accellog.core.errors import InputError
from accellog.core.session import SessionMeta
from accellog.core.units import TEMP_LSB_PER_DEGC, TEMP_OFFSET_DEGC
from accellog.store.batch_decode import decode_batch
from accellog.store.codec import BatchDecoder
from accellog.store.collect import check_file
from accellog.store.layout import NS_PER_S, TOPIC_IMU, metadata_to_meta

CHUNK_BYTES = 8 << 20
"""Encoded /imu bytes per chunk (about 200k samples of counts and times)."""


@dataclass
class ImuChunk:
    """Consecutive IMU samples: t_s (n,), sample_index (n,), accel_g (n,3), gyro_dps (n,3) or None, temp."""

    t_s: np.ndarray
    sample_index: np.ndarray
    accel_g: np.ndarray
    accel_counts: np.ndarray | None
    gyro_dps: np.ndarray | None
    gyro_counts: np.ndarray | None
    temp_degC: np.ndarray | None


def read_meta(path: str | Path) -> SessionMeta:
    """The session metadata of a finished or unfinished accellog MCAP file (no samples are decoded)."""
    from accellog.store.reader import session_summary

    d = session_summary(path)
    return metadata_to_meta(d["metadata"], str(path)) if d.get("metadata") else SessionMeta(source="unknown")


def _chunk_from_decoder(dec: BatchDecoder, meta: SessionMeta, where: str) -> ImuChunk:
    arrays, scalars, counts = dec.result()
    n = int(counts["t_ns"].sum())
    first = np.asarray(scalars["first_sample_index"], np.int64)
    index = np.repeat(first - (np.cumsum(counts["t_ns"]) - counts["t_ns"]), counts["t_ns"]) + np.arange(n)

    def three(name: str) -> np.ndarray | None:
        a = arrays[name]
        if a.size == 0:
            return None
        if a.size != 3 * n:
            raise InputError(f"{name} has {a.size} values for {n} samples (mixed batches)", where=where)
        return a.reshape(n, 3)

    ac, gc = three("accel_counts"), three("gyro_counts")
    accel = three("accel_g")
    if accel is None:
        if ac is None or not meta.accel_lsb_per_g:
            raise InputError("IMU batches carry no accelerometer values this reader can scale", where=where)
        accel = ac / meta.accel_lsb_per_g
    gyro = three("gyro_dps")
    if gyro is None and gc is not None and meta.gyro_lsb_per_dps:
        gyro = gc / meta.gyro_lsb_per_dps
    temp = arrays["temp_degC"] if arrays["temp_degC"].size == n else None
    if temp is None and arrays["temp_counts"].size == n:
        temp = arrays["temp_counts"] / TEMP_LSB_PER_DEGC + TEMP_OFFSET_DEGC
    return ImuChunk(arrays["t_ns"] / NS_PER_S, index, accel, ac, gyro, gc, temp)


def iter_imu_chunks(path: str | Path, chunk_bytes: int = CHUNK_BYTES) -> Iterator[ImuChunk]:
    """Yield the session's IMU samples in file order, about chunk_bytes of messages at a time."""
    path = Path(path)
    check_file(path)
    meta = read_meta(path)
    fast = _fast_chunks(path, meta, chunk_bytes)
    try:
        first = next(fast)
    except StopIteration:
        first = None
    except _NotFast:
        first = None
    if first is not None:
        yield first
        yield from fast  # a surprise after the first chunk is an error, never a silent restart
        return
    yield from _message_chunks(path, meta, chunk_bytes)


class _NotFast(Exception):
    """The chunk walker met something outside the canonical layout."""


_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")  # channel_id, sequence, log_time, publish_time
_OP_MESSAGE, _OP_CHUNK = 0x05, 0x06


def _records(raw: bytes) -> bytes:
    """The decompressed records of one Chunk record (opcode, length, content)."""
    op, _ = _REC.unpack_from(raw, 0)
    if op != _OP_CHUNK:
        raise _NotFast("chunk index does not point at a chunk")
    usize = struct.unpack_from("<Q", raw, 9 + 16)[0]
    (clen,) = struct.unpack_from("<I", raw, 9 + 28)
    comp = raw[9 + 32 : 9 + 32 + clen]
    (rlen,) = struct.unpack_from("<Q", raw, 9 + 32 + clen)
    body = memoryview(raw)[9 + 40 + clen : 9 + 40 + clen + rlen]
    if comp == b"zstd":
        import zstandard

        out = zstandard.ZstdDecompressor().decompress(body, max_output_size=usize)
    elif comp == b"lz4":
        import lz4.frame

        out = lz4.frame.decompress(body)
    elif comp == b"":
        out = bytes(body)
    else:
        raise _NotFast(f"compression {comp!r}")
    if len(out) != usize:
        raise _NotFast("chunk size")
    return out


def _imu_payloads(records: bytes, imu_ids: set[int]) -> tuple[list[int], list[int]]:
    """(starts, ends) of the /imu message payloads in a chunk's records."""
    starts, ends = [], []
    pos, total = 0, len(records)
    unpack, unpack_msg = _REC.unpack_from, _MSG.unpack_from
    while pos < total:
        op, ln = unpack(records, pos)
        nxt = pos + 9 + ln
        if nxt > total:
            raise _NotFast("record across the chunk end")
        if op == _OP_MESSAGE and unpack_msg(records, pos + 9)[0] in imu_ids:
            starts.append(pos + 9 + _MSG.size)
            ends.append(nxt)
        pos = nxt
    return starts, ends


def _fast_chunks(path: Path, meta: SessionMeta, chunk_bytes: int) -> Iterator[ImuChunk]:
    where = str(path)
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except (McapError, EOFError, ValueError, OSError) as exc:
            raise _NotFast(str(exc)) from None
        if summary is None or not summary.chunk_indexes:
            raise _NotFast("no chunk index")
        imu_ids = {cid for cid, ch in summary.channels.items() if ch.topic == TOPIC_IMU}
        if not imu_ids or any(summary.channels[c].message_encoding != "protobuf" for c in imu_ids):
            raise _NotFast("no protobuf /imu channel")
        group: list[tuple[bytes, list[int], list[int]]] = []  # MCAP chunks decoded together
        nbytes = 0
        for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
            if ci.message_index_offsets and not (imu_ids & set(ci.message_index_offsets)):
                continue  # a chunk without /imu messages
            f.seek(ci.chunk_start_offset)
            records = _records(f.read(ci.chunk_length))
            starts, ends = _imu_payloads(records, imu_ids)
            if not starts:
                continue
            group.append((records, starts, ends))
            nbytes += len(records)
            if nbytes >= chunk_bytes:
                yield _decode_group(group, meta, where)
                group, nbytes = [], 0
        if group:
            yield _decode_group(group, meta, where)


def _decode_group(group: list[tuple[bytes, list[int], list[int]]], meta: SessionMeta, where: str) -> ImuChunk:
    """One ImuChunk from the /imu payloads of consecutive MCAP chunks (one vectorised decode)."""
    buf = np.frombuffer(b"".join(g[0] for g in group), np.uint8)
    shift = np.cumsum([0] + [len(g[0]) for g in group[:-1]])
    starts = np.concatenate([np.asarray(g[1], np.int64) + o for g, o in zip(group, shift, strict=True)])
    ends = np.concatenate([np.asarray(g[2], np.int64) + o for g, o in zip(group, shift, strict=True)])
    dec = decode_batch("ImuBatch", buf, starts, ends)
    if dec is None:  # not canonical protobuf: the per-message decoder gives the same result
        dec = BatchDecoder("ImuBatch")
        for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
            dec.add(buf[a:b].tobytes())
    return _chunk_from_decoder(dec, meta, where)


def _message_chunks(path: Path, meta: SessionMeta, chunk_bytes: int) -> Iterator[ImuChunk]:
    """mcap's reader, message by message (any layout mcap reads); salvage when there is no summary."""
    where = str(path)
    yielded = 0
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            if reader.get_summary() is None:
                raise McapError("no summary section")
            dec, nbytes = BatchDecoder("ImuBatch"), 0
            for _, ch, msg in reader.iter_messages(topics=[TOPIC_IMU], log_time_order=False):
                if ch.message_encoding != "protobuf":
                    raise InputError(f"{TOPIC_IMU} is not protobuf ImuBatch", where=where)
                dec.add(msg.data)
                nbytes += len(msg.data)
                if nbytes >= chunk_bytes:
                    yield _chunk_from_decoder(dec, meta, where)
                    yielded += 1
                    dec, nbytes = BatchDecoder("ImuBatch"), 0
            if dec.n_messages:
                yield _chunk_from_decoder(dec, meta, where)
                yielded += 1
            if not yielded:
                raise InputError(f"not an accellog session: no {TOPIC_IMU} messages", where=where)
            return
    except (McapError, EOFError, ValueError, OSError) as exc:
        if yielded:
            raise InputError(
                f"unreadable after {yielded} chunks ({type(exc).__name__}: {exc})", where=where
            ) from None
    yield from _salvaged(path, 1 << 18)


def _salvaged(path: Path, chunk_samples: int) -> Iterator[ImuChunk]:
    """An unfinished file: salvage it whole with ``read_session`` and cut it into chunks."""
    from accellog.store.reader import read_session

    s = read_session(path)
    for i in range(0, s.n, chunk_samples):
        sl = slice(i, i + chunk_samples)
        yield ImuChunk(
            s.t_s[sl],
            s.sample_index[sl],
            s.accel_g[sl],
            None if s.accel_counts is None else s.accel_counts[sl],
            None if s.gyro_dps is None else s.gyro_dps[sl],
            None if s.gyro_counts is None else s.gyro_counts[sl],
            None if s.temp_degC is None else s.temp_degC[sl],
        )
