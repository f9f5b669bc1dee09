"""Gyro calibration of an MCAP session chunk by chunk: ``calibrate_gyro`` on a file without loading
it (memory: one block plus O(windows + 10 ms blocks between the first and last hold middle)).

Two streaming passes over ``store.stream.iter_imu``:

1. locate: the sample index of every time the fit asks for (hold window edges, hold start/middle/end)
   is the count of samples before it, summed over blocks (``np.searchsorted`` on the whole time
   axis, block by block), plus the time of the first sample at or after each hold middle;
2. sum: the rate and temperature sums over the bias windows, and the trapezoid integrals of the
   rate and temperature over the 10 ms blocks between hold middles (a sample pair that straddles
   two blocks is carried over), with the times at the block edges.

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
from accellog.calibrate.gyro_rotation import _block_edges, _increments
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
    fine = coarse = None
    if k:
        fine, coarse = _block_edges(t_mid, mids, ends, starts, 0.01)
    wins, pairs, t_fine, has_temp = _sum_pass(path, a, b, fine)
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
    temp_int = pairs[1].acc if has_temp and np.any(cal.temp_bias_dps_per_degC != 0) else None
    if fine[-1] == fine[0]:
        phi, c, at = np.zeros((0, 3)), np.zeros((0, 3)), np.searchsorted(coarse, mids)
    else:
        phi, c, at = _increments(pairs[0].acc, temp_int, np.diff(t_fine), cal, fine, coarse, mids)
    return _fit_matrix(phi, c, at, known, cal, model, 0.05, reference)


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
    buffer holds all of it; its start is carried to the next block until then."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, width: int) -> None:
        self.lo, self.hi, self.k = np.asarray(lo, np.int64), np.asarray(hi, np.int64), 0
        self.acc = np.zeros((self.lo.size, width) if width > 1 else self.lo.size)

    def add(self, x: np.ndarray, x0: int) -> int:
        """Sum the ranges complete within x (global indices x0 ..); returns the first index still needed."""
        end = x0 + x.shape[0]
        m = self.k + int(np.searchsorted(self.hi[self.k :], end, side="right"))
        if m > self.k:
            lo, hi = self.lo[self.k : m] - x0, self.hi[self.k : m] - x0
            edges = np.stack([lo, hi], axis=1).ravel()
            if edges[-1] >= x.shape[0]:
                edges = edges[:-1]
            self.acc[self.k : m] = np.add.reduceat(x, edges, axis=0)[::2]
            self.k = m
        return int(self.lo[m]) if m < self.lo.size else end


def _sum_pass(path, a: np.ndarray, b: np.ndarray, fine: np.ndarray | None):
    """Rate/temperature sums over the windows [a, b), trapezoid integrals over the fine blocks and
    the times at their edges (module doc); returns (windows, fine, t_fine, has_temp)."""
    wins = (_Segments(a, b, 3), _Segments(a, b, 1))
    f = np.zeros(0, np.int64) if fine is None or fine.size < 2 else fine
    pairs = (_Segments(f[:-1], f[1:], 3), _Segments(f[:-1], f[1:], 1))
    t_fine = np.zeros(f.size)
    buf, buf0, has_temp = None, 0, True  # samples (t, w, temp) kept from global index buf0
    for blk in iter_imu(path):
        g0 = buf0 + (0 if buf is None else buf[0].size)
        lo, hi = np.searchsorted(f, [g0, g0 + blk.n])  # the fine edges in this block (f is sorted)
        t_fine[lo:hi] = blk.t_s[f[lo:hi] - g0]
        has_temp = has_temp and blk.temp_degC is not None
        new = (blk.t_s, np.asarray(blk.gyro_dps, float), blk.temp_degC if has_temp else np.zeros(blk.n))
        buf = new if buf is None else tuple(np.concatenate([o, n]) for o, n in zip(buf, new, strict=True))
        t, w, temp = buf
        need = [wins[0].add(w, buf0)]
        if has_temp:
            wins[1].add(np.asarray(temp, float), buf0)
        if f.size and t.size > 1:
            dt = np.diff(t)
            inc = w[:-1] + w[1:]
            inc *= (0.5 * dt)[:, None]
            need.append(pairs[0].add(inc, buf0))
            if has_temp:
                ti = temp[:-1] + temp[1:]
                ti *= 0.5 * dt
                pairs[1].add(ti, buf0)
        keep = min(*need, buf0 + t.size) - buf0  # a range not yet begun: keep nothing
        buf, buf0 = tuple(x[keep:] for x in buf), buf0 + keep
    return wins, pairs, t_fine, has_temp
