"""The layout of accellog MCAP files: topics, message types and session metadata.

| topic | schema | content |
|---|---|---|
| /imu | ImuBatch | accel/gyro/temp counts (or values) with per-sample sensor time t_ns |
| /mag | MagBatch | magnetometer counts, ST2, ASA factors |
| /poses | PoseLabel | labelled static holds |
| /events | Event | gaps, overflows, notes, ... |
| /truth | TruthBatch | ground truth of simulated sessions |
| /derived/... | Vector3Batch | derived channels (e.g. calibrated acceleration) |

Schemas in accellog.store.schema (protobuf package accellog.v1, one message per FIFO read). Every
``SessionMeta`` field is stored as the MCAP metadata record 'session' (strings; extra keys as
'extra.<key>', plus 'schema_version'). Message log_time = meta.start_time_unix_ns + sensor t_ns of
the first sample; publish_time = start_time_unix_ns + host_time_ns.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import SessionMeta
from accellog.core.version import __version__
from accellog.store.schema import SCHEMA_VERSION

NS_PER_S = 1_000_000_000
MCAP_MAGIC = b"\x89MCAP0\r\n"

TOPIC_IMU = "/imu"
TOPIC_MAG = "/mag"
TOPIC_POSES = "/poses"
TOPIC_EVENTS = "/events"
TOPIC_TRUTH = "/truth"
DERIVED_PREFIX = "/derived/"

TOPIC_MESSAGE = {
    TOPIC_IMU: "ImuBatch",
    TOPIC_MAG: "MagBatch",
    TOPIC_POSES: "PoseLabel",
    TOPIC_EVENTS: "Event",
    TOPIC_TRUTH: "TruthBatch",
}
# ---------------------------------------------------------------------------------------------
# session metadata <-> MCAP metadata record (strings)


def meta_to_metadata(meta: SessionMeta) -> dict[str, str]:
    """MCAP metadata 'session': every SessionMeta field as a string (None -> ''), extra as 'extra.<k>'."""
    out = {"schema_version": SCHEMA_VERSION, "accellog_version": __version__}
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


def to_ns(t_s: float) -> int:
    return round(t_s * NS_PER_S)


MAX_TIME_S = 9.2e9
"""Largest |t| (s) that int64 nanoseconds hold (2^63 ns = 9.22e9 s, about 292 years)."""


def to_ns_array(t_s: np.ndarray, where: str | None = None) -> np.ndarray:
    """Times (s) as int64 ns; InputError for a time that does not fit (NaN, inf, |t| >= MAX_TIME_S),
    which the conversion would silently wrap."""
    t = np.asarray(t_s, dtype=np.float64)
    bad = ~(np.abs(t) < MAX_TIME_S)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(
            f"time stamp {t[k]:g} s at sample {k} does not fit int64 nanoseconds (|t| < {MAX_TIME_S:g} s): "
            "a corrupt time value?",
            where=where,
        )
    return np.round(t * NS_PER_S).astype(np.int64)
