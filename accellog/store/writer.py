"""Crash-safe ``SessionWriter`` (and ``write_session`` for whole in-memory sessions): the current
chunk ends and the OS file is flushed at least every ``flush_interval_s`` of sensor time or wall time,
so a killed recorder loses at most that much data (plus the chunk being written); the readers
salvage every complete chunk of an unfinished file."""

from __future__ import annotations

import contextlib
import math
import time
from pathlib import Path

import numpy as np
from mcap.writer import CompressionType, Writer

from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel, Session, SessionMeta, Truth
from accellog.core.units import temp_counts_to_degC
from accellog.core.version import __version__
from accellog.store.atomic import AtomicOutput, OutputLock, check_output
from accellog.store.codec import encode
from accellog.store.layout import (
    DERIVED_PREFIX,
    NS_PER_S,
    TOPIC_EVENTS,
    TOPIC_IMU,
    TOPIC_MAG,
    TOPIC_MESSAGE,
    TOPIC_POSES,
    TOPIC_TRUTH,
    meta_to_metadata,
    to_ns,
    to_ns_array,
)
from accellog.store.schema import SCHEMA_VERSION, file_descriptor_set_bytes, full_name
from accellog.store.zstd_level import ZSTD_LEVEL, at_level

# Chunk compression written by default: zstd. At zstd's level 3 its files are 32-39 % smaller than
# lz4's (1 kHz hour: 54-60 MB instead of 79-99 MB; the ZSTD_LEVEL accellog writes adds 1.2-8 %), so a session read from storage (SD card,
# disk, network share) is read 25-42 % faster; from the page cache lz4 reads are faster (a streamed
# pass 7-22 %, read_session up to 59 %: at most 0.16 s an hour) and its writes take 10-30 % less CPU
# (benchmarks/bench_compression.py). "lz4" and "none" stay available; readers take any of them.
DEFAULT_COMPRESSION = "zstd"
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
COMPRESSIONS = tuple(_COMPRESSION)


def check_compression(name: str) -> str:
    """``name`` if it is a chunk compression the writer knows, else InputError (one line)."""
    if name not in _COMPRESSION:
        raise InputError(f"compression {name!r}: use " + ", ".join(repr(c) for c in COMPRESSIONS))
    return name


# ---------------------------------------------------------------------------------------------
# writer


class SessionWriter:
    """Write a session to MCAP as it is recorded; crash-safe (see module docstring).

    Use as a context manager: on an exception inside the ``with`` a 'note' event names it and the
    file is still finished cleanly. Counters: ``samples_written``, ``mag_samples_written``,
    ``events_written``, ``poses_written``, ``truth_samples_written``, ``messages_written``,
    ``flushes``.
    """

    def __init__(
        self,
        path: str | Path,
        meta: SessionMeta,
        *,
        flush_interval_s: float = 0.5,
        chunk_size: int = 64 * 1024,
        compression: str = DEFAULT_COMPRESSION,
        exclusive: bool = False,
        overwrite: bool = False,
        zstd_level: int = ZSTD_LEVEL,
    ) -> None:
        """exclusive=True (live recording): the file is created new under an exclusive output lock
        (accellog.store.atomic), an existing file is refused unless overwrite=True (``--force``).
        zstd_level: the level of zstd chunks (ZSTD_LEVEL)."""
        check_compression(compression)
        self._level = int(zstd_level)
        self.path = Path(path)
        self.meta = meta
        self._flush_s = float(flush_interval_s)
        self._flush_ns = to_ns(self._flush_s) if math.isfinite(self._flush_s) else None
        self._base_ns = int(meta.start_time_unix_ns)
        self._lock: OutputLock | None = None
        if exclusive:
            check_output(self.path, overwrite=overwrite)
            self._lock = OutputLock(self.path).acquire()
        try:
            if exclusive and overwrite and self.path.exists():
                self.path.unlink()
            self._f = open(self.path, "xb" if exclusive else "wb")  # noqa: SIM115 (closed in close())
        except FileExistsError:
            self._unlock()
            raise InputError("file exists; use --force to replace it", where=str(path)) from None
        except OSError as exc:
            self._unlock()
            raise InputError(f"cannot create the MCAP file: {exc.strerror or exc}", where=str(path)) from None
        self._w = Writer(
            self._f, chunk_size=chunk_size, compression=_COMPRESSION[compression], enable_data_crcs=True
        )
        self._w.start(profile="", library=f"accellog {__version__}")
        self._w.add_metadata("session", meta_to_metadata(meta))
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        for topic, msg in TOPIC_MESSAGE.items():
            self._channel(topic, msg)
        self.samples_written = 0
        self.mag_samples_written = 0
        self.events_written = 0
        self.poses_written = 0
        self.truth_samples_written = 0
        self.messages_written = 0
        self.flushes = 0
        self.closed = False
        self._t_last_ns = 0
        self._last_flush_t_ns: int | None = None
        self._last_flush_wall = time.monotonic()

    # -- plumbing ---------------------------------------------------------------------------------
    def _channel(self, topic: str, message: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            with at_level(self._level):  # mcap's Writer may end the current chunk to register them
                sid = self._schema_ids.get(message)
                if sid is None:
                    sid = self._w.register_schema(full_name(message), "protobuf", file_descriptor_set_bytes())
                    self._schema_ids[message] = sid
                cid = self._w.register_channel(topic, "protobuf", sid, metadata={"accellog": SCHEMA_VERSION})
            self._channels[topic] = cid
            self._seq[topic] = 0
        return cid

    def _add(self, topic: str, message: str, t_ns: int, data: bytes, host_time_ns: int = 0) -> None:
        if self.closed:
            raise ValueError(f"{self.path}: writer is closed")
        cid = self._channel(topic, message)
        log_time = max(0, self._base_ns + int(t_ns))
        pub = max(0, self._base_ns + int(host_time_ns)) if host_time_ns else log_time
        with at_level(self._level):  # a full chunk is compressed by this call
            self._w.add_message(
                cid, log_time=log_time, data=data, publish_time=pub, sequence=self._seq[topic]
            )
        self._seq[topic] += 1
        self.messages_written += 1

    def _maybe_flush(self, t_ns: int) -> None:
        """End the chunk if flush_interval_s of sensor or wall time passed since the last flush."""
        self._t_last_ns = max(self._t_last_ns, int(t_ns))
        if self._flush_ns is None:
            return
        if self._last_flush_t_ns is None:  # first data: put schemas/channels on disk at once
            self.flush()
            return
        if (
            self._t_last_ns - self._last_flush_t_ns >= self._flush_ns
            or time.monotonic() - self._last_flush_wall >= self._flush_s
        ):
            self.flush()

    def flush(self) -> None:
        """End the current chunk and write it to the OS (survives a killed process, not power loss)."""
        with at_level(self._level):
            self._w.flush()
        self.flushes += 1
        self._last_flush_t_ns = self._t_last_ns
        self._last_flush_wall = time.monotonic()

    # -- data -------------------------------------------------------------------------------------
    def write_imu(
        self,
        first_index: int,
        t_ns,
        accel_counts=None,
        gyro_counts=None,
        temp_counts=None,
        host_time_ns: int = 0,
        accel_g=None,
        gyro_dps=None,
        temp_degC=None,
    ) -> None:
        """One FIFO batch: t_ns (n,) sensor ns since start; counts (n,3)/(n,) int; or values in g, deg/s, degC."""
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        n = t.shape[0]
        if n == 0:
            return
        if accel_counts is None and accel_g is None:
            raise ValueError("write_imu needs accel_counts or accel_g")
        if accel_counts is not None and accel_g is None and self.meta.accel_lsb_per_g is None:
            raise ValueError("accel_counts without meta.accel_lsb_per_g: give accel_g too")
        for name, arr, width in (
            ("accel_counts", accel_counts, 3),
            ("gyro_counts", gyro_counts, 3),
            ("temp_counts", temp_counts, 1),
            ("accel_g", accel_g, 3),
            ("gyro_dps", gyro_dps, 3),
            ("temp_degC", temp_degC, 1),
        ):
            if arr is not None and np.size(arr) != n * width:
                raise ValueError(f"write_imu: {name} has {np.size(arr)} values, expected {n} x {width}")
        data = encode(
            "ImuBatch",
            first_sample_index=int(first_index),
            t_ns=t,
            accel_counts=accel_counts,
            gyro_counts=gyro_counts,
            temp_counts=temp_counts,
            host_time_ns=int(host_time_ns),
            accel_g=accel_g,
            gyro_dps=gyro_dps,
            temp_degC=temp_degC,
        )
        self._add(TOPIC_IMU, "ImuBatch", int(t[0]), data, int(host_time_ns))
        self.samples_written += n
        self._maybe_flush(int(t[-1]))

    def write_mag(
        self,
        t_ns,
        mag_counts=None,
        st2=None,
        asa_factor=None,
        ut_per_lsb: float = 0.0,
        mag_uT=None,
        *,
        first_index: int | None = None,
        host_time_ns: int = 0,
    ) -> None:
        """Magnetometer samples: t_ns (m,), raw counts (m,3), ST2 bytes (m,), ASA factors (3,), uT/LSB."""
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        m = t.shape[0]
        if m == 0:
            return
        if mag_counts is None and mag_uT is None:
            raise ValueError("write_mag needs mag_counts or mag_uT")
        st2_b = b"" if st2 is None else np.asarray(st2, dtype=np.uint8).reshape(-1).tobytes()
        if st2 is not None and len(st2_b) != m:
            raise ValueError(f"write_mag: st2 has {len(st2_b)} values, expected {m}")
        data = encode(
            "MagBatch",
            first_sample_index=self.mag_samples_written if first_index is None else int(first_index),
            t_ns=t,
            mag_counts=mag_counts,
            st2=st2_b,
            asa_factor=asa_factor,
            ut_per_lsb=float(ut_per_lsb),
            mag_uT=mag_uT,
            host_time_ns=int(host_time_ns),
        )
        self._add(TOPIC_MAG, "MagBatch", int(t[0]), data, int(host_time_ns))
        self.mag_samples_written += m
        self._maybe_flush(int(t[-1]))

    def write_mag_reading(self, reading) -> None:
        """Write a driver's magnetometer reading (duck-typed: t_ns, counts|mag_counts, st2,
        asa_factor|asa, ut_per_lsb, uT|mag_uT, host_time_ns; single sample or batch)."""

        def get(*names, default=None):
            for nm in names:
                v = getattr(reading, nm, None)
                if v is not None:
                    return v
            return default

        self.write_mag(
            np.atleast_1d(get("t_ns")),
            mag_counts=get("counts", "mag_counts"),
            st2=None if get("st2") is None else np.atleast_1d(get("st2")),
            asa_factor=get("asa_factor", "asa"),
            ut_per_lsb=float(get("ut_per_lsb", "uT_per_lsb", default=0.0)),
            mag_uT=get("uT", "mag_uT"),
            host_time_ns=int(get("host_time_ns", default=0)),
        )

    def write_pose(self, pose: PoseLabel) -> None:
        """A labelled static hold (start_s/end_s stored as ns)."""
        data = encode(
            "PoseLabel",
            name=pose.name,
            start_ns=to_ns(pose.start_s),
            end_ns=to_ns(pose.end_s),
            up_sensor=pose.up_sensor,
            q_sensor_to_world=pose.q_sensor_to_world,
            hold_index=int(pose.hold_index),
        )
        self._add(TOPIC_POSES, "PoseLabel", to_ns(pose.start_s), data)
        self.poses_written += 1
        self._maybe_flush(self._t_last_ns)

    def write_event(self, event: Event) -> None:
        """An event (gap, overflow, note, ...) at its sensor time."""
        t_ns = to_ns(event.t_s)
        data = encode(
            "Event",
            t_ns=t_ns,
            kind=event.kind,
            detail=event.detail,
            sample_index=int(event.sample_index),
            lost_samples=int(event.lost_samples),
        )
        self._add(TOPIC_EVENTS, "Event", t_ns, data)
        self.events_written += 1
        self._maybe_flush(self._t_last_ns)

    def write_truth(self, truth: Truth, *, batch_size: int = 1000) -> None:
        """Ground truth, written in slices of batch_size samples."""
        t_ns = to_ns_array(truth.t_s)
        for i in range(0, t_ns.shape[0], batch_size):
            s = slice(i, i + batch_size)
            data = encode(
                "TruthBatch",
                t_ns=t_ns[s],
                specific_force_g=truth.specific_force_g[s],
                omega_dps=truth.omega_dps[s],
                position_m=truth.position_m[s],
                velocity_mps=truth.velocity_mps[s],
                q_sensor_to_world=truth.q_sensor_to_world[s],
                temp_degC=truth.temp_degC[s],
            )
            self._add(TOPIC_TRUTH, "TruthBatch", int(t_ns[i]), data)
            self.truth_samples_written += int(t_ns[s].shape[0])
            self._maybe_flush(self._t_last_ns)

    def write_vector3(self, topic: str, t_ns, values, unit: str, frame: str = "sensor") -> None:
        """A derived 3-vector batch on /derived/<topic>: t_ns (n,) ns, values (n,3) in ``unit``."""
        if not topic.startswith(DERIVED_PREFIX):
            topic = DERIVED_PREFIX + topic.lstrip("/")
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        if t.shape[0] == 0:
            return
        if np.size(values) != 3 * t.shape[0]:
            raise ValueError(f"write_vector3: values has {np.size(values)} values, expected {t.shape[0]} x 3")
        data = encode("Vector3Batch", t_ns=t, values=values, unit=unit, frame=frame)
        self._add(topic, "Vector3Batch", int(t[0]), data)
        self._maybe_flush(int(t[-1]))

    def update_meta(self, meta: SessionMeta) -> None:
        """Record facts known only at the end (e.g. an importer's pose list) as a later 'session'
        metadata record; readers take the last one."""
        self.meta = meta
        self._w.add_metadata("session", meta_to_metadata(meta))

    def attach(self, name: str, media_type: str, data: bytes) -> None:
        """Attach a file (e.g. 'calibration/accel.json', 'application/json')."""
        self._w.add_attachment(
            create_time=time.time_ns(),
            log_time=max(0, self._base_ns + self._t_last_ns),
            name=name,
            media_type=media_type,
            data=bytes(data),
        )

    def close(self) -> None:
        """Write the summary and close the file (idempotent)."""
        if self.closed:
            return
        self.closed = True
        try:
            with at_level(self._level):
                self._w.finish()
        except OSError as exc:  # full disk, I/O error: the lock goes, the chunks written stay readable
            if self._lock is None:  # an atomic output: its temporary file is removed by its owner
                raise
            raise InputError(
                f"cannot finish the MCAP file: {exc.strerror or exc}; it holds the first "
                f"{self.samples_written} samples, without its summary (accellog reads them)",
                where=str(self.path),
            ) from None
        finally:
            with contextlib.suppress(OSError):  # the error above (or the one that ended it) says why
                self._f.close()
            self._unlock()

    def _unlock(self) -> None:
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and not self.closed:
            with contextlib.suppress(Exception):  # the writer itself may be what failed; still finish
                what = "interrupted" if issubclass(exc_type, KeyboardInterrupt) else exc_type.__name__
                self.write_event(Event(self._t_last_ns / NS_PER_S, "note", f"recording ended: {what}: {exc}"))
        self.close()


def _batch_bounds(sample_index: np.ndarray, host_ns: np.ndarray | None, batch_size: int) -> list[tuple]:
    """(start, end) of IMU batches: split at sample-index jumps, host-time changes, every batch_size."""
    n = sample_index.shape[0]
    cuts = [np.flatnonzero(np.diff(sample_index) != 1) + 1]
    if host_ns is not None:
        runs = np.flatnonzero(np.diff(host_ns) != 0) + 1
        if runs.shape[0] <= n // 8:
            cuts.append(runs)
    starts = np.unique(np.concatenate([[0], *cuts, [n]]))
    bounds = []
    for s, e in zip(starts[:-1].tolist(), starts[1:].tolist(), strict=True):
        bounds += [(i, min(i + batch_size, e)) for i in range(s, e, batch_size)]
    return bounds


def _values_needed(counts, values, scale_fn) -> bool:
    """True if values are not exactly recomputed from counts (so both must be stored)."""
    if counts is None:
        return True
    if values is None:
        return False
    try:
        return not np.array_equal(scale_fn(counts), values)
    except TypeError:
        return True


def write_session(
    path: str | Path,
    session: Session,
    *,
    batch_size: int = 500,
    compression: str = DEFAULT_COMPRESSION,
    chunk_size: int = 1024 * 1024,
    inputs: tuple = (),
    overwrite: bool = True,
) -> Path:
    """Write a whole in-memory Session atomically (accellog.store.atomic: lock, temp file, fsync,
    rename); an output equal to one of `inputs` is refused, an existing one too with overwrite=False.

    IMU batches hold up to batch_size samples and are split where sample_index jumps or host time
    changes (so both round-trip exactly; host time varying at nearly every sample is stored per
    batch, as the batch's last value). Counts are stored when present; values in g/deg/s/degC are
    stored when there are no counts or they are not exactly counts / LSB.
    """
    path = Path(path)
    meta = session.meta
    n = session.n
    ao = AtomicOutput(path, inputs=(*inputs, session.path or None), overwrite=overwrite)
    where = str(session.path or path)
    t_ns = to_ns_array(session.t_s, where)
    si = np.asarray(session.sample_index, dtype=np.int64)
    host_ns = None if session.host_time_s is None else to_ns_array(session.host_time_s, where)
    lsb_a, lsb_g = meta.accel_lsb_per_g, meta.gyro_lsb_per_dps
    ac = session.accel_counts
    put_ag = _values_needed(ac, session.accel_g, lambda c: c / lsb_a) if lsb_a else True
    gc = session.gyro_counts
    put_gd = session.gyro_dps is not None and (
        _values_needed(gc, session.gyro_dps, lambda c: c / lsb_g) if lsb_g else True
    )
    tc = session.temp_counts
    put_td = session.temp_degC is not None and _values_needed(tc, session.temp_degC, temp_counts_to_degC)
    gd = session.gyro_dps if put_gd else None  # values written next to (or instead of) the counts
    td = session.temp_degC if put_td else None
    tmp = ao.begin()
    try:
        with SessionWriter(
            tmp, meta, flush_interval_s=math.inf, chunk_size=chunk_size, compression=compression
        ) as w:
            if n:
                for s, e in _batch_bounds(si, host_ns, batch_size):
                    w.write_imu(
                        int(si[s]),
                        t_ns[s:e],
                        accel_counts=None if ac is None else ac[s:e],
                        gyro_counts=None if gc is None else gc[s:e],
                        temp_counts=None if tc is None else tc[s:e],
                        host_time_ns=0 if host_ns is None else int(host_ns[e - 1]),
                        accel_g=session.accel_g[s:e] if put_ag else None,
                        gyro_dps=None if gd is None else gd[s:e],
                        temp_degC=None if td is None else td[s:e],
                    )
            if session.mag_t_s is not None and session.mag_t_s.shape[0]:
                m_ns = to_ns_array(session.mag_t_s)
                for i in range(0, m_ns.shape[0], batch_size):
                    s = slice(i, i + batch_size)
                    w.write_mag(
                        m_ns[s],
                        mag_counts=None if session.mag_counts is None else session.mag_counts[s],
                        st2=None if session.mag_st2 is None else session.mag_st2[s],
                        mag_uT=None if session.mag_uT is None else session.mag_uT[s],
                        first_index=i,
                    )
            for p in session.poses:
                w.write_pose(p)
            for ev in session.events:
                w.write_event(ev)
            if session.truth is not None:
                w.write_truth(session.truth)
    except BaseException:
        ao.abort()
        raise
    ao.commit()
    return path
