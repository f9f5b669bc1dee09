"""MCAP files of accellog sessions: a crash-safe ``SessionWriter`` and a fast, recovering ``read_session``.

Layout (schemas in accellog/messages.py, protobuf package accellog.v1, one message per FIFO read):

| topic | schema | content |
|---|---|---|
| /imu | ImuBatch | accel/gyro/temp counts (or values) with per-sample sensor time t_ns |
| /mag | MagBatch | magnetometer counts, ST2, ASA factors |
| /poses | PoseLabel | labelled static holds |
| /events | Event | gaps, overflows, notes, ... |
| /truth | TruthBatch | ground truth of simulated sessions |
| /derived/... | Vector3Batch | derived channels (e.g. calibrated acceleration) |

Every ``SessionMeta`` field is stored as the MCAP metadata record 'session' (strings; extra keys as
'extra.<key>', plus 'schema_version'). Message log_time = meta.start_time_unix_ns + sensor t_ns of
the first sample; publish_time = start_time_unix_ns + host_time_ns.

Crash safety: the writer ends the current chunk and flushes the OS file at least every
``flush_interval_s`` of sensor time or wall time, so a killed recorder loses at most that much data
(plus the chunk being written); ``read_session`` salvages every complete chunk of an unfinished file.

Reading: a finished file in the canonical layout is read by ``_fast_collect`` (file mapped, footer and
summary parsed with struct, chunks decompressed ~4 MiB at a time into two reused buffers, the next group
on a worker thread while this one is decoded, records walked by checked guesses (runs of equal-length
messages), every channel's payloads decoded at once by ``messages.decode_batch`` straight into arrays
sized once; unit conversions into preallocated arrays, in two halves on two threads); anything else, or any surprise on the way, goes to the generic reader (mcap's SeekingReader +
``BatchDecoder``, with salvage of unfinished files). Both give identical Sessions (tests check it).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import mmap
import os
import struct
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from accellog.core.errors import InputError
from accellog.core.session import Event, PoseLabel, Session, SessionMeta, Truth
from accellog.core.units import TEMP_LSB_PER_DEGC, TEMP_OFFSET_DEGC, temp_counts_to_degC
from accellog.core.version import __version__
from accellog.store import messages as pb

NS_PER_S = 1_000_000_000
MCAP_MAGIC = b"\x89MCAP0\r\n"

TOPIC_IMU = "/imu"
TOPIC_MAG = "/mag"
TOPIC_POSES = "/poses"
TOPIC_EVENTS = "/events"
TOPIC_TRUTH = "/truth"
DERIVED_PREFIX = "/derived/"

_TOPIC_MESSAGE = {
    TOPIC_IMU: "ImuBatch",
    TOPIC_MAG: "MagBatch",
    TOPIC_POSES: "PoseLabel",
    TOPIC_EVENTS: "Event",
    TOPIC_TRUTH: "TruthBatch",
}
# read_session / read_vector3 try the vectorised reader first; False forces the generic reader (tests and
# benchmarks compare the two).
FAST_READ = True
# Chunk compression written by default. lz4 decompresses ~2x faster than zstd (read_session of a 1 kHz
# hour: ~0.3 s instead of ~0.4 s, benchmarks/bench_readback.py) and costs the recorder less CPU; its files
# are ~1.65x larger (~100 MB/h instead of ~60 MB/h at 1 kHz). Both are standard MCAP; readers take either.
DEFAULT_COMPRESSION = "lz4"
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


# ---------------------------------------------------------------------------------------------
# session metadata <-> MCAP metadata record (strings)


def meta_to_metadata(meta: SessionMeta) -> dict[str, str]:
    """MCAP metadata 'session': every SessionMeta field as a string (None -> ''), extra as 'extra.<k>'."""
    out = {"schema_version": pb.SCHEMA_VERSION, "accellog_version": __version__}
    for f in dataclasses.fields(SessionMeta):
        if f.name == "extra":
            continue
        v = getattr(meta, f.name)
        out[f.name] = "" if v is None else (repr(float(v)) if isinstance(v, float) else str(v))
    for k, v in meta.extra.items():
        out[f"extra.{k}"] = str(v)
    return out


def metadata_to_meta(d: dict[str, str], where: str = "") -> SessionMeta:
    """Inverse of ``meta_to_metadata`` (unknown keys are ignored, missing ones take defaults)."""
    kw: dict = {}
    for f in dataclasses.fields(SessionMeta):
        if f.name == "extra" or f.name not in d:
            continue
        s, ann = d[f.name], str(f.type)
        try:
            if "None" in ann and s == "":
                kw[f.name] = None
            elif ann.startswith("int"):
                kw[f.name] = int(s)
            elif ann.startswith("float"):
                kw[f.name] = float(s)
            else:
                kw[f.name] = s
        except ValueError:
            raise InputError(f"metadata 'session' field {f.name}={s!r} is not a {ann}", where=where) from None
    kw["extra"] = {k[6:]: v for k, v in d.items() if k.startswith("extra.")}
    kw.setdefault("source", "unknown")
    return SessionMeta(**kw)


def _ns(t_s: float) -> int:
    return round(t_s * NS_PER_S)


def _ns_array(t_s: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t_s, dtype=np.float64) * NS_PER_S).astype(np.int64)


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
    ) -> None:
        if compression not in _COMPRESSION:
            raise ValueError(f"compression must be one of {sorted(_COMPRESSION)}, not {compression!r}")
        self.path = Path(path)
        self.meta = meta
        self._flush_s = float(flush_interval_s)
        self._flush_ns = _ns(self._flush_s) if math.isfinite(self._flush_s) else None
        self._base_ns = int(meta.start_time_unix_ns)
        try:
            self._f = open(self.path, "wb")  # noqa: SIM115 (closed in close())
        except OSError as exc:
            raise InputError(f"cannot create the MCAP file: {exc.strerror or exc}", where=str(path)) from None
        self._w = Writer(
            self._f, chunk_size=chunk_size, compression=_COMPRESSION[compression], enable_data_crcs=True
        )
        self._w.start(profile="", library=f"accellog {__version__}")
        self._w.add_metadata("session", meta_to_metadata(meta))
        self._schema_ids: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[str, int] = {}
        for topic, msg in _TOPIC_MESSAGE.items():
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
            sid = self._schema_ids.get(message)
            if sid is None:
                sid = self._w.register_schema(
                    pb.full_name(message), "protobuf", pb.file_descriptor_set_bytes()
                )
                self._schema_ids[message] = sid
            cid = self._w.register_channel(topic, "protobuf", sid, metadata={"accellog": pb.SCHEMA_VERSION})
            self._channels[topic] = cid
            self._seq[topic] = 0
        return cid

    def _add(self, topic: str, message: str, t_ns: int, data: bytes, host_time_ns: int = 0) -> None:
        if self.closed:
            raise ValueError(f"{self.path}: writer is closed")
        cid = self._channel(topic, message)
        log_time = max(0, self._base_ns + int(t_ns))
        pub = max(0, self._base_ns + int(host_time_ns)) if host_time_ns else log_time
        self._w.add_message(cid, log_time=log_time, data=data, publish_time=pub, sequence=self._seq[topic])
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
        data = pb.encode(
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
        data = pb.encode(
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
        data = pb.encode(
            "PoseLabel",
            name=pose.name,
            start_ns=_ns(pose.start_s),
            end_ns=_ns(pose.end_s),
            up_sensor=pose.up_sensor,
            q_sensor_to_world=pose.q_sensor_to_world,
            hold_index=int(pose.hold_index),
        )
        self._add(TOPIC_POSES, "PoseLabel", _ns(pose.start_s), data)
        self.poses_written += 1
        self._maybe_flush(self._t_last_ns)

    def write_event(self, event: Event) -> None:
        """An event (gap, overflow, note, ...) at its sensor time."""
        t_ns = _ns(event.t_s)
        data = pb.encode(
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
        t_ns = _ns_array(truth.t_s)
        for i in range(0, t_ns.shape[0], batch_size):
            s = slice(i, i + batch_size)
            data = pb.encode(
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
        data = pb.encode("Vector3Batch", t_ns=t, values=values, unit=unit, frame=frame)
        self._add(topic, "Vector3Batch", int(t[0]), data)
        self._maybe_flush(int(t[-1]))

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
            self._w.finish()
        finally:
            self._f.close()

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and not self.closed:
            try:
                what = "interrupted" if issubclass(exc_type, KeyboardInterrupt) else exc_type.__name__
                self.write_event(Event(self._t_last_ns / NS_PER_S, "note", f"recording ended: {what}: {exc}"))
            except Exception:  # the writer itself may be what failed; still try to finish
                pass
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
) -> Path:
    """Write a whole in-memory Session atomically (temp file + rename); returns the path.

    IMU batches hold up to batch_size samples and are split where sample_index jumps or host time
    changes (so both round-trip exactly; host time varying at nearly every sample is stored per
    batch, as the batch's last value). Counts are stored when present; values in g/deg/s/degC are
    stored when there are no counts or they are not exactly counts / LSB.
    """
    path = Path(path)
    meta = session.meta
    n = session.n
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    t_ns = _ns_array(session.t_s)
    si = np.asarray(session.sample_index, dtype=np.int64)
    host_ns = None if session.host_time_s is None else _ns_array(session.host_time_s)
    lsb_a, lsb_g = meta.accel_lsb_per_g, meta.gyro_lsb_per_dps
    ac = session.accel_counts
    put_ag = _values_needed(ac, session.accel_g, lambda c: c / lsb_a) if lsb_a else True
    gc = session.gyro_counts
    put_gd = session.gyro_dps is not None and (
        _values_needed(gc, session.gyro_dps, lambda c: c / lsb_g) if lsb_g else True
    )
    tc = session.temp_counts
    put_td = session.temp_degC is not None and _values_needed(tc, session.temp_degC, temp_counts_to_degC)
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
                        gyro_dps=session.gyro_dps[s:e] if put_gd else None,
                        temp_degC=session.temp_degC[s:e] if put_td else None,
                    )
            if session.mag_t_s is not None and session.mag_t_s.shape[0]:
                m_ns = _ns_array(session.mag_t_s)
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
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


# ---------------------------------------------------------------------------------------------
# reader


_Decoder = pb.BatchDecoder | pb.DecodedBatch  # n_messages and result() (arrays, scalars, counts)


@dataclasses.dataclass
class _Collected:
    metadata: dict[str, str]
    topics: dict[str, str]  # topic -> schema name
    decoders: dict[str, _Decoder]
    recovered: str | None  # None: finished file; else what was salvaged


def _check_file(path: Path) -> None:
    if not path.is_file():
        raise InputError("no such file", where=str(path))
    try:
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc}", where=str(path)) from None
    if not head:
        raise InputError("empty file (0 bytes), not an MCAP session", where=str(path))
    if head != MCAP_MAGIC:
        raise InputError("not an MCAP file (bad magic bytes)", where=str(path))


class _Sink:
    """Routes (schema, channel, data) of accellog topics into per-topic batch decoders."""

    def __init__(self, topics: Iterable[str] | None) -> None:
        self.want = None if topics is None else set(topics)
        self.topics: dict[str, str] = {}
        self.decoders: dict[str, _Decoder] = {}
        self.metadata: dict[str, str] = {}
        self.n_messages = 0

    def channel(self, schema: Schema | None, channel: Channel) -> str | None:
        """Message type of the channel if it is an accellog.v1 protobuf channel, else None."""
        name = "" if schema is None else schema.name
        if schema is None or schema.encoding != "protobuf" or channel.message_encoding != "protobuf":
            self.topics.setdefault(channel.topic, f"{name or 'no schema'} as {channel.message_encoding}")
            return None
        self.topics.setdefault(channel.topic, name)
        msg = name[len(pb.PACKAGE) + 1 :] if name.startswith(pb.PACKAGE + ".") else ""
        return msg if msg in pb.MESSAGE_DEFS else None

    def add(self, schema: Schema | None, channel: Channel, data: bytes) -> None:
        self.n_messages += 1
        if self.want is not None and channel.topic not in self.want:
            return
        dec = self.decoders.get(channel.topic)
        if dec is None:
            msg = self.channel(schema, channel)
            if msg is None:
                return
            dec = self.decoders[channel.topic] = pb.BatchDecoder(msg)
        dec.add(data)


def _collect(path: Path, topics: Iterable[str] | None = None) -> _Collected:
    """Read every message of ``topics`` (all if None); salvage unfinished files chunk by chunk.

    Finished files in the canonical layout take the vectorised ``_fast_collect``; anything else (and
    any surprise on the way) takes the generic path (mcap's reader + ``BatchDecoder``), which gives
    the same result wherever both apply.
    """
    _check_file(path)
    fast = _fast_collect(path, topics) if FAST_READ else None
    if fast is not None:
        return fast
    return _generic_collect(path, topics)


def _generic_collect(path: Path, topics: Iterable[str] | None = None) -> _Collected:
    """``_collect`` with mcap's SeekingReader and one ``BatchDecoder.add`` per message."""
    sink = _Sink(topics)
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise McapError("no summary section")
            for sch, ch, msg in reader.iter_messages(topics=topics, log_time_order=False):
                sink.add(sch, ch, msg.data)
            for md in reader.iter_metadata():
                if md.name == "session":
                    sink.metadata = dict(md.metadata)
            for ch in summary.channels.values():
                sink.channel(summary.schemas.get(ch.schema_id), ch)
        return _Collected(sink.metadata, sink.topics, sink.decoders, None)
    except (McapError, EOFError, ValueError, OSError, IndexError, KeyError) as exc:
        fast_error = exc
    return _recover(path, topics, fast_error)


# ---------------------------------------------------------------------------------------------
# fast path: walk the MCAP file with struct/numpy, decode every batch channel at once


class _NotFast(Exception):
    """The fast reader met something outside the canonical layout: the generic reader decides."""


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
_Bytes = bytes | mmap.mmap  # the file: mapped read-only (no copy) by _fast_collect
_GROUP_BYTES = 4 << 20  # decompressed bytes decoded at a time (fits in L2/L3 cache)
_PAD = 16  # zero bytes after the decompressed records (vectorised reads may look a few bytes ahead)


def _fast_collect(path: Path, topics: Iterable[str] | None = None) -> _Collected | None:
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
    except Exception:  # an optimisation only: on any surprise the generic reader decides
        return None


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


def _fast_parse(data: _Bytes, topics: Iterable[str] | None) -> _Collected:
    size = len(data)
    if size < 2 * len(MCAP_MAGIC) + _FOOTER_SIZE or data[-len(MCAP_MAGIC) :] != MCAP_MAGIC:
        raise _NotFast("no footer magic: unfinished file")
    footer = size - len(MCAP_MAGIC) - _FOOTER_SIZE
    if _REC.unpack_from(data, footer) != (_OP_FOOTER, 20):
        raise _NotFast("no footer")
    summary_start = _U64.unpack_from(data, footer + 9)[0]
    if summary_start == 0 or summary_start >= footer:
        raise _NotFast("no summary section")

    # summary section: every record parsed must fill its declared length exactly
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

    # chunk indexes (vectorised): start offset of each chunk, in summary order
    buf = np.frombuffer(data, np.uint8)
    ci = np.asarray(chunk_index_at, dtype=np.int64)
    map_len = pb.read_le(buf, ci + 32, "<u4").astype(np.int64)
    comp_len = pb.read_le(buf, ci + 44 + map_len, "<u4").astype(np.int64)
    if np.any(32 + 4 + map_len + 8 + 4 + comp_len + 16 != np.asarray(chunk_index_len)):
        raise _NotFast("chunk index length")
    chunk_at = pb.read_le(buf, ci + 16, "<u8").astype(np.int64)
    if np.any(chunk_at > footer - 49) or np.any(buf[chunk_at] != _OP_CHUNK):
        raise _NotFast("chunk index does not point at a chunk")
    # chunk: start, end u64, uncompressed_size u64, crc u32, compression string, records (u64 length)
    c = chunk_at + 9
    usize = pb.read_le(buf, c + 16, "<u8").astype(np.int64)
    name_len = pb.read_le(buf, c + 28, "<u4").astype(np.int64)
    if np.any(name_len > 4):
        raise _NotFast("compression")
    rec_len = pb.read_le(buf, c + 32 + name_len, "<u8")
    if np.any(rec_len > np.uint64(size)):
        raise _NotFast("chunk past the end")
    rec_at = c + 40 + name_len
    rec_end = rec_at + rec_len.astype(np.int64)
    if np.any(rec_end > footer):
        raise _NotFast("chunk past the end")
    # chunks in groups of about _GROUP_BYTES decompressed: each group is decoded while in the CPU cache
    sink = _Sink(topics)
    message_of: dict[int, str | None] = {}  # channel id -> accellog message type (None: not decoded)
    parts: dict[int, pb.BatchAccumulator] = {}
    name_at, name_len, rec_at, rec_end = (
        (c + 32).tolist(),
        name_len.tolist(),
        rec_at.tolist(),
        rec_end.tolist(),
    )
    chunks = _Decompressor(data)
    usize_list = usize.tolist()
    done = (np.cumsum(usize) / max(1, int(usize.sum()))).tolist()  # fraction read after each chunk
    groups = _groups(usize)

    def decompress(i: int) -> tuple[bytearray, int]:
        g0, g1 = groups[i]
        return chunks.records(
            name_at[g0:g1], name_len[g0:g1], rec_at[g0:g1], rec_end[g0:g1], usize_list[g0:g1], i % 2
        )

    # group i + 1 is decompressed in a thread (lz4/zstd release the GIL) while group i is decoded;
    # leaving the with-block (also on an exception) waits for it, before the file is unmapped
    with ThreadPoolExecutor(1) as pool:
        pending = pool.submit(decompress, 0)
        for i, (g0, g1) in enumerate(groups):
            records, used = pending.result()
            if i + 1 < len(groups):
                pending = pool.submit(decompress, i + 1)
            _decode_group(
                records, used, usize_list[g0:g1], done[g1 - 1], channels, schemas, sink, message_of, parts
            )
    for cid, msg in message_of.items():
        if msg is not None:
            sink.decoders[channels[cid].topic] = parts[cid].finish()
    for ch in channels.values():
        sink.channel(schemas.get(ch.schema_id), ch)

    for at in metadata_at:
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
        if name == "session":
            sink.metadata = kv
    return _Collected(sink.metadata, sink.topics, sink.decoders, None)


def _decode_group(
    records: bytearray,
    used: int,
    usize: list[int],
    done: float,
    channels: dict[int, Channel],
    schemas: dict[int, Schema],
    sink: _Sink,
    message_of: dict[int, str | None],
    parts: dict[int, pb.BatchAccumulator],
) -> None:
    """Decode the messages of one group of decompressed chunks into the channels' accumulators."""
    messages = _message_starts(records, usize)
    if not messages.shape[0]:
        return
    rb = np.frombuffer(records, np.uint8, used + _PAD)
    msg_len = pb.read_le(rb, messages + 1, "<u8")
    if np.any(msg_len < _MESSAGE_HEADER):
        raise _NotFast("short message record")
    channel_id = pb.read_le(rb, messages + 9, "<u2")
    payload_at = messages + 9 + _MESSAGE_HEADER
    payload_end = messages + 9 + msg_len.astype(np.int64)
    ids, first = np.unique(channel_id, return_index=True)
    for cid in ids[np.argsort(first)].tolist():
        if cid not in message_of:  # first message of the channel, as the generic sink sees it
            ch = channels[cid]
            wanted = sink.want is None or ch.topic in sink.want
            schema = None if ch.schema_id == 0 else schemas[ch.schema_id]
            message_of[cid] = sink.channel(schema, ch) if wanted else None
            parts[cid] = pb.BatchAccumulator(message_of[cid] or "")
        msg = message_of[cid]
        if msg is None:
            continue
        sel = slice(None) if ids.shape[0] == 1 else np.flatnonzero(channel_id == cid)
        acc, frac = parts[cid], done
        dec = pb.decode_batch(
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
    """Decompresses runs of chunks into one reused buffer (fresh memory per group would cost page faults)."""

    def __init__(self, data: _Bytes) -> None:
        import lz4.frame
        import zstandard

        self.data = data
        self.zstd = zstandard.ZstdDecompressor().decompress
        self.lz4 = lz4.frame.decompress
        self.bufs = [bytearray(), bytearray()]

    def records(
        self,
        name_at: list[int],
        name_len: list[int],
        at: list[int],
        end: list[int],
        usize: list[int],
        slot: int = 0,
    ) -> tuple[bytearray, int]:
        """(buffer, n): the chunks' records back to back in buffer[:n], then _PAD zero bytes.

        Two buffers (slot 0 or 1): one is filled while the other is decoded."""
        total = sum(usize)
        if len(self.bufs[slot]) < total + _PAD:
            self.bufs[slot] = bytearray(total + _PAD)
        buf, data, mv = self.bufs[slot], self.data, memoryview(self.data)  # released on return
        pos = 0
        for na, nl, a, b, u in zip(name_at, name_len, at, end, usize, strict=True):
            comp = data[na : na + nl]
            if comp == b"zstd":
                out = self.zstd(mv[a:b], max_output_size=u)
            elif comp == b"lz4":
                out = self.lz4(mv[a:b])
            elif comp == b"":
                out = mv[a:b]
            else:
                raise _NotFast(f"compression {comp!r}")
            if len(out) != u:
                raise _NotFast("chunk size")
            buf[pos : pos + u] = out
            pos += u
        buf[pos : pos + _PAD] = bytes(_PAD)
        return buf, pos


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
            ok = (rb[guess] == _OP_MESSAGE) & (pb.read_le(rb, guess + 1, "<u8") == ln)
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


def _recover(path: Path, topics: Iterable[str] | None, why: Exception) -> _Collected:
    """Scan the file front to back and keep every complete chunk (all-or-nothing per chunk)."""
    sink = _Sink(topics)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    n_chunks = 0
    stop = ""

    def handle(rec) -> None:
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
            sink.channel(schemas.get(rec.schema_id), rec)
        elif isinstance(rec, Message):
            ch = channels.get(rec.channel_id)
            if ch is not None:
                sink.add(schemas.get(ch.schema_id), ch, rec.data)
        elif isinstance(rec, Metadata) and rec.name == "session":
            sink.metadata = dict(rec.metadata)

    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, emit_chunks=True).records:
                if isinstance(rec, Chunk):
                    inner = breakup_chunk(rec, validate_crc=True)  # whole chunk or nothing
                    for r in inner:
                        handle(r)
                    n_chunks += 1
                else:
                    handle(rec)
        except Exception as exc:  # anything unreadable ends the salvage: keep what is complete
            stop = f"{type(exc).__name__} at byte {f.tell()}"
    size = path.stat().st_size
    detail = (
        f"file was not finished ({type(why).__name__}: {why}); salvaged {sink.n_messages} messages "
        f"in {n_chunks} chunks of {size} bytes; reading stopped: {stop or 'end of data'}"
    )
    return _Collected(sink.metadata, sink.topics, sink.decoders, detail)


def _reshape(arr: np.ndarray, n: int, width: int, what: str, where: str) -> np.ndarray | None:
    if arr.size == 0:
        return None
    if arr.size != n * width:
        raise InputError(f"{what} has {arr.size} values for {n} samples (mixed batches)", where=where)
    return arr.reshape(n, width) if width > 1 else arr


_SPLIT_MIN = 200_000  # _split_run: samples below which one thread does it all


def _split_run(fn, n: int) -> None:
    """fn(0, n/2) on a worker thread and fn(n/2, n) here, concurrently (numpy releases the GIL)."""
    if n < _SPLIT_MIN:
        fn(0, n)
        return
    mid = n // 2
    with ThreadPoolExecutor(1) as pool:
        first = pool.submit(fn, 0, mid)
        fn(mid, n)
        first.result()


def read_session(path: str | Path) -> Session:
    """Read an accellog MCAP file into a Session (fast; recovers unfinished/truncated files).

    A recovered file gets an extra Event('recovered') saying how much was salvaged. Raises
    InputError (one line) for a missing/empty/non-MCAP file, a file without an accellog.v1 /imu
    channel, or a session without samples.
    """
    path = Path(path)
    where = str(path)
    col = _collect(path)
    if col.topics.get(TOPIC_IMU) != pb.full_name("ImuBatch"):
        found = ", ".join(f"{t} ({s})" for t, s in sorted(col.topics.items())) or "none"
        if col.recovered is not None and not col.topics:
            raise InputError("truncated MCAP file: no complete chunk with IMU data to recover", where=where)
        raise InputError(
            f"not an accellog session: no {TOPIC_IMU} channel of {pb.full_name('ImuBatch')} (channels: {found})",
            where=where,
        )
    meta = metadata_to_meta(col.metadata, where) if col.metadata else SessionMeta(source="unknown")
    dec = col.decoders.get(TOPIC_IMU)
    if dec is None or dec.n_messages == 0:
        raise InputError(
            "session has no IMU samples" + (" (truncated file)" if col.recovered else ""), where=where
        )
    arrays, scalars, counts = dec.result()
    n_per = counts["t_ns"]
    n = int(n_per.sum())
    if n == 0:
        raise InputError("session has no IMU samples", where=where)
    t_ns = arrays["t_ns"]
    starts = np.cumsum(n_per) - n_per
    first = np.asarray(scalars["first_sample_index"], dtype=np.int64)
    offset = first - starts  # sample_index[i] = offset[k] + i for the samples i of message k
    if np.all(offset == offset[0]):  # no gap anywhere: one arange
        sample_index = np.arange(offset[0], offset[0] + n, dtype=np.int64)
    else:
        sample_index = np.repeat(offset, n_per) + np.arange(n, dtype=np.int64)
    full = n_per > 0  # samples out of order <=> a message starts below the previous one's last index
    in_order = not np.any(first[full][1:] < (first + n_per - 1)[full][:-1])
    host = np.asarray(scalars["host_time_ns"], dtype=np.int64)
    host_time_s = np.repeat(host / NS_PER_S, n_per) if np.any(host != 0) else None

    lsb_a = lsb_g = temp_c = None  # conversions to do from counts (filled in halves on 2 threads)
    accel_counts = _reshape(arrays["accel_counts"], n, 3, "accel_counts", where)
    accel_g = _reshape(arrays["accel_g"], n, 3, "accel_g", where)
    if accel_g is None:
        if accel_counts is None:
            raise InputError("IMU batches carry neither accel_counts nor accel_g", where=where)
        if not meta.accel_lsb_per_g:
            raise InputError("accel_counts without accel_lsb_per_g in the session metadata", where=where)
        accel_g = np.empty(accel_counts.shape)  # = accel_counts / accel_lsb_per_g, filled below
        lsb_a = meta.accel_lsb_per_g
    gyro_counts = _reshape(arrays["gyro_counts"], n, 3, "gyro_counts", where)
    gyro_dps = _reshape(arrays["gyro_dps"], n, 3, "gyro_dps", where)
    if gyro_dps is None and gyro_counts is not None and meta.gyro_lsb_per_dps:
        gyro_dps = np.empty(gyro_counts.shape)  # = gyro_counts / gyro_lsb_per_dps
        lsb_g = meta.gyro_lsb_per_dps
    temp_counts = _reshape(arrays["temp_counts"], n, 1, "temp_counts", where)
    temp_degC = _reshape(arrays["temp_degC"], n, 1, "temp_degC", where)
    if temp_degC is None and temp_counts is not None:
        temp_degC = np.empty(n)  # = temp_counts_to_degC(temp_counts)
        temp_c = temp_counts
    t_s = np.empty(n)

    def convert(lo: int, hi: int) -> None:
        """Unit conversions of samples lo..hi into the preallocated float64 arrays (no temporaries)."""
        np.divide(t_ns[lo:hi], NS_PER_S, out=t_s[lo:hi])
        if lsb_a is not None:
            np.divide(accel_counts[lo:hi], lsb_a, out=accel_g[lo:hi])
        if lsb_g is not None:
            np.divide(gyro_counts[lo:hi], lsb_g, out=gyro_dps[lo:hi])
        if temp_c is not None:
            out = temp_degC[lo:hi]  # temp_counts_to_degC: counts / 333.87 + 21, the same two operations
            np.divide(temp_c[lo:hi], TEMP_LSB_PER_DEGC, out=out)
            np.add(out, TEMP_OFFSET_DEGC, out=out)

    _split_run(convert, n)

    if not in_order:  # batches out of order: sort samples once
        order = np.argsort(sample_index, kind="stable")
        sample_index, t_s = sample_index[order], t_s[order]
        fix = [accel_g, accel_counts, gyro_dps, gyro_counts, temp_degC, temp_counts, host_time_s]
        accel_g, accel_counts, gyro_dps, gyro_counts, temp_degC, temp_counts, host_time_s = (
            None if a is None else a[order] for a in fix
        )

    session = Session(
        meta=meta,
        t_s=t_s,
        sample_index=sample_index,
        accel_g=accel_g,
        accel_counts=accel_counts,
        gyro_dps=gyro_dps,
        gyro_counts=gyro_counts,
        temp_degC=temp_degC,
        temp_counts=temp_counts,
        host_time_s=host_time_s,
        path=str(path),
    )
    _read_mag(session, col.decoders.get(TOPIC_MAG), where)
    session.poses = _read_poses(col.decoders.get(TOPIC_POSES))
    session.events = _read_events(col.decoders.get(TOPIC_EVENTS))
    session.truth = _read_truth(col.decoders.get(TOPIC_TRUTH), where)
    if col.recovered is not None:
        session.events.append(Event(float(session.t_s[-1]), "recovered", col.recovered))
    return session


def _read_mag(session: Session, dec: _Decoder | None, where: str) -> None:
    if dec is None or dec.n_messages == 0:
        return
    arrays, scalars, counts = dec.result()
    m = int(counts["t_ns"].sum())
    if m == 0:
        return
    session.mag_t_s = arrays["t_ns"] / NS_PER_S
    session.mag_counts = _reshape(arrays["mag_counts"], m, 3, "mag_counts", where)
    st2 = b"".join(scalars["st2"])
    session.mag_st2 = np.frombuffer(st2, np.uint8).copy() if len(st2) == m else None
    mag_uT = _reshape(arrays["mag_uT"], m, 3, "mag_uT", where)
    if mag_uT is None and session.mag_counts is not None:
        asa = arrays["asa_factor"]
        if asa.size == 3 * dec.n_messages:
            factor = np.repeat(asa.reshape(-1, 3), counts["t_ns"], axis=0)
        else:
            factor = np.ones((m, 3))
        scale = np.repeat(np.asarray(scalars["ut_per_lsb"], dtype=np.float64), counts["t_ns"])
        mag_uT = session.mag_counts * factor * scale[:, None]
    session.mag_uT = mag_uT


def _messages(dec: _Decoder | None):
    """Per-message dicts of a small-message channel (poses, events)."""
    if dec is None:
        return []
    arrays, scalars, counts = dec.result()
    out = []
    offs = {k: np.concatenate([[0], np.cumsum(v)]) for k, v in counts.items()}
    for i in range(dec.n_messages):
        d = {k: v[i] for k, v in scalars.items()}
        for k, a in arrays.items():
            d[k] = a[offs[k][i] : offs[k][i + 1]]
        out.append(d)
    return out


def _read_poses(dec: _Decoder | None) -> list[PoseLabel]:
    return [
        PoseLabel(
            name=d["name"],
            start_s=d["start_ns"] / NS_PER_S,
            end_s=d["end_ns"] / NS_PER_S,
            up_sensor=tuple(float(v) for v in d["up_sensor"]),
            q_sensor_to_world=tuple(float(v) for v in d["q_sensor_to_world"])
            if d["q_sensor_to_world"].size
            else None,
            hold_index=int(d["hold_index"]),
        )
        for d in _messages(dec)
    ]


def _read_events(dec: _Decoder | None) -> list[Event]:
    return [
        Event(d["t_ns"] / NS_PER_S, d["kind"], d["detail"], int(d["sample_index"]), int(d["lost_samples"]))
        for d in _messages(dec)
    ]


def _read_truth(dec: _Decoder | None, where: str) -> Truth | None:
    if dec is None or dec.n_messages == 0:
        return None
    a, _, counts = dec.result()
    k = int(counts["t_ns"].sum())

    def r(name: str, width: int) -> np.ndarray:
        out = _reshape(a[name], k, width, name, where)
        return np.full((k, width) if width > 1 else (k,), np.nan) if out is None else out

    return Truth(
        t_s=a["t_ns"] / NS_PER_S,
        specific_force_g=r("specific_force_g", 3),
        omega_dps=r("omega_dps", 3),
        position_m=r("position_m", 3),
        velocity_mps=r("velocity_mps", 3),
        q_sensor_to_world=r("q_sensor_to_world", 4),
        temp_degC=r("temp_degC", 1),
    )


def read_vector3(path: str | Path, topic: str) -> tuple[np.ndarray, np.ndarray, str, str]:
    """A derived channel: (t_s (n,), values (n,3), unit, frame). InputError if the topic is absent."""
    path = Path(path)
    if not topic.startswith(DERIVED_PREFIX):
        topic = DERIVED_PREFIX + topic.lstrip("/")
    col = _collect(path, [topic])
    dec = col.decoders.get(topic)
    if dec is None or dec.n_messages == 0:
        raise InputError(f"no derived channel {topic}", where=str(path))
    a, s, c = dec.result()
    n = int(c["t_ns"].sum())
    return a["t_ns"] / NS_PER_S, a["values"].reshape(n, 3), s["unit"][0], s["frame"][0]


def read_attachments(path: str | Path) -> list[tuple[str, str, bytes]]:
    """(name, media_type, data) of every attachment of a finished file."""
    _check_file(Path(path))
    try:
        with open(path, "rb") as f:
            return [(a.name, a.media_type, bytes(a.data)) for a in make_reader(f).iter_attachments()]
    except McapError as exc:
        raise InputError(f"cannot read attachments ({exc}): file not finished?", where=str(path)) from None


def session_summary(path: str | Path) -> dict:
    """Fast facts from the MCAP summary section (no message is decoded).

    Keys: path, bytes, finished, messages, chunks, topics {topic: {schema, messages}}, start_ns,
    end_ns, duration_s (log-time span), metadata (the 'session' record), attachments [(name,
    media_type, bytes)]. An unfinished file is scanned instead (finished=False).
    """
    path = Path(path)
    _check_file(path)
    out: dict = {"path": str(path), "bytes": path.stat().st_size}
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summ = reader.get_summary()
            if summ is None or summ.statistics is None:
                raise McapError("no summary")
            st = summ.statistics
            out.update(
                finished=True,
                messages=st.message_count,
                chunks=st.chunk_count,
                start_ns=st.message_start_time,
                end_ns=st.message_end_time,
                duration_s=(st.message_end_time - st.message_start_time) / NS_PER_S,
                topics={
                    ch.topic: {
                        "schema": summ.schemas[ch.schema_id].name if ch.schema_id in summ.schemas else "",
                        "messages": st.channel_message_counts.get(cid, 0),
                    }
                    for cid, ch in summ.channels.items()
                },
                metadata={},
                attachments=[(a.name, a.media_type, a.data_size) for a in summ.attachment_indexes],
            )
            for md in reader.iter_metadata():
                if md.name == "session":
                    out["metadata"] = dict(md.metadata)
        return out
    except (McapError, EOFError, ValueError, OSError) as exc:
        col = _recover(path, None, exc)
    out.update(
        finished=False,
        recovered=col.recovered,
        topics={
            t: {"schema": s, "messages": col.decoders[t].n_messages if t in col.decoders else 0}
            for t, s in col.topics.items()
        },
        messages=sum(d.n_messages for d in col.decoders.values()),
        metadata=col.metadata,
        attachments=[],
    )
    return out
