"""The samples a replay reads: a whole Session in memory, or an MCAP file streamed block by block.

``open_replay_input`` streams a finished accellog MCAP file (``store.stream.iter_imu``: memory of one
chunk group, whatever the session length) after the same time-stamp checks as ``load_input``
(``calibrate.stream_segment.stream_check_timestamps``, one extra decompression pass). It reads the
file whole (``store.reader.read_session``) when the file is damaged or unfinished (the reader says
what it kept), when it is not MCAP (CSV, ROS 2 bag: imported whole), or when a calibration needs a
driver that is not local in time (``dtemp_degC_per_s``: a centred 5 s slope over the whole series).

``batches`` cuts the blocks at the replay's batch edges t0 + k * batch_s (s); every other driver
(t_s, temp_degC, t_in_pose_s) is computed per batch with ``calibrate.calibration.session_drivers``,
giving the same values as on the whole session.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from accellog.core.errors import DataIntegrityWarning, InputError
from accellog.core.session import Event, PoseLabel, Session, SessionMeta
from accellog.store.stream import ImuBlock, closed_after

WHOLE_SESSION_DRIVERS = frozenset({"dtemp_degC_per_s"})
"""Drivers computed over the whole series (not per batch): a calibration using one is replayed from
the whole session in memory."""


@dataclass
class ReplayInput:
    """A session to replay: labels up front, samples from ``blocks()``. ``n`` and ``span_s`` are
    exact for a Session and estimated from the MCAP summary for a streamed file (they size display
    buckets and strides only)."""

    where: str
    meta: SessionMeta
    poses: list[PoseLabel]
    events: list[Event]
    n: int
    t0_s: float
    span_s: float
    session: Session | None = None
    path: Path | None = None
    _drivers: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def streamed(self) -> bool:
        return self.session is None

    def blocks(self) -> Iterator[ImuBlock]:
        """The samples in file order (one block for a Session)."""
        s = self.session
        if s is not None:
            yield ImuBlock(s.meta, s.t_s, s.sample_index, s.accel_g, s.gyro_dps, s.temp_degC)
            return
        from accellog.store.stream import iter_imu

        yield from iter_imu(self.path)

    def mean_accel_g(self) -> np.ndarray:
        """Mean reading (g; NaNs ignored), one pass over a streamed file."""
        if self.session is not None:
            return np.nanmean(self.session.accel_g, axis=0)
        tot, cnt = np.zeros(3), np.zeros(3)
        with closed_after(self.blocks()) as blocks:
            for b in blocks:
                ok = np.isfinite(b.accel_g)
                tot += np.where(ok, b.accel_g, 0.0).sum(axis=0)
                cnt += ok.sum(axis=0)
        return tot / np.maximum(cnt, 1)

    def drivers(self, b: ImuBlock, i0: int, needed: Sequence[str]) -> dict[str, np.ndarray]:
        """The needed driver signals of batch b (whose first sample is sample i0 of the replay)."""
        from accellog.calibrate.model.session_drivers import session_drivers

        if not needed:
            return {}
        if self.session is not None:  # computed once on the whole session, then sliced
            missing = [k for k in needed if k not in self._drivers]
            if missing:
                self._drivers.update(session_drivers(self.session, missing))
            return {k: v[i0 : i0 + b.n] for k, v in self._drivers.items() if k in needed}
        view = SimpleNamespace(t_s=b.t_s, temp_degC=b.temp_degC, poses=self.poses)
        return session_drivers(view, list(needed))  # every driver here is local in time


def open_replay_input(
    session: Session | str | os.PathLike, needed_drivers: Sequence[str] = ()
) -> ReplayInput:
    """A ReplayInput for a Session, or for a session file (streamed when it can be; module doc)."""
    if isinstance(session, Session):
        return _whole(session, session.path or session.meta.source)
    p = Path(session)
    if not p.is_file():
        raise InputError("no such session file", where=str(p))
    if not WHOLE_SESSION_DRIVERS & set(needed_drivers):
        streamed = _streamed(p)
        if streamed is not None:
            return streamed
    from accellog.flows.stages import load_input

    s = load_input(p)
    if not isinstance(s, Session):
        raise InputError("replay needs a recorded session with samples, not a pose table", where=str(p))
    return _whole(s, str(p))


def _whole(s: Session, where) -> ReplayInput:
    if s.n < 2:
        raise InputError(f"session has {s.n} samples: nothing to replay", where=where)
    t0 = float(s.t_s[0])
    return ReplayInput(str(where), s.meta, list(s.poses), list(s.events), s.n, t0, float(s.t_s[-1]) - t0, s)


def _streamed(p: Path) -> ReplayInput | None:
    """A streamed ReplayInput, or None when the file takes the whole-session reader."""
    from accellog.calibrate.observe.stream_segment import stream_check_timestamps
    from accellog.flows.stream_input import can_stream
    from accellog.store.stream import iter_imu, read_labels

    if not can_stream(p):
        return None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        stream_check_timestamps(p)  # load_input's refusals (duplicated, decreasing, < 2 samples)
    if any(issubclass(w.category, DataIntegrityWarning) for w in caught):
        return None  # damaged chunks: read_session names what it skips
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    meta, poses, events = read_labels(p)
    blocks = iter_imu(p)
    try:
        first = next(blocks)
    finally:
        blocks.close()
    t0 = float(first.t_s[0])
    from accellog.store.reader import session_summary

    summ = session_summary(p)
    span = max(float(summ.get("duration_s") or 0.0), float(first.t_s[-1]) - t0)
    rate = float(meta.sample_rate_hz or 0.0) or (first.n - 1) / max(float(first.t_s[-1]) - t0, 1e-9)
    return ReplayInput(str(p), meta, poses, events, round(span * rate) + 1, t0, span, None, p)


def batches(blocks: Iterator[ImuBlock], t0_s: float, batch_s: float) -> Iterator[ImuBlock]:
    """The blocks cut where floor((t - t0) / batch_s) changes: batch k holds t0 + k batch_s <= t <
    t0 + (k+1) batch_s (s)."""
    for b in blocks:
        k = np.floor((b.t_s - t0_s) / batch_s)
        cuts = np.r_[0, np.flatnonzero(k[1:] != k[:-1]) + 1, b.n]
        for i0, i1 in zip(cuts[:-1].tolist(), cuts[1:].tolist(), strict=True):
            yield _slice(b, slice(i0, i1))


def _slice(b: ImuBlock, sl: slice) -> ImuBlock:
    def cut(a):
        return None if a is None else a[sl]

    return ImuBlock(b.meta, b.t_s[sl], b.sample_index[sl], b.accel_g[sl], cut(b.gyro_dps), cut(b.temp_degC))
