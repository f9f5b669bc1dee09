"""``read_session``: an accellog MCAP file into a ``Session`` (fast; recovers unfinished/truncated files).

A finished file in the canonical layout is read by ``fastread``; anything else, or any surprise on the
way, by the generic reader with salvage (``collect``). Unit conversions go into preallocated arrays, in
two halves on two threads. Also ``read_vector3`` (derived channels), ``read_attachments`` and
``session_summary``.

The fast reader converts the /imu channel group by group (``ImuAccumulator``): after each group's
ImuBatch messages are decoded into it, it converts their samples at once, while they are in the CPU
cache and while the reader's other thread decompresses the next group, into arrays sized once: t_s
(ns -> s, in place of t_ns: the integer times are not kept), accel_g and gyro_dps (counts / LSB),
temp_degC (counts / 333.87 + 21), host_time_s (each message's host time on its samples) and
sample_index. Every conversion is elementwise, so the values are those of converting the whole
arrays at the end (bit for bit); ``read_session`` decides at the end which ones it uses (a file that
stores values instead of counts, or mixed batches, take its usual path). ``first_indexes`` and
``per_sample`` are shared with the chunk-by-chunk reader (``store.stream``).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import NoReturn

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader

from accellog.core.errors import DataIntegrityWarning, InputError
from accellog.core.session import Event, PoseLabel, Session, SessionMeta, Truth, quat4, vec3
from accellog.core.units import TEMP_LSB_PER_DEGC, temp_counts_to_degC
from accellog.store.collect import Collected, Damage, Decoder, check_file, generic_collect, recover
from accellog.store.layout import (
    DERIVED_PREFIX,
    NS_PER_S,
    TOPIC_EVENTS,
    TOPIC_IMU,
    TOPIC_MAG,
    TOPIC_POSES,
    TOPIC_TRUTH,
    metadata_to_meta,
)
from accellog.store.mcap.batch_decode import BatchAccumulator, DecodedBatch
from accellog.store.mcap.fastread import fast_collect
from accellog.store.mcap.records import scanned_metadata
from accellog.store.mcap.summary import SummaryFacts, attachments_of, summary_of
from accellog.store.schema import full_name

# read_session / read_vector3 try the vectorised reader first; False forces the generic reader (tests and
# benchmarks compare the two).
FAST_READ = True


def collect_session(path: Path, topics: Iterable[str] | None = None, accumulator=None) -> Collected:
    """Read every message of ``topics`` (all if None); salvage unfinished files chunk by chunk.

    Finished files in the canonical layout take the vectorised ``fast_collect``; anything else (and
    any surprise on the way) takes the generic path (mcap's reader + ``BatchDecoder``), which gives
    the same result wherever both apply.
    """
    check_file(path)
    fast = fast_collect(path, topics, accumulator) if FAST_READ else None
    if fast is not None:
        return fast
    return generic_collect(path, topics)


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
    col = collect_session(path, accumulator=_imu_accumulator)
    if col.topics.get(TOPIC_IMU) != full_name("ImuBatch"):
        _refuse_without_imu(col, where)
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
    derived = getattr(dec, "derived", None) or {}  # converted group by group while reading
    if derived and lsb_scales(col.metadata) != (meta.accel_lsb_per_g or None, meta.gyro_lsb_per_dps or None):
        derived = {k: v for k, v in derived.items() if k not in ("accel_g", "gyro_dps")}  # other scales
    first = first_indexes(scalars["first_sample_index"], n_per, where)
    sample_index, in_order = _sample_index(first, n_per, n, derived.get("sample_index"))
    host = np.asarray(scalars["host_time_ns"], dtype=np.int64)
    cols = _sample_arrays(arrays, n, meta, where, derived)
    if not np.any(host != 0):
        cols["host_time_s"] = None
    elif "host_time_s" in derived:
        cols["host_time_s"] = derived["host_time_s"]
    else:
        cols["host_time_s"] = np.repeat(host / NS_PER_S, n_per)
    if not in_order:  # batches out of order: sort samples once
        order = np.argsort(sample_index, kind="stable")
        sample_index = sample_index[order]
        cols = {k: None if a is None else a[order] for k, a in cols.items()}
    session = Session(meta=meta, sample_index=sample_index, path=str(path), **cols)
    _read_other_topics(session, col, where)
    return session


def _refuse_without_imu(col: Collected, where: str) -> NoReturn:
    """InputError for a file without a readable accellog IMU channel: damaged, truncated or another kind."""
    found = ", ".join(f"{t} ({s})" for t, s in sorted(col.topics.items())) or "none"
    if col.damaged:
        raise InputError("nothing readable: " + "; ".join(d.describe() for d in col.damaged[:3]), where=where)
    if col.recovered is not None and not col.topics:
        if col.recovered.startswith("damaged"):
            raise InputError(f"no complete chunk with IMU data to recover: {col.recovered}", where=where)
        raise InputError("truncated MCAP file: no complete chunk with IMU data to recover", where=where)
    raise InputError(
        f"not an accellog session: no {TOPIC_IMU} channel of {full_name('ImuBatch')} (channels: {found})",
        where=where,
    )


def _imu_accumulator(topic: str, message: str, meta_kv: dict[str, str]):
    """The fast reader's accumulator of the /imu channel: converts units group by group."""
    if topic != TOPIC_IMU or message != "ImuBatch":
        return None
    return ImuAccumulator(message, *lsb_scales(meta_kv))


def _sample_index(
    first: np.ndarray, n_per: np.ndarray, n: int, done: np.ndarray | None = None
) -> tuple[np.ndarray, bool]:
    """(sample index of every sample, whether the batches are in order) from each batch's first index
    (done: the sample index already computed group by group)."""
    starts = np.cumsum(n_per) - n_per
    offset = first - starts  # sample_index[i] = offset[k] + i for the samples i of message k
    if done is not None:
        sample_index = done
    elif np.all(offset == offset[0]):  # no gap anywhere: one arange (shifted: no stop past int64)
        sample_index = np.arange(n, dtype=np.int64)
        sample_index += offset[0]
    else:
        sample_index = np.repeat(offset, n_per) + np.arange(n, dtype=np.int64)
    full = n_per > 0  # samples out of order <=> a message starts below the previous one's last index
    in_order = not np.any(first[full][1:] < (first + n_per - 1)[full][:-1])
    return sample_index, bool(in_order)


def _sample_arrays(arrays: dict, n: int, meta: SessionMeta, where: str, derived: dict) -> dict:
    """The Session's sample columns (t_s, accel, gyro, temperature; counts and physical units), the
    missing physical ones taken from ``derived`` (converted while reading) or converted from counts
    in two halves on two threads."""
    lsb_a = lsb_g = temp_c = None  # conversions to do from counts (filled in halves on 2 threads)
    accel_counts = _reshape(arrays["accel_counts"], n, 3, "accel_counts", where)
    accel_g = _reshape(arrays["accel_g"], n, 3, "accel_g", where)
    if accel_g is None:
        if accel_counts is None:
            raise InputError("IMU batches carry neither accel_counts nor accel_g", where=where)
        if not meta.accel_lsb_per_g:
            raise InputError("accel_counts without accel_lsb_per_g in the session metadata", where=where)
        accel_g = derived.get("accel_g")  # = accel_counts / accel_lsb_per_g
        if accel_g is None:
            accel_g = np.empty(accel_counts.shape)  # filled below
            lsb_a = meta.accel_lsb_per_g
        accel_g = accel_g.reshape(accel_counts.shape)
    gyro_counts = _reshape(arrays["gyro_counts"], n, 3, "gyro_counts", where)
    gyro_dps = _reshape(arrays["gyro_dps"], n, 3, "gyro_dps", where)
    if gyro_dps is None and gyro_counts is not None and meta.gyro_lsb_per_dps:
        gyro_dps = derived.get("gyro_dps")  # = gyro_counts / gyro_lsb_per_dps
        if gyro_dps is None:
            gyro_dps = np.empty(gyro_counts.shape)
            lsb_g = meta.gyro_lsb_per_dps
        gyro_dps = gyro_dps.reshape(gyro_counts.shape)
    temp_counts = _reshape(arrays["temp_counts"], n, 1, "temp_counts", where)
    temp_degC = _reshape(arrays["temp_degC"], n, 1, "temp_degC", where)
    if temp_degC is None and temp_counts is not None:
        temp_degC = derived.get("temp_degC")  # = temp_counts_to_degC(temp_counts)
        if temp_degC is None:
            temp_degC = np.empty(n)
            temp_c = temp_counts
    t_ns = arrays.get("t_ns")
    t_s = derived.get("t_s")
    if t_s is None:
        t_s = np.empty(n)

    def convert(lo: int, hi: int) -> None:
        """Unit conversions of samples lo..hi into the preallocated float64 arrays (no temporaries)."""
        if t_ns is not None:
            np.divide(t_ns[lo:hi], NS_PER_S, out=t_s[lo:hi])
        if lsb_a is not None and accel_counts is not None:
            np.divide(accel_counts[lo:hi], lsb_a, out=accel_g[lo:hi])
        if lsb_g is not None and gyro_counts is not None and gyro_dps is not None:
            np.divide(gyro_counts[lo:hi], lsb_g, out=gyro_dps[lo:hi])
        if temp_c is not None and temp_degC is not None:
            temp_counts_to_degC(temp_c[lo:hi], out=temp_degC[lo:hi])

    if t_ns is not None or lsb_a is not None or lsb_g is not None or temp_c is not None:
        _split_run(convert, n)
    return {
        "t_s": t_s,
        "accel_g": accel_g,
        "accel_counts": accel_counts,
        "gyro_dps": gyro_dps,
        "gyro_counts": gyro_counts,
        "temp_degC": temp_degC,
        "temp_counts": temp_counts,
    }


def _read_other_topics(session: Session, col: Collected, where: str) -> None:
    """Magnetometer, poses, events and truth into the session; the recovered and damaged parts as events
    (each damaged chunk also a DataIntegrityWarning)."""
    _read_mag(session, col.decoders.get(TOPIC_MAG), where)
    session.poses = read_poses(col.decoders.get(TOPIC_POSES))
    session.events = read_events(col.decoders.get(TOPIC_EVENTS))
    session.truth = _read_truth(col.decoders.get(TOPIC_TRUTH), where)
    if col.recovered is not None:
        session.events.append(Event(float(session.t_s[-1]), "recovered", col.recovered))
    for d in col.damaged:
        ev = _damage_event(session, d)
        session.events.append(ev)
        warnings.warn(f"{where}: {ev.detail}", DataIntegrityWarning, stacklevel=3)  # read_session's caller


def _damage_event(session: Session, d: Damage) -> Event:
    """Event('damaged') for a skipped chunk: what was lost, counted from the sample-index gaps the
    skipped chunk left (its IMU batches start within [start, end] of the chunk's log times), less
    the gaps other events already account for."""
    if not d.chunk:
        return Event(float(session.t_s[-1]), "damaged", d.describe() + "; the session metadata is unverified")
    base = session.meta.start_time_unix_ns
    t0, t1 = (d.start_ns - base) / NS_PER_S, (d.end_ns - base) / NS_PER_S
    t, si, n = session.t_s, session.sample_index, session.n
    i0 = max(int(np.searchsorted(t, t0)) - 1, 0)
    i1 = min(int(np.searchsorted(t, t1, "right")), n - 1)
    lost = int(si[i1] - si[i0]) - (i1 - i0)
    lost -= sum(e.lost_samples for e in session.events if t0 <= e.t_s <= t[i1] and e.kind != "damaged")
    lost = max(lost, 0)
    rate = session.meta.sample_rate_hz
    tail = t1 >= t[-1]  # the chunk held the last batches: how many samples they had is unknown
    if tail and rate:
        lost += round((t1 - t[-1]) * rate)
    detail = (
        f"damaged chunk at byte {d.offset} (t {t0:.3f}-{t1:.3f} s): {d.reason}; skipped, "
        f"{'at least ' if tail else ''}{lost} IMU samples lost (and any pose, event or mag message in it)"
    )
    return Event(float(min(max(t0, 0.0), t[-1])), "damaged", detail, int(si[i0]) + 1, lost)


def _read_mag(session: Session, dec: Decoder | None, where: str) -> None:
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


def _messages(dec: Decoder | None):
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


def read_poses(dec: Decoder | None) -> list[PoseLabel]:
    return [
        PoseLabel(
            name=d["name"],
            start_s=d["start_ns"] / NS_PER_S,
            end_s=d["end_ns"] / NS_PER_S,
            up_sensor=vec3(d["up_sensor"]),
            q_sensor_to_world=quat4(d["q_sensor_to_world"]) if d["q_sensor_to_world"].size else None,
            hold_index=int(d["hold_index"]),
        )
        for d in _messages(dec)
    ]


def read_events(dec: Decoder | None) -> list[Event]:
    return [
        Event(d["t_ns"] / NS_PER_S, d["kind"], d["detail"], int(d["sample_index"]), int(d["lost_samples"]))
        for d in _messages(dec)
    ]


def _read_truth(dec: Decoder | None, where: str) -> Truth | None:
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
    col = collect_session(path, [topic])
    dec = col.decoders.get(topic)
    if dec is None or dec.n_messages == 0:
        raise InputError(f"no derived channel {topic}", where=str(path))
    a, s, c = dec.result()
    n = int(c["t_ns"].sum())
    return a["t_ns"] / NS_PER_S, a["values"].reshape(n, 3), s["unit"][0], s["frame"][0]


def read_attachments(path: str | Path) -> list[tuple[str, str, bytes]]:
    """(name, media_type, data) of every attachment of a finished file."""
    check_file(Path(path))
    try:
        found = attachments_of(path, summary_of(path).attachment_indexes)  # no chunk index objects
    except Exception:
        found = None
    try:
        if found is None:
            with open(path, "rb") as f:
                found = list(make_reader(f).iter_attachments())
        return [(a.name, a.media_type, bytes(a.data)) for a in found]
    except McapError as exc:
        raise InputError(f"cannot read attachments ({exc}): file not finished?", where=str(path)) from None


def _facts_summary(facts: SummaryFacts) -> dict:
    """session_summary's keys of a finished file, from mcap.summary.summary_of."""
    st = facts.statistics
    if st is None:
        raise ValueError("a summary without a Statistics record (session_summary scans such a file)")
    return {
        "finished": True,
        "messages": st.message_count,
        "chunks": st.chunk_count,
        "start_ns": st.message_start_time,
        "end_ns": st.message_end_time,
        "duration_s": (st.message_end_time - st.message_start_time) / NS_PER_S,
        "topics": {
            ch.topic: {
                "schema": facts.schemas[ch.schema_id].name if ch.schema_id in facts.schemas else "",
                "messages": st.channel_message_counts.get(cid, 0),
            }
            for cid, ch in facts.channels.items()
        },
        "metadata": dict(facts.metadata.get("session", {})),
        "attachments": [(a.name, a.media_type, a.data_size) for a in facts.attachment_indexes],
    }


def session_summary(path: str | Path) -> dict:
    """Fast facts from the MCAP summary section (no message is decoded).

    Keys: path, bytes, finished, messages, chunks, topics {topic: {schema, messages}}, start_ns,
    end_ns, duration_s (log-time span), metadata (the 'session' record), attachments [(name,
    media_type, bytes)]. An unfinished file is scanned instead (finished=False).
    """
    path = Path(path)
    check_file(path)
    out: dict = {"path": str(path), "bytes": path.stat().st_size}
    try:
        facts = summary_of(path)  # without the chunk indexes (~75 MB for a day of 0.5 s chunks)
    except Exception:
        facts = None
    if facts is not None and facts.statistics is not None:
        return out | _facts_summary(facts)
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
            metas = reader.iter_metadata() if summ.metadata_indexes else scanned_metadata(path)
            for md in metas:
                if md.name == "session":
                    out["metadata"] = dict(md.metadata)
        return out
    except (McapError, EOFError, ValueError, OSError) as exc:
        col = recover(path, None, exc)
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


# ---------------------------------------------------------------------------------------------
# the /imu columns converted group by group while the fast reader walks a file (module doc)

F8 = np.dtype(np.float64)
INT64_MAX = np.iinfo(np.int64).max


def first_indexes(first, n_per: np.ndarray, where: str) -> np.ndarray:
    """Each message's first_sample_index (a proto uint64: list or array) as int64; InputError (one
    line) if a message's samples would go beyond int64 (the sample indexes are int64)."""
    top = 0 if not len(first) else int(first.max() if isinstance(first, np.ndarray) else max(first))
    if top > INT64_MAX:  # (checked first: asarray of a list mixing int64 and uint64 values is float)
        raise InputError(f"first_sample_index {top} is beyond int64", where=where)
    a = np.asarray(first, dtype=np.int64)
    if np.any(a - 1 > INT64_MAX - n_per):  # a + n_per - 1 without overflow (a >= 0)
        raise InputError("IMU sample indexes beyond int64 (first_sample_index near 2**63)", where=where)
    return a


def lsb_scales(meta_kv: dict[str, str]) -> tuple[float | None, float | None]:
    """(accel LSB per g, gyro LSB per deg/s) of the 'session' metadata, None where absent/invalid/0
    (read_session checks and reports the metadata itself)."""

    def num(key: str) -> float | None:
        try:
            v = float(meta_kv.get(key) or 0.0)
        except ValueError:
            return None
        return v or None

    return num("accel_lsb_per_g"), num("gyro_lsb_per_dps")


def per_sample(first: np.ndarray, host_s: np.ndarray, n_per: np.ndarray, idx: np.ndarray, host: np.ndarray):
    """Fill idx and host for the samples of messages with first sample index ``first``, host time
    ``host_s`` (s) and ``n_per`` samples each: message k's samples get first[k] + 0, 1, ... and
    host_s[k] (as read_session computes them for the whole session)."""
    m = int(n_per[0]) if n_per.shape[0] else 0
    if m and np.all(n_per == m):  # equal reads (the usual case): written in place, no temporaries
        host.reshape(-1, m)[...] = host_s[:, None]
        np.add(first[:, None], np.arange(m, dtype=np.int64), out=idx.reshape(-1, m))
        return
    host[...] = np.repeat(host_s, n_per)
    offset = first - (np.cumsum(n_per) - n_per)  # sample_index[i] = offset[k] + i
    idx[...] = np.repeat(offset, n_per) + np.arange(idx.shape[0], dtype=np.int64)


class ImuAccumulator(BatchAccumulator):
    """ImuBatch parts joined as by BatchAccumulator, each part's samples converted as it is added
    (see module doc) on a worker thread while the next group is decoded here (numpy releases the
    GIL); ``finish()`` returns the batch without t_ns and with ``derived`` columns."""

    scalar_arrays = True  # first_sample_index, host_time_ns as arrays: no lists of 100 k ints per hour

    def __init__(self, message: str, accel_lsb: float | None, gyro_lsb: float | None) -> None:
        super().__init__(message)
        self._scalar_parts: dict[str, list] = {}
        self._lsb = {"accel_counts": accel_lsb, "gyro_counts": gyro_lsb, "temp_counts": TEMP_LSB_PER_DEGC}
        self._phys = {"accel_counts": "accel_g", "gyro_counts": "gyro_dps", "temp_counts": "temp_degC"}
        self._done: dict[str, int] = {}  # items of each stored field already handed to a conversion
        self._derived = BatchAccumulator(message)  # the float and index columns (worker thread only)
        self._pool: ThreadPoolExecutor | None = None
        self._pending: Future | None = None

    def _wait(self) -> None:
        """Wait for the conversion in flight (raises its exception)."""
        if self._pending is not None:
            pending, self._pending = self._pending, None
            pending.result()

    def _add_scalars(self, part: DecodedBatch) -> None:
        for name, v in part.scalars.items():
            self._scalar_parts.setdefault(name, []).append(v)

    def reserve(self, name: str, dtype: np.dtype, count: int, done: float) -> np.ndarray:
        store = self._store.get(name)
        if store is not None and self._used.get(name, 0) + count > store.shape[0]:
            self._wait()  # the store grows (may move): no conversion may be reading it
        return super().reserve(name, dtype, count, done)

    def add(self, part: DecodedBatch, done: float) -> None:
        super().add(part, done)
        views = {}
        for name in ("t_ns", *self._lsb):
            lo, hi = self._done.get(name, 0), self._used.get(name, 0)
            self._done[name] = hi
            if hi > lo and (name == "t_ns" or self._lsb[name] is not None):
                views[name] = self._store[name][lo:hi]
        self._wait()  # one conversion in flight: the previous group's
        if done >= 1.0:  # the file's last group: nothing left to decode meanwhile (core.threads)
            self._convert(views, part, done)
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(1)
        self._pending = self._pool.submit(self._convert, views, part, done)

    def _convert(self, views: dict[str, np.ndarray], part: DecodedBatch, done: float) -> None:
        """The conversions of one part (worker thread): views of its new stored items."""
        t = views.pop("t_ns", None)
        if t is not None:  # ns -> s in place: the float64 times overwrite the int64 ones (same size)
            np.divide(t, NS_PER_S, out=t.view(F8))
        for name, counts in views.items():
            out = self._derived.reserve(self._phys[name], F8, counts.shape[0], done)
            if name == "temp_counts":
                temp_counts_to_degC(counts, out=out)
            else:
                lsb = self._lsb[name]
                if lsb is None:
                    raise RuntimeError(f"{name} stored without its LSB in the session metadata")
                np.divide(counts, lsb, out=out)
        n_per = part.counts.get("t_ns")
        if n_per is not None and n_per.shape[0]:
            self._per_message(part, n_per, done)

    def _per_message(self, part: DecodedBatch, n_per: np.ndarray, done: float) -> None:
        """host_time_s and sample_index of the part's samples (per_sample)."""
        k = int(n_per.sum())
        per_sample(
            np.asarray(part.scalars["first_sample_index"], dtype=np.int64),
            np.asarray(part.scalars["host_time_ns"], dtype=np.int64) / NS_PER_S,
            n_per,
            self._derived.reserve("sample_index", np.dtype(np.int64), k, done),
            self._derived.reserve("host_time_s", F8, k, done),
        )

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool, self._pending = None, None

    def finish(self) -> DecodedBatch:
        self._wait()
        self.close()
        out = super().finish()
        for name, parts in self._scalar_parts.items():
            if all(isinstance(v, np.ndarray) for v in parts):
                out.scalars[name] = np.concatenate(parts)
            else:  # a part decoded with lists
                out.scalars[name] = [
                    x for v in parts for x in (v.tolist() if isinstance(v, np.ndarray) else v)
                ]
        derived = self._derived.finish().arrays
        derived["t_s"] = out.arrays.pop("t_ns").view(F8)
        out.derived = derived
        return out
