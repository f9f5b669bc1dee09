"""Gyro calibration of an MCAP session chunk by chunk: ``calibrate_gyro`` on a file without loading
it (memory: one chunk group plus O(windows + coarse blocks), the coarse blocks being the 10 ms
blocks of the moves and one per hold: bounded by the moves, not by the session length).

Three streaming passes over ``store.stream.iter_imu``:

1. locate: the sample index of every time the fit asks for (hold window edges, hold start/middle/end)
   is the count of samples before it, summed over blocks (``np.searchsorted`` on the whole time
   axis, block by block), plus the time of the first sample at or after each hold middle;
2. windows: the rate and temperature sums over the bias windows, from which the bias model
   (``gyro._bias_fit``) is fitted;
3. integrate: the trapezoid integrals of the rate (and temperature) over the 10 ms fine blocks
   between hold middles (a sample pair that straddles two groups is carried over), bias-corrected
   and reduced to their coarse blocks (phi, c) as each chunk group completes them
   (``_CoarseBlocks``: the prefix sum and any open coarse block carried between groups).

The fit itself is the one of ``calibrate.gyro`` on these sums, so the result equals
``calibrate_gyro(s.t_s, s.gyro_dps, s.poses, s.temp_degC)`` of ``s = read_session(path)`` up to the
rounding of sums split at block boundaries (~1e-16 relative).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from accellog.calibrate.gyro import (
    GyroCalibration,
    _bias_fit,
    _bias_window_times,
    _bias_windows,
    _fit_matrix,
    _holds,
    _known_poses,
    _pose_times,
)
from accellog.calibrate.gyro_rotation import _block_edges
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel
from accellog.store.stream import iter_imu


def stream_calibrate_gyro(
    path: str | Path,
    poses: Sequence[PoseLabel],
    *,
    model: str = "full",
    reference: str = "gravity",
    t_ref_degC: float = 25.0,
    window_s: float = 1.0,
    min_temp_span_degC: float = 2.0,
    trim_s: float = 0.2,
) -> GyroCalibration | None:
    """calibrate_gyro on the session in path (module doc); None when it records no gyro rate."""
    iv = _holds(poses)
    if iv.shape[0] == 0:
        raise InputError("no static holds: the gyro bias cannot be estimated")
    n_ref = len(poses) if reference == "gravity" else sum(p.q_sensor_to_world is not None for p in poses)
    known = _known_poses(poses, model, reference) if n_ref >= 2 else []
    win_times = _bias_window_times(iv, window_s, trim_s)
    pose_t = _pose_times(known) if known else (np.zeros(0),) * 3
    queries = np.concatenate([*win_times, *pose_t])
    found = _locate(path, queries)
    if found is None:
        return None
    counts, n_total, first_at = found
    cuts = np.cumsum([len(q) for q in win_times])[:-1] if win_times else []
    a, b = _bias_windows(np.split(counts[: sum(len(q) for q in win_times)], cuts) if win_times else [])
    k = len(known)
    pidx = np.clip(counts[counts.size - 3 * k :], 0, n_total - 1) if k else np.zeros(0, np.int64)
    mids, ends, starts = pidx[:k], pidx[k : 2 * k], pidx[2 * k :]
    t_mid = {int(i): float(v) for i, v in zip(mids, first_at[first_at.size - 3 * k :][:k], strict=True)}
    wins, has_temp = _window_pass(path, a, b)
    if a.size < 2:
        raise InputError(
            f"static holds give fewer than 2 windows of {window_s} s: gyro bias cannot be estimated"
        )
    n = (b - a).astype(float)
    means = wins[0].acc / n[:, None]
    temps = wins[1].acc / n if has_temp else np.full(a.size, np.nan)
    cal = _bias_fit(means, temps, has_temp, int(iv.shape[0]), t_ref_degC, window_s, min_temp_span_degC)
    if not k:
        return cal
    fine, coarse = _block_edges(t_mid, mids, ends, starts, 0.01)
    if fine[-1] == fine[0]:
        phi, c = np.zeros((0, 3)), np.zeros((0, 3))
    else:
        use_temp = has_temp and bool(np.any(cal.temp_bias_dps_per_degC != 0))
        blocks = _CoarseBlocks(fine, coarse, cal, use_temp)
        _integrate_pass(path, fine, blocks)
        phi, c = blocks.phi, blocks.c
    return _fit_matrix(phi, c, np.searchsorted(coarse, mids), known, cal, model, 0.05, reference)


def _locate(path, queries: np.ndarray):
    """(samples before each query time, samples in all, time of the first sample >= each query
    (the last sample's time when none is)); None when the session has no gyro rate."""
    counts = np.zeros(queries.size, np.int64)
    first_at = np.full(queries.size, np.nan)
    n_total, t_last = 0, np.nan
    for blk in iter_imu(path):
        if blk.gyro_dps is None:
            return None
        j = np.searchsorted(blk.t_s, queries)
        new = (j < blk.n) & np.isnan(first_at)
        first_at[new] = blk.t_s[j[new]]
        counts += j
        n_total += blk.n
        t_last = blk.t_s[-1]
    if n_total == 0:
        return None
    first_at[np.isnan(first_at)] = t_last
    return counts, n_total, first_at


class _Segments:
    """Sums over sorted, non-overlapping index ranges [lo_j, hi_j), each summed in one np.add.reduceat
    call over exactly its samples (bit for bit the whole-session sums): a range is summed once the
    buffer holds all of it; its start is carried to the next block until then. keep=False: only the
    sums of the ranges completed by the last add are held (self.new, ranges self.done), not all."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, width: int, keep: bool = True) -> None:
        self.lo, self.hi, self.k = np.asarray(lo, np.int64), np.asarray(hi, np.int64), 0
        shape = (self.lo.size if keep else 0, width) if width > 1 else (self.lo.size if keep else 0,)
        self.acc, self.keep = np.zeros(shape), keep
        self.new, self.done = self.acc[:0], (0, 0)

    def add(self, x: np.ndarray, x0: int) -> int:
        """Sum the ranges complete within x (global indices x0 ..); returns the first index still needed."""
        end = x0 + x.shape[0]
        m = self.k + int(np.searchsorted(self.hi[self.k :], end, side="right"))
        self.new, self.done = self.acc[:0], (self.k, m)
        if m > self.k:
            lo, hi = self.lo[self.k : m] - x0, self.hi[self.k : m] - x0
            edges = np.stack([lo, hi], axis=1).ravel()
            if edges[-1] >= x.shape[0]:
                edges = edges[:-1]
            self.new = np.add.reduceat(x, edges, axis=0)[::2]
            if self.keep:
                self.acc[self.k : m] = self.new
            self.k = m
        return int(self.lo[m]) if m < self.lo.size else end


class _CoarseBlocks:
    """gyro._increments fed the fine blocks in order, a batch at a time: each batch is reduced to
    its coarse blocks at once (memory O(coarse blocks + one batch), not O(fine blocks)).

    Carried between batches: the running sum p of all earlier fine blocks (the prefix p_excl of the
    next one) and the partial (phi, sum p_excl x b) and p_excl at the start of a coarse block still
    open, prepended as a row to the next batch's sums, so every sum is formed in the same order as
    the whole-array cumsum/reduceat of gyro._increments."""

    def __init__(self, fine: np.ndarray, coarse: np.ndarray, base: GyroCalibration, use_temp: bool):
        self.at = np.searchsorted(fine, coarse[:-1])  # first fine block of each coarse block
        self.end = np.append(self.at[1:], fine.size - 1)  # one past its last fine block
        self.phi, self.c = np.zeros((self.at.size, 3)), np.zeros((self.at.size, 3))
        self.base, self.use_temp = base, use_temp
        self.p, self.k, self.open = np.zeros(3), 0, None  # open: (phi, cross sum, p at start)

    def add(self, w_int: np.ndarray, temp_int: np.ndarray | None, span: np.ndarray) -> None:
        """The next fine blocks: rate integrals (deg), temperature integrals (degC s), durations (s)."""
        base = self.base
        b = w_int - np.outer(span, base.bias_dps)
        if self.use_temp:
            b -= np.outer(temp_int - base.t_ref_degC * span, base.temp_bias_dps_per_degC)
        b = np.deg2rad(b)
        if b.shape[0] == 0:
            return
        k0, k1 = self.k, self.k + b.shape[0]
        ps = np.cumsum(np.concatenate([self.p[None], b]), axis=0)
        p_excl, self.p, self.k = ps[:-1], ps[-1], k1
        cr = np.cross(p_excl, b)
        qs, qe = np.searchsorted(self.at, [k0, k1])
        offs, q = self.at[qs:qe] - k0, np.arange(qs, qe)
        p_at = p_excl[offs]
        if self.open is not None:
            b, cr = np.concatenate([self.open[0][None], b]), np.concatenate([self.open[1][None], cr])
            offs, q = np.concatenate([[0], offs + 1]), np.concatenate([[qs - 1], q])
            p_at = np.concatenate([self.open[2][None], p_at])
        phi, crs = np.add.reduceat(b, offs, axis=0), np.add.reduceat(cr, offs, axis=0)
        self.open = None
        if self.end[q[-1]] > k1:  # the last coarse block goes on in the next batch
            self.open = (phi[-1], crs[-1], p_at[-1])
            phi, crs, p_at, q = phi[:-1], crs[:-1], p_at[:-1], q[:-1]
        self.phi[q] = phi
        self.c[q] = 0.5 * (crs - np.cross(p_at, phi))


def _window_pass(path, a: np.ndarray, b: np.ndarray):
    """Rate and temperature sums over the windows [a, b) (sample indices); returns (sums, has_temp)."""
    wins = (_Segments(a, b, 3), _Segments(a, b, 1))
    buf, buf0, has_temp = None, 0, True  # samples (w, temp) kept from global index buf0
    for blk in iter_imu(path):
        has_temp = has_temp and blk.temp_degC is not None
        new = (np.asarray(blk.gyro_dps, float), np.asarray(blk.temp_degC, float) if has_temp else None)
        buf = new if buf is None else tuple(_cat(o, n) for o, n in zip(buf, new, strict=True))
        need = wins[0].add(buf[0], buf0)
        if has_temp:
            wins[1].add(buf[1], buf0)
        keep = min(need, buf0 + buf[0].shape[0]) - buf0
        buf, buf0 = tuple(None if x is None else x[keep:] for x in buf), buf0 + keep
    return wins, has_temp


def _cat(old, new):
    return None if old is None or new is None else np.concatenate([old, new])


def _integrate_pass(path, fine: np.ndarray, blocks: _CoarseBlocks) -> None:
    """Trapezoid integrals of the rate (and temperature) over the fine blocks, fed to blocks as
    each chunk group completes them (a sample pair that straddles two groups is carried over)."""
    pairs = (_Segments(fine[:-1], fine[1:], 3, keep=False), _Segments(fine[:-1], fine[1:], 1, keep=False))
    buf, buf0 = None, 0  # samples (t, w, temp) kept from global index buf0
    for blk in iter_imu(path):
        temp = np.asarray(blk.temp_degC, float) if blocks.use_temp else np.zeros(blk.n)
        new = (blk.t_s, np.asarray(blk.gyro_dps, float), temp)
        buf = new if buf is None else tuple(np.concatenate([o, n]) for o, n in zip(buf, new, strict=True))
        t, w, temp = buf
        need = buf0  # one sample: keep it for the pair it starts
        if t.size > 1:
            dt = np.diff(t)
            inc = w[:-1] + w[1:]
            inc *= (0.5 * dt)[:, None]
            need = pairs[0].add(inc, buf0)
            temp_int = None
            if blocks.use_temp:
                ti = temp[:-1] + temp[1:]
                ti *= 0.5 * dt
                pairs[1].add(ti, buf0)
                temp_int = pairs[1].new
            k0, m = pairs[0].done
            span = t[fine[k0 + 1 : m + 1] - buf0] - t[fine[k0:m] - buf0]
            blocks.add(pairs[0].new, temp_int, span)
        keep = min(need, buf0 + t.size) - buf0  # a range not yet begun: keep nothing
        buf, buf0 = tuple(x[keep:] for x in buf), buf0 + keep
