"""The per-block steps of the static stages (``evaluate``, ``drift``, ``integrate``) over a
``store.source.Source``: ``cut_blocks`` applies until_s / max_samples, ``checked_blocks`` the checks
every stage makes (finite reading, finite and strictly increasing time stamps across blocks: one
InputError line), ``mean_reading`` a pass of its own for the mean, ``first_mean`` the mean of the
first block alone (a guess of it without a pass: a stage checks it against the mean of its own pass).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.store.source import Source
from accellog.store.stream import ImuBlock, closed_after, iter_imu


def cut_blocks(src: Source, until_s: float | None, max_samples: int | None) -> Iterator[ImuBlock]:
    """The blocks of one pass with t <= until_s and at most max_samples samples."""
    n = 0
    blocks = src.blocks()
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


def checked_blocks(src: Source, until_s: float | None, max_samples: int | None) -> Iterator[tuple]:
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


def mean_reading(src: Source) -> np.ndarray:
    """nanmean of every accel sample of the session (g), uncut: a pass of its own."""
    s = np.zeros(3)
    c = np.zeros(3)
    with closed_after(src.blocks()) as blocks:
        for b in blocks:
            bs, bc = nan_sums(b.accel_g)
            s += bs
            c += bc
    return s / np.maximum(c, 1)


def nan_sums(accel_g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sum, count) per axis of the finite readings (g): mean_reading's sums of one block."""
    ok = np.isfinite(accel_g)
    return np.where(ok, accel_g, 0.0).sum(axis=0), ok.sum(axis=0)


def first_mean(src: Source) -> np.ndarray:
    """nanmean of the accel of the source's first block (g): mean_reading of a session in memory,
    of a file's first chunk group otherwise (no pass over the file); zeros without a sample."""
    if src.in_memory:
        return mean_reading(src)
    assert src.path is not None  # a streamed source reads a file
    blocks = iter_imu(src.path)
    with closed_after(blocks):
        b = next(blocks, None)
    if b is None:
        return np.zeros(3)
    s, c = nan_sums(b.accel_g)
    return s / np.maximum(c, 1)
