"""Chunk-by-chunk reading: an accellog MCAP session as a sequence of IMU sample blocks, memory
bounded by one block (~4 MiB of decompressed records, ~50 k samples) whatever the session length.

    for block in iter_imu("long.mcap"):
        acc.add(block.accel_g)          # accumulate window sums, integrals, Allan sums, ...

The blocks are exactly the samples ``read_session`` returns, in file order, split at chunk-group
boundaries (same conversions: counts / LSB, temperature counts / 333.87 + 21 degC). Damaged chunks
are skipped and named as in ``read_session`` (a ``DataIntegrityWarning`` each). Files the fast
walker does not take (unfinished, non-canonical) are read by ``read_session`` and the rest of the
samples handed out in one block (memory then is that of ``read_session``). ``read_session`` stays
for notebooks and whole-session work; ``read_labels`` gives the poses and events (they are stored
at the end of a recording, so a stage that needs them reads them first: one decompression pass).
"""

from __future__ import annotations

import contextlib
import copy
import mmap
import warnings
from collections.abc import Generator, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np

from accellog.core.errors import DataIntegrityWarning, InputError
from accellog.core.heap import HeapTrim
from accellog.core.session import Event, PoseLabel, SessionMeta
from accellog.core.timeseries import LineFit
from accellog.core.units import temp_counts_to_degC
from accellog.store.collect import check_file
from accellog.store.layout import NS_PER_S, TOPIC_EVENTS, TOPIC_IMU, TOPIC_POSES, metadata_to_meta
from accellog.store.mcap.batch_decode import DecodedBatch
from accellog.store.reader import first_indexes, per_sample


@dataclass
class ImuBlock:
    """Consecutive IMU samples of a session (arrays as in Session; None where not recorded)."""

    meta: SessionMeta
    t_s: np.ndarray
    sample_index: np.ndarray
    accel_g: np.ndarray
    gyro_dps: np.ndarray | None
    temp_degC: np.ndarray | None
    host_time_s: np.ndarray | None = None
    """Host read time of every sample (s; 0 where the recorder stored none)."""
    accel_counts: np.ndarray | None = None
    gyro_counts: np.ndarray | None = None
    """Raw counts as stored (None where the session stores physical units only; cut blocks drop them)."""

    @property
    def n(self) -> int:
        return int(self.t_s.shape[0])


_B = TypeVar("_B")


@contextlib.contextmanager
def closed_after(blocks: Iterable[_B]) -> Iterator[Iterable[_B]]:
    """blocks, closed on leaving the with-block, also on an error (when it has close()). A reader
    left to the garbage collector is closed on whatever thread the collection runs, and its close
    joins the decompression threads: a collection inside Thread.start deadlocked there (seen in CI)."""
    try:
        yield blocks
    finally:
        close = getattr(blocks, "close", None)
        if close is not None:
            close()


def iter_imu(path: str | Path) -> Generator[ImuBlock, None, None]:
    """The session's IMU samples block by block (see module doc); raises InputError as read_session."""
    from accellog.store.mcap import fastread

    path = Path(path)
    where = str(path)
    check_file(path)
    n_done = [0]
    try:
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            walk = fastread.fast_walk(data, [TOPIC_IMU], stream=TOPIC_IMU)
            try:
                yield from _walked(walk, where, n_done)
            finally:
                walk.close()  # release its views of the mapped file before the map closes
        return
    except fastread.Refuse as exc:
        raise InputError(str(exc), where=where) from None
    except InputError:
        raise
    except Exception:  # the fast walker declined: read the whole session, hand out the rest
        pass
    from accellog.store.reader import read_session

    s = read_session(path)
    rest = slice(n_done[0], None)
    yield ImuBlock(
        s.meta,
        s.t_s[rest],
        s.sample_index[rest],
        s.accel_g[rest],
        None if s.gyro_dps is None else s.gyro_dps[rest],
        None if s.temp_degC is None else s.temp_degC[rest],
        None if s.host_time_s is None else s.host_time_s[rest],
        None if s.accel_counts is None else s.accel_counts[rest],
        None if s.gyro_counts is None else s.gyro_counts[rest],
    )


def _walked(walk, where: str, n_done: list[int]) -> Iterator[ImuBlock]:
    """The blocks of a fast_walk stream (n_done[0] counts the samples handed out)."""
    meta = None
    trim = HeapTrim()
    while True:
        trim()  # the consumer is done with the previous block
        try:
            kv, dec = next(walk)
        except StopIteration as end:
            for d in end.value.damaged:
                warnings.warn(f"{where}: {d.describe()}", DataIntegrityWarning, stacklevel=3)
            return
        if meta is None:
            meta = metadata_to_meta(kv, where) if kv else SessionMeta(source="unknown")
        if dec is not None and dec.n_messages:
            block = _block(dec, meta, where)
            n_done[0] += block.n
            yield block


def _block(dec: DecodedBatch, meta: SessionMeta, where: str) -> ImuBlock:
    """One group's decoded ImuBatch messages as arrays in the units read_session gives."""
    arrays, scalars, counts = dec.result()
    n_per = counts["t_ns"]
    n = int(n_per.sum())
    first = first_indexes(scalars["first_sample_index"], n_per, where)
    full = n_per > 0  # samples out of order <=> a message starts below the previous one's last index
    if np.any(first[full][1:] < (first + n_per - 1)[full][:-1]):
        raise InputError("IMU batches out of order: read it whole with read_session", where=where)
    sample_index, host_s = np.empty(n, np.int64), np.empty(n)
    per_sample(
        first, np.asarray(scalars["host_time_ns"], dtype=np.int64) / NS_PER_S, n_per, sample_index, host_s
    )

    def vec(name: str, width: int) -> np.ndarray | None:
        a = arrays[name]
        if a.size == 0:
            return None
        if a.size != n * width:
            raise InputError(f"{name} has {a.size} values for {n} samples (mixed batches)", where=where)
        return a.reshape(n, width) if width > 1 else a

    accel_g = vec("accel_g", 3)
    if accel_g is None:
        ac = vec("accel_counts", 3)
        if ac is None or not meta.accel_lsb_per_g:
            raise InputError("IMU batches carry no usable accelerometer data", where=where)
        accel_g = ac / meta.accel_lsb_per_g
    gyro_dps = vec("gyro_dps", 3)
    gc = vec("gyro_counts", 3)
    if gyro_dps is None and gc is not None and meta.gyro_lsb_per_dps:
        gyro_dps = gc / meta.gyro_lsb_per_dps
    temp_degC = vec("temp_degC", 1)
    tc = vec("temp_counts", 1)
    if temp_degC is None and tc is not None:
        temp_degC = temp_counts_to_degC(tc)
    return ImuBlock(meta, arrays["t_ns"] / NS_PER_S, sample_index, accel_g, gyro_dps, temp_degC, host_s,
                    vec("accel_counts", 3), gc)  # fmt: skip


def read_host_clock(path: str | Path) -> LineFit | None:
    """The host clock of a session: host - sensor time (s) against sensor time at the last sample
    of every run of equal host times (one point per read batch; the points
    calibrate.diagnosis.clock_from_host_time fits), streamed in bounded memory; None when the
    session stores no host time (as read_session's None)."""
    clock = HostClock()
    with closed_after(iter_imu(path)) as blocks:
        for b in blocks:
            clock.add(b)
    return clock.result()


class HostClock:
    """read_host_clock fed block by block (add), e.g. from another pass over the file; result():
    the line fit of its points (core.timeseries.LineFit), or None without host time."""

    def __init__(self) -> None:
        self.line = LineFit()
        self.any_host, self.n, self.missing = False, 0, False
        self.carry: tuple | None = None  # (t, host) of the previous block's last sample: its run may go on

    @classmethod
    def for_pass(cls, _src: object = None) -> HostClock:
        """A new HostClock for one pass (calibrate.observe.segment.observe_riding's rider of a Source)."""
        return cls()

    @classmethod
    def of(cls, t_s: np.ndarray, host_s: np.ndarray) -> LineFit | None:
        """result() of a session's whole sample and host times (s) in memory."""
        clock = cls()
        clock.add_times(np.asarray(t_s, float), np.asarray(host_s, float))
        return clock.result()

    def add(self, b: ImuBlock) -> None:
        if b.host_time_s is None or self.missing:
            self.n += b.n
            self.missing = True
            return
        self.add_times(b.t_s, b.host_time_s)

    def add_times(self, ts: np.ndarray, th: np.ndarray) -> None:
        """One block's sensor and host times (s)."""
        self.n += ts.shape[0]
        if ts.shape[0] == 0:
            return
        self.any_host = self.any_host or bool(np.any(th != 0))
        if self.carry is not None and th[0] != self.carry[1]:
            self.line.add([self.carry[0]], [self.carry[1] - self.carry[0]])
        last = np.flatnonzero(np.diff(th) != 0)  # run ends inside the block (not its last sample)
        self.line.add(ts[last], th[last] - ts[last])
        self.carry = (float(ts[-1]), float(th[-1]))

    def result(self) -> LineFit | None:
        if self.missing or not self.any_host or self.n <= 2 or self.carry is None:
            return None
        line = copy.deepcopy(self.line)  # pending points are not shared
        line.add([self.carry[0]], [self.carry[1] - self.carry[0]])
        return line


def read_labels(path: str | Path) -> tuple[SessionMeta, list[PoseLabel], list[Event]]:
    """Metadata, pose labels and events of a session without its samples (bounded memory)."""
    from accellog.store.reader import collect_session, read_events, read_poses

    path = Path(path)
    col = collect_session(path, [TOPIC_POSES, TOPIC_EVENTS])
    meta = metadata_to_meta(col.metadata, str(path)) if col.metadata else SessionMeta(source="unknown")
    return meta, read_poses(col.decoders.get(TOPIC_POSES)), read_events(col.decoders.get(TOPIC_EVENTS))
