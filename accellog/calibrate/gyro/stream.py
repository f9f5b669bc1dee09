"""Gyro calibration of a session fed block by block: the one implementation of the stage (the fits
on its sums: ``gyro.fit``). ``blocks`` is a pass factory: a ``store.source.Source`` (an MCAP file
chunk group by chunk group, without loading it; a Session as one block); ``calibrate.calibrate_gyro``
feeds it whole arrays as one block. Memory: one
block plus O(windows + coarse blocks + the fine blocks of one hold pair), the coarse blocks being
the 10 ms blocks of the moves and one per hold: bounded by the moves, not by the session length.

Two passes over the blocks (``blocks()`` is called once per pass):

1. windows and locate: the sample index of every time the fit asks for (hold window edges, hold
   start/middle/end) is the count of samples before it, summed over blocks (``np.searchsorted`` on
   the whole time axis, block by block), plus the time of the first sample at or after each hold
   middle; each bias window's rate and temperature sums are taken as soon as its end is found
   (``FirstPass``), and the bias model (``fit.bias_fit``) is fitted from them; the samples whose
   rate clips are counted per move on the way (``fit.clipped_in_moves``: those moves are left out).
   A caller that reads the file anyway (the fit's observation pass) feeds ``first_pass(...)`` its
   blocks and hands it over: then this pass is not made again;
2. integrate: the trapezoid integrals of the rate (and temperature) over the 10 ms fine blocks
   between hold middles (a sample pair that straddles two blocks is carried over), bias-corrected
   and reduced to their coarse blocks (phi, c; ``rotation`` module doc) as each block completes them
   (``_CoarseBlocks``: the prefix sum and any open coarse block carried between blocks). The fine
   block edges are made one hold pair at a time (``rotation.fine_pieces``); the pass stops at the
   last hold middle. The matrix is then fitted on (phi, c) (``fit.fit_matrix``).

Every window and fine-block sum is one ``np.add.reduceat`` over exactly its samples, so the result
does not depend on where the blocks are cut, but for the sums of a coarse block that spans two
blocks (~1e-16 relative).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import NamedTuple

import numpy as np

from accellog.calibrate.gyro.fit import (
    BIAS_TRIM_S,
    BIAS_WINDOW_S,
    bias_window_times,
    clipped_in_moves,
    fit_matrix,
    hold_intervals,
    known_poses,
    pose_times,
    screened_bias_fit,
)
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.gyro.rotation import coarse_plan, fine_pieces
from accellog.core.errors import InputError
from accellog.core.heap import trim_heap
from accellog.core.session import PoseLabel
from accellog.store.stream import ImuBlock, closed_after

_BLOCK_S = 0.01
"""Fine block length (s)."""


class RateBlock(NamedTuple):
    """Consecutive samples of a session: times (s, increasing), rates (N,3) deg/s (None: no gyro
    recorded), temperatures (N,) degC or None (a store.stream.ImuBlock has these fields too)."""

    t_s: np.ndarray
    gyro_dps: np.ndarray | None
    temp_degC: np.ndarray | None


Blocks = Callable[[], Iterable[RateBlock | ImuBlock]]
"""A session's blocks in time order: a fresh iteration of them per call (one call per pass)."""


def calibrate_blocks(
    blocks: Blocks,
    poses: Sequence[PoseLabel] | np.ndarray,
    *,
    model: str = "full",
    reference: str = "gravity",
    t_ref_degC: float = 25.0,
    window_s: float = BIAS_WINDOW_S,
    min_temp_span_degC: float = 2.0,
    temp_order: int = 1,
    still_ref: GyroCalibration | None = None,
    trim_s: float = BIAS_TRIM_S,
    full_scale_dps: float | None = None,
    floor_deg: float = 0.05,
    rotations: bool = True,
    base: GyroCalibration | None = None,
    first: FirstPass | None = None,
) -> GyroCalibration | None:
    """The gyro calibration of the session blocks() yields (module doc): the bias from the holds
    poses (trim_s cut from both ends of each), then the matrix from the rotations between them when
    >= 2 have a reference (all for reference='gravity', those with an orientation for
    'orientation'); None when the session records no gyro rate. Arguments: gyro.fit.

    rotations=False: the bias only (poses may then be (K,2) start/end times, s). base: the bias is
    base's (no windows are summed) and the matrix is fitted (>= 2 poses with a reference needed).
    first: step 1 already fed every block (first_pass with the same arguments). temp_order: 2 adds
    b_T2 dT^2 to the bias (fit.bias_fit). still_ref: a calibration of the same gyro (a lab prior):
    windows whose mean is more than fit.STILL_TOL_DPS from its bias are turns, not stops (fit.still_windows)."""
    iv, known, first_new = _plan(
        poses, model, reference, window_s, trim_s, full_scale_dps, rotations, bias=base is None
    )
    if first is None:
        first = first_new
        with closed_after(blocks()) as it:
            for blk in it:
                if not first.add(blk):
                    break
        trim_heap()  # the pass's block arrays are freed: give their pages back (core.heap)
    found = first.result()
    if found is None:
        return None
    has_temp, located = found[1:]
    if base is None:
        base = _bias(
            found[0],
            has_temp,
            int(iv.shape[0]),
            t_ref_degC,
            window_s,
            min_temp_span_degC,
            temp_order,
            still_ref,
        )
    del found  # the window sums are not held through the second pass (24 h: 3.4 MB)
    if not known:
        return base
    phi, c, at = _rotation_blocks(blocks, located, len(known), base, has_temp)
    return fit_matrix(phi, c, at, known, base, model, floor_deg, reference, first.moves.counts > 0)


def _bias(sums, has_temp: bool, n_holds: int, t_ref_degC: float, window_s: float, min_span: float,
          temp_order: int = 1, still_ref: GyroCalibration | None = None):  # fmt: skip
    """fit.bias_fit on the window means of FirstPass sums (the turning ones out: fit.screened_bias_fit)."""
    means = sums[0] / sums[2][:, None]
    temps = sums[1] / sums[2] if has_temp else np.full(sums[2].size, np.nan)
    return screened_bias_fit(
        means, temps, has_temp, n_holds, t_ref_degC, window_s, min_span, temp_order, still_ref
    )


def bias_windows(blocks: Blocks, poses, *, window_s: float = BIAS_WINDOW_S, trim_s: float = BIAS_TRIM_S):
    """(window means (W,3) deg/s, window temperatures (W,) degC (NaN without), has_temp) of one
    session's holds: step 1 alone, for a bias pooled over sessions (fit.pooled_bias); None without gyro."""
    first = _plan(poses, "full", "gravity", window_s, trim_s, None, rotations=False)[2]
    with closed_after(blocks()) as it:
        for blk in it:
            if not first.add(blk):
                break
    found = first.result()
    if found is None:
        return None
    sums, has_temp = found[0], found[1]
    temps = sums[1] / sums[2] if has_temp else np.full(sums[2].size, np.nan)
    return sums[0] / sums[2][:, None], temps, has_temp


def _rotation_blocks(blocks: Blocks, located, k: int, base: GyroCalibration, has_temp: bool):
    """Step 2 (module doc): (phi, c, coarse block index of each hold middle) from the blocks and the
    located hold middles, ends and starts of the k poses rotated between."""
    counts, n_total, first_at = located
    pidx = np.clip(counts, 0, n_total - 1)
    mids, ends, starts = pidx[:k], pidx[k : 2 * k], pidx[2 * k :]
    t_mid = {int(i): float(v) for i, v in zip(mids, first_at[:k], strict=True)}
    coarse, at, n_fine = coarse_plan(t_mid, mids, ends, starts, _BLOCK_S)
    mid_at = np.searchsorted(coarse, mids)
    if n_fine == 1:
        return np.zeros((0, 3)), np.zeros((0, 3)), mid_at
    del coarse
    use_temp = has_temp and bool(np.any(base.temp_poly_dps != 0))
    acc = _CoarseBlocks(at, n_fine, base, use_temp)
    with closed_after(blocks()) as it:
        _integrate_pass(it, mids[0], fine_pieces(t_mid, mids, _BLOCK_S), acc)
    trim_heap()
    return acc.phi, acc.c, mid_at


def first_pass(
    poses: Sequence[PoseLabel],
    *,
    model: str = "full",
    reference: str = "gravity",
    window_s: float = BIAS_WINDOW_S,
    trim_s: float = BIAS_TRIM_S,
    full_scale_dps: float | None = None,
) -> FirstPass:
    """Step 1 of calibrate_blocks with these arguments, to be fed a pass's blocks (add) and
    handed to it as first; InputError as calibrate_blocks (no static holds)."""
    return _plan(poses, model, reference, window_s, trim_s, full_scale_dps)[2]


def _plan(poses, model, reference, window_s, trim_s, full_scale_dps, rotations=True, bias=True):
    """(holds, poses rotated between, an unfed FirstPass) of calibrate_blocks' arguments."""
    iv = hold_intervals(poses)
    if bias and iv.shape[0] == 0:
        raise InputError("no static holds: the gyro bias cannot be estimated")
    if not bias:
        known = known_poses(poses, model, reference)
    elif not rotations:
        known = []
    else:
        n_ref = len(poses) if reference == "gravity" else sum(p.q_sensor_to_world is not None for p in poses)
        known = known_poses(poses, model, reference) if n_ref >= 2 else []
    win_times = bias_window_times(iv, window_s, trim_s) if bias else []
    pose_t = pose_times(known) if known else (np.zeros(0),) * 3
    return iv, known, FirstPass(win_times, np.concatenate(pose_t), _MoveClips(pose_t[0], full_scale_dps))


class _MoveClips:
    """Clipped samples per move (fit.clipped_in_moves), summed block by block."""

    def __init__(self, mid_t: np.ndarray, full_scale_dps: float | None) -> None:
        self.mid_t, self.full_scale_dps = mid_t, full_scale_dps
        self.counts = np.zeros(max(len(mid_t) - 1, 0), np.int64)

    def add(self, t_s: np.ndarray, gyro_dps: np.ndarray) -> None:
        self.counts += clipped_in_moves(t_s, gyro_dps, self.mid_t, self.full_scale_dps)


class FirstPass:
    """Module doc step 1 fed block by block: the rate and temperature sums over the bias windows
    (edge times win_times, one array per hold) and the locate for the pose times pose_q; moves
    counts the clipped samples per move. result(): ((rate sums (W,3), temperature sums (W,),
    samples (W,)) of the windows of >= 2 samples, has_temp, (samples before each pose time,
    samples in all, time of the first sample at or after each (the last sample's time when none
    is))); None when the session has no gyro rate (or no block was added).

    A window's sample range [a, b) is the count of samples before its edge times; the count is
    final once a sample at or after the time has passed (times sorted), so each window is summed
    (_Segments, one np.add.reduceat over exactly its samples) as soon as its end is found, the
    samples from the first window still open kept over to the next block."""

    def __init__(self, win_times: list[np.ndarray], pose_q: np.ndarray, moves: _MoveClips) -> None:
        nw = [len(q) for q in win_times]
        queries = np.concatenate([*win_times, pose_q])
        qlo = np.concatenate(
            [s + np.arange(n - 1) for s, n in zip(np.cumsum([0, *nw]), nw, strict=False)] or [[]]
        )
        self.qlo, self.n_pose, self.moves = qlo.astype(np.int64), pose_q.size, moves
        self.loc = _Locator(queries)
        self.end_t = (
            np.maximum.accumulate(queries[self.qlo + 1]) if self.qlo.size else np.zeros(0)
        )  # prefix max
        self.nxt, self.has_temp, self.no_gyro, self.seen = 0, True, False, False
        w = qlo.size  # the window sums, filled in as the windows end (none of < 2 samples kept)
        self.sums: tuple[np.ndarray, np.ndarray, np.ndarray] | None = (
            np.zeros((w, 3)),
            np.zeros(w),
            np.zeros(w),
        )
        self.buf: tuple[np.ndarray, np.ndarray | None] | None = None  # samples (w, temp) kept from
        self.buf0 = 0  # global index buf0

    def add(self, blk) -> bool:
        """The next block (a RateBlock); False once the session shows no gyro rate."""
        if self.no_gyro or blk.gyro_dps is None:
            self.no_gyro = True
            return False
        self.seen = True
        if not len(blk.t_s):
            return True  # nothing to locate or sum
        loc, qlo, nxt = self.loc, self.qlo, self.nxt
        self.moves.add(blk.t_s, blk.gyro_dps)
        loc.add(blk.t_s)
        self.has_temp = has_temp = self.has_temp and blk.temp_degC is not None
        w, temp = np.asarray(blk.gyro_dps, float), np.asarray(blk.temp_degC, float) if has_temp else None
        if self.buf is not None:
            w, temp = np.concatenate([self.buf[0], w]), _cat(self.buf[1], temp)
        buf, sums = (w, temp), self.sums
        assert sums is not None, "add() after result()"
        m = max(nxt, int(np.searchsorted(self.end_t, loc.t_last, side="right")))  # windows with a found end
        _window_sums(loc.counts[qlo[nxt:m]], loc.counts[qlo[nxt:m] + 1], buf, self.buf0, sums, nxt)
        self.nxt = nxt = m
        held = self.buf0 + buf[0].shape[0]
        need = held if nxt == qlo.size else loc.count(qlo[nxt])
        keep = min(need, held) - self.buf0
        self.buf, self.buf0 = (w[keep:], None if temp is None else temp[keep:]), self.buf0 + keep
        return True

    def result(self):
        """The sums and locate of every block added (class doc), once; None without gyro rate."""
        loc, qlo, nxt = self.loc, self.qlo, self.nxt
        if self.no_gyro or not self.seen:
            return None
        counts, n_total, first_at = loc.finish()
        if nxt < qlo.size:  # windows running to the end of the session
            _window_sums(counts[qlo[nxt:]], counts[qlo[nxt:] + 1], self.buf, self.buf0, self.sums, nxt)
            self.nxt = qlo.size
        keep = self.sums[2] >= 2
        sums = tuple(x[keep] for x in self.sums)
        k = self.n_pose
        located = (counts[counts.size - k :].copy(), n_total, first_at[first_at.size - k :].copy())
        self.buf = self.sums = self.loc = None  # taken once: freed with the locate
        return sums, self.has_temp, located


class _Locator:
    """For each query time: the count of samples before it and the time of the first sample at or
    after it, as the blocks pass (times increasing, as the time-stamp checks require). A query is
    settled by the first block whose last sample is at or after it; only unsettled queries are
    searched, in time order (O(samples + queries log queries) in all, not blocks x queries)."""

    def __init__(self, queries: np.ndarray) -> None:
        self.q, self.order = queries, np.argsort(queries, kind="stable")
        self.sorted, self.k = queries[self.order], 0  # settled: self.order[: self.k]
        self.counts, self.first_at = np.zeros(queries.size, np.int64), np.full(queries.size, np.nan)
        self.n, self.t_last = 0, -np.inf

    def add(self, t: np.ndarray) -> None:
        """The next block's sample times (s)."""
        m = self.k + int(np.searchsorted(self.sorted[self.k :], t[-1], side="right"))
        j = np.searchsorted(t, self.sorted[self.k : m])
        idx = self.order[self.k : m]
        self.counts[idx], self.first_at[idx] = self.n + j, t[j]
        self.k, self.n, self.t_last = m, self.n + t.size, max(self.t_last, t[-1])

    def count(self, i: int) -> int:
        """Samples before query i: final once settled, else all samples so far (a lower bound)."""
        return int(self.counts[i]) if self.q[i] <= self.t_last else self.n

    def finish(self) -> tuple[np.ndarray, int, np.ndarray]:
        """(counts, samples in all, first times): unsettled queries count every sample and take the
        last sample's time."""
        rest = self.order[self.k :]
        self.counts[rest], self.first_at[rest] = self.n, self.t_last
        return self.counts, self.n, self.first_at


def _window_sums(a: np.ndarray, b: np.ndarray, buf: tuple, buf0: int, out: tuple, at: int) -> None:
    """The (rate sums, temperature sums, samples) of the windows [a, b) of >= 2 samples, all in buf,
    written to out's rows at, at + 1, ... (a window of fewer samples is left at 0): arrays made once
    for all windows, not three small ones per block kept to the end of the pass (~6,700 at 24 h)."""
    n = b - a
    keep = n >= 2
    a, b = a[keep], b[keep]
    out[2][at : at + n.size] = n
    if not a.size:
        return
    rows = at + np.flatnonzero(keep)
    for x, o in zip(buf, out[:2], strict=True):
        if x is not None:
            seg = _Segments(a, b)
            seg.add(x, buf0)
            o[rows] = seg.new


class _Segments:
    """Sums over sorted, non-overlapping index ranges [lo_j, hi_j), each summed in one np.add.reduceat
    call over exactly its samples (bit for bit the whole-session sums): a range is summed once the
    buffer holds all of it; its start is carried to the next block until then. Only the sums of the
    ranges completed by the last add are held (self.new, ranges self.done), not all."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray) -> None:
        self.lo, self.hi, self.k = np.asarray(lo, np.int64), np.asarray(hi, np.int64), 0
        self.new, self.done = np.zeros(0), (0, 0)  # new: set by every add

    def add(self, x: np.ndarray, x0: int) -> int:
        """Sum the ranges complete within x (global indices x0 ..); returns the first index still needed."""
        end = x0 + x.shape[0]
        m = self.k + int(np.searchsorted(self.hi[self.k :], end, side="right"))
        self.new, self.done = x[:0], (self.k, m)
        if m > self.k:
            lo, hi = self.lo[self.k : m] - x0, self.hi[self.k : m] - x0
            edges = np.stack([lo, hi], axis=1).ravel()
            if edges[-1] >= x.shape[0]:
                edges = edges[:-1]
            self.new = np.add.reduceat(x, edges, axis=0)[::2]
            self.k = m
        return int(self.lo[m]) if m < self.lo.size else end


class _CoarseBlocks:
    """The coarse block increments (phi, c; rotation module doc) of the bias-corrected fine blocks b,
    fed in order a batch at a time, each batch reduced to its coarse blocks at once (memory
    O(coarse blocks + one batch), not O(fine blocks)): phi = sum of b over the coarse block and
    c = 1/2 sum_{i<j} b_i x b_j = 1/2 (sum p_excl x b - p_start x phi), p_excl the sum of all
    earlier fine blocks and p_start its value at the coarse block's first.

    Carried between batches: the running sum p of all earlier fine blocks (the p_excl of the next
    one) and the partial (phi, sum p_excl x b) and p_start of a coarse block still open, prepended
    as a row to the next batch's sums, so every sum is formed in the order of one whole batch."""

    def __init__(self, at: np.ndarray, n_fine: int, base: GyroCalibration, use_temp: bool):
        """at: first fine block of each coarse block; n_fine: number of fine block edges."""
        self.at = np.asarray(at, np.int64)
        self.end = np.append(self.at[1:], n_fine - 1)  # one past its last fine block
        self.phi, self.c = np.zeros((self.at.size, 3)), np.zeros((self.at.size, 3))
        self.base, self.use_temp = base, use_temp
        self.p, self.k = np.zeros(3), 0
        self.open: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (phi, cross sum, p at start)

    def add(self, w_int: np.ndarray, temp_int: np.ndarray | None, span: np.ndarray) -> None:
        """The next fine blocks: rate integrals (deg), temperature integrals (degC s), durations (s)."""
        base = self.base
        b = w_int - np.outer(span, base.bias_dps)
        if self.use_temp:  # int b_T dT dt; int b_T2 dT^2 dt ~ b_T2 (mean dT)^2 span (a fine block's
            assert temp_int is not None  # use_temp: the pass integrates the temperature
            dT_s = temp_int - base.t_ref_degC * span  # temperature is flat: the error is b_T2 var(T) span)
            b -= np.outer(dT_s, base.temp_bias_dps_per_degC)
            if base.temp_bias2_dps_per_degC2 is not None:
                b -= np.outer(dT_s**2 / np.maximum(span, 1e-300), base.temp_bias2_dps_per_degC2)
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


def _cat(old: np.ndarray | None, new: np.ndarray | None) -> np.ndarray | None:
    return None if old is None or new is None else np.concatenate([old, new])


def _integrate_pass(blocks: Iterable, first: int, pieces: Iterator[np.ndarray], acc: _CoarseBlocks) -> None:
    """Trapezoid integrals of the rate (and temperature) over the fine blocks, fed to acc as each
    block completes them (a sample pair that straddles two blocks is carried over). The fine edges
    come hold pair by hold pair from pieces (after the first, mids[0]), taken as the samples reach
    them; the pass stops after the last edge (samples past it are not integrated)."""
    edges, more = np.array([first], np.int64), True  # the fine edges from the first block not summed
    buf: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None  # samples (t, w, temp or
    buf0 = 0  # None) kept from global index buf0
    for blk in blocks:
        t, w = blk.t_s, np.asarray(blk.gyro_dps, float)
        temp = np.asarray(blk.temp_degC, float) if acc.use_temp else None
        if buf is not None:
            t, w, temp = np.concatenate([buf[0], t]), np.concatenate([buf[1], w]), _cat(buf[2], temp)
        buf = (t, w, temp)
        held = t.size
        end = buf0 + held - 1  # one past the last sample pair held
        while more and edges[-1] < end:
            piece = next(pieces, None)
            more = piece is not None
            edges = edges if piece is None else np.concatenate([edges, piece])
        need = int(edges[0])
        if edges.size > 1 and need < end:
            stop = held if more else min(held, int(edges[-1]) - buf0 + 1)
            part = None if temp is None else temp[:stop]
            need, m = _integrate(t[:stop], w[:stop], part, buf0, edges, acc)
            edges = edges[m:]
        if edges.size == 1 and not more:
            return  # the last fine block is summed: the rest of the session is not needed
        keep = min(need, buf0 + held) - buf0  # a range not yet begun: keep nothing
        buf, buf0 = (t[keep:], w[keep:], None if temp is None else temp[keep:]), buf0 + keep


def _integrate(t, w, temp, buf0: int, edges: np.ndarray, acc: _CoarseBlocks) -> tuple[int, int]:
    """The fine blocks between consecutive edges that the samples t, w, temp (global indices buf0 ..)
    complete, fed to acc; returns (the first sample still needed, the number of blocks fed)."""
    need = int(edges[0])
    pairs = (_Segments(edges[:-1], edges[1:]), _Segments(edges[:-1], edges[1:]))
    lo = need - buf0
    half_dt = np.diff(t[lo:])
    half_dt *= 0.5
    inc = w[lo:-1] + w[lo + 1 :]
    inc *= half_dt[:, None]
    need = pairs[0].add(inc, need)
    del inc  # its block sums are taken: not held beside the temperature's
    temp_int = None
    if temp is not None:
        ti = temp[lo:-1] + temp[lo + 1 :]
        ti *= half_dt
        pairs[1].add(ti, buf0 + lo)
        temp_int = pairs[1].new
    m = pairs[0].done[1]
    span = t[edges[1 : m + 1] - buf0] - t[edges[:m] - buf0]
    acc.add(pairs[0].new, temp_int, span)
    return need, m
