"""A static session as consecutive sample blocks: the one input of ``evaluate``, ``drift`` and
``integrate``.

An MCAP file is read chunk by chunk (``store.stream.iter_imu``: memory bounded by one chunk group,
whatever the session length); a Session already in memory (CSV, a damaged file read whole, a
caller's own) is one block. Every pass (``Blocks.read``) yields the blocks again; ``cut_blocks``
applies until_s / max_samples and ``checked_blocks`` the checks every stage makes (finite reading,
finite and strictly increasing time stamps across blocks: one InputError line).

The file's time-stamp check (``stream_segment.TimestampCheck``) rides along the first pass when
asked (``Blocks.checked``): the reader's own refusal first, then the check's error, then the pass's
own InputError, as when the check ran in a pass of its own; a file with damaged chunks gives None
(DataIntegrityWarning: the caller reads it whole, and the whole-session reader says what it skips).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.observe.stream_segment import TimestampCheck
from accellog.core.errors import DataIntegrityWarning, InputError
from accellog.core.session import PoseLabel, Session, SessionMeta
from accellog.store.stream import ImuBlock, closed_after, iter_imu

T = TypeVar("T")

WHOLE_SESSION_DRIVERS = ("dtemp_degC_per_s",)
"""Drivers computed over a centred span of samples (a 5 s slope needs samples on both sides of a
block boundary): a model reading them is evaluated on the whole session as one block."""


class Blocks:
    """The blocks of one static session (module doc): ``read()`` starts a pass over them."""

    def __init__(
        self,
        meta: SessionMeta,
        poses: list[PoseLabel],
        where: str,
        read: Callable[[], Iterator[ImuBlock]],
        *,
        in_memory: bool = False,
        check_times: bool = False,
    ) -> None:
        self.meta, self.poses, self.where = meta, poses, where
        self._read = read
        self.in_memory = in_memory
        """One block in memory: its series are kept for plots (Evaluation.t_s ...)."""
        self.check_times = check_times
        self._first: _Source | None = None  # the checked first pass (checked)

    def read(self) -> Iterator[ImuBlock]:
        """A new pass over the blocks (the checked one first, inside checked)."""
        first, self._first = self._first, None
        return first if first is not None else self._read()

    def can_take(self, cals: Sequence[Calibration]) -> bool:
        """False for a file and a model reading a driver that is not pointwise (WHOLE_SESSION_DRIVERS)."""
        return self.in_memory or not any(
            d in c.model.required_drivers for c in cals for d in WHOLE_SESSION_DRIVERS
        )

    def checked(self, run: Callable[[], T]) -> T | None:
        """run() with the file's time-stamp check made in its first pass when check_times (module
        doc; None: damaged chunks), else run()."""
        if not self.check_times:
            return run()
        check = TimestampCheck()
        src = self._first = _Source(self._read(), check)
        out, err = None, None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                out = run()
            except InputError as e:
                err = e
            finally:
                self._first = None
            if src.failed is not None:  # the reader refused the file: its error, as the check pass raised it
                raise src.failed
            src.drain()
        if any(issubclass(w.category, DataIntegrityWarning) for w in caught):
            return None
        for w in caught:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        check.finish(self.where)
        if err is not None:
            raise err
        return out


def session_blocks(session: Session) -> Blocks:
    """A Session in memory as one block (time stamps checked when it was loaded)."""
    s = session
    block = ImuBlock(s.meta, s.t_s, s.sample_index, s.accel_g, s.gyro_dps, s.temp_degC)
    where = s.path or s.meta.source
    return Blocks(s.meta, s.poses, where, lambda: iter([block]), in_memory=True)


def file_blocks(
    path: str | Path, meta: SessionMeta, poses: list[PoseLabel], *, check_times: bool = True
) -> Blocks:
    """An MCAP file chunk by chunk (labels read before: stream_input.open_streamed)."""
    return Blocks(meta, poses, str(path), lambda: iter_imu(path), check_times=check_times)


class _Source:
    """A pass's blocks, each block's stamps fed to a TimestampCheck on the way; drain() feeds the
    blocks the pass did not need (after a cut or an error)."""

    def __init__(self, blocks: Iterator[ImuBlock], check: TimestampCheck) -> None:
        self.blocks = blocks
        self.check = check
        self.failed: Exception | None = None  # the reader's own refusal of the file

    def __iter__(self) -> Iterator[ImuBlock]:
        while True:
            try:
                b = next(self.blocks)
            except StopIteration:
                return
            except Exception as e:
                self.failed = e
                raise
            self.check.add(b.t_s)
            yield b

    def close(self) -> None:
        """Nothing: drain() reads the rest for the check, then closes the reader."""

    def drain(self) -> None:
        for _ in self:
            pass
        close = getattr(self.blocks, "close", None)
        if close is not None:
            close()


def cut_blocks(src: Blocks, until_s: float | None, max_samples: int | None) -> Iterator[ImuBlock]:
    """The blocks of one pass with t <= until_s and at most max_samples samples."""
    n = 0
    blocks = src.read()
    with closed_after(blocks):
        for b in blocks:
            k = b.n
            if until_s is not None:
                k = min(k, int(np.searchsorted(b.t_s, until_s, side="right")))
            if max_samples is not None:
                k = min(k, int(max_samples) - n)
            if k > 0:
                n += k
                yield b if k == b.n else ImuBlock(
                    b.meta, b.t_s[:k], b.sample_index[:k], b.accel_g[:k],
                    None if b.gyro_dps is None else b.gyro_dps[:k],
                    None if b.temp_degC is None else b.temp_degC[:k],
                )  # fmt: skip
            if k < b.n:
                return


def checked_blocks(src: Blocks, until_s: float | None, max_samples: int | None) -> Iterator[tuple]:
    """(ImuBlock, the block as a Session) of every cut block whose accel is finite and whose
    stamps are finite and strictly increasing across blocks (else one InputError line)."""
    n, t_prev = 0, np.nan
    for b in cut_blocks(src, until_s, max_samples):
        if not np.isfinite(b.accel_g).all():
            i = int(np.argmax(~np.isfinite(b.accel_g).all(axis=1)))
            raise InputError(f"accel is NaN/inf at t = {b.t_s[i]:.3f} s", where=src.where)
        _check_step(b, n, t_prev, src.where)
        t_prev = float(b.t_s[-1])
        n += b.n
        yield b, Session(meta=src.meta, t_s=b.t_s, sample_index=b.sample_index, accel_g=b.accel_g,
                         temp_degC=b.temp_degC, poses=src.poses, path=src.where)  # fmt: skip


def _check_step(b: ImuBlock, n_before: int, t_prev: float, where: str) -> None:
    """core.timeseries.check_time across blocks: finite, strictly increasing stamps (same message)."""
    t = b.t_s
    if not np.all(np.isfinite(t)):
        raise InputError("timestamps contain NaN or infinite values", where=where)
    tt = t if n_before == 0 else np.concatenate([[t_prev], t])
    bad = np.diff(tt) <= 0
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(
            f"timestamps not strictly increasing at sample {n_before - (n_before > 0) + i + 1} "
            f"(t = {tt[i + 1]:.6f} s): they must increase",
            where=where,
        )


def mean_reading(src: Blocks) -> np.ndarray:
    """nanmean of every accel sample of the session (g), uncut: a pass of its own."""
    s = np.zeros(3)
    c = np.zeros(3)
    for b in src.read():
        ok = np.isfinite(b.accel_g)
        s += np.where(ok, b.accel_g, 0.0).sum(axis=0)
        c += ok.sum(axis=0)
    return s / np.maximum(c, 1)
