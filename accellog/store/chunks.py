"""Read the IMU samples of an accellog MCAP file chunk by chunk (bounded memory, for hour-long sessions).

``iter_imu_chunks`` walks the /imu messages with mcap's reader in file order and yields ``ImuChunk`` s of
about ``chunk_bytes`` encoded bytes each, in the units ``read_session`` gives (g, deg/s, degC), with their
raw counts. Only the current messages are held in memory. A file without a summary (unfinished) is
salvaged by ``read_session`` (whole) and then cut into chunks, so every readable file streams.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader

from accellog.core.errors import InputError
from accellog.core.session import SessionMeta
from accellog.core.units import TEMP_LSB_PER_DEGC, TEMP_OFFSET_DEGC
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
    where = str(path)
    check_file(path)
    meta = read_meta(path)
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
