"""Gyro rates -> rotations between holds, for the gyro matrix fit (accellog.calibrate.gyro.fit).

The rate is integrated once (accellog.calibrate.gyro.stream) into ~10 ms trapezoid fine blocks
from the middle of the first hold to the middle of the last; a gyro matrix M then corrects the
blocks instead of every sample. Block edges: between the middles a, b of consecutive holds, ~10 ms
blocks evenly spaced from a to b (np.linspace, rounded); the coarse blocks are the fine blocks of
the move between the holds, but the fine blocks inside a hold (a .. end of hold a, start of hold
b .. b) merged into one each.

A fine block's phi is the trapezoid integral of the bias-corrected rate (body frame):
int (w - b0 - b_T (T - T_ref)) dt = W - b0 dt - b_T (int T dt - T_ref dt), so only the raw rate
and the temperature are integrated per sample. It is exact for rotation about a fixed axis (the
protocol's moves) and second order in (rate x block length) otherwise; it is linear in the rate,
so a gyro matrix correction applies to the blocks instead of every sample. A coarse block that
merges the fine blocks b_1..b_n of a static hold also carries their second-order term
c = 1/2 sum_{i<j} b_i x b_j, so that exp(b_1) ... exp(b_n) = exp(phi + c) + O(|b|^3)
(Baker-Campbell-Hausdorff; the product the dense integration forms); corrected by M, a block's
rotation vector is M^-1 phi + det(M^-1) M^T c. The quaternion arithmetic is accellog.core.rotations
(complex-step safe, so the fit's Jacobian goes through it exactly).
"""

from __future__ import annotations

import itertools

import numpy as np

from accellog.core.rotations import (
    prefix_quat_product,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
)
from accellog.core.timeseries import sorted_unique


def _pair_fine(t, a: int, b: int, block_s: float) -> np.ndarray:
    """The fine block edges a .. b of one hold pair (np.linspace, rounded)."""
    n = max(1, int(np.ceil((t[b] - t[a]) / block_s)))
    return np.linspace(a, b, n + 1).round().astype(np.int64)


def _pair_coarse(t, a: int, b: int, end_a: int, start_b: int, block_s: float) -> np.ndarray:
    """The coarse block edges after a up to b: the fine ones of the move from the end of hold a to
    the start of hold b, then b (repeats not removed)."""
    e = _pair_fine(t, a, b, block_s)
    lo = e[e <= max(end_a, a)].max()
    hi = e[e >= min(max(start_b, lo), b)].min()
    return np.append(e[1:][(e[1:] >= lo) & (e[1:] <= hi)], b)


def fine_pieces(t, mids: np.ndarray, block_s: float):
    """The fine block edges (module doc; t: sample times, anything indexable by sample index) after
    mids[0] as consecutive pieces, one per hold pair, increasing and without repeats (memory: one
    pair's edges)."""
    last = mids[0]
    for a, b in itertools.pairwise(mids):
        f = sorted_unique(_pair_fine(t, a, b, block_s))
        f = f[f > last]
        if f.size:
            last = f[-1]
        yield f


def coarse_plan(t, mids: np.ndarray, ends: np.ndarray, starts: np.ndarray, block_s: float):
    """(coarse block edges (module doc) from mids[0], index in the fine edges of each coarse edge
    but the last, number of fine edges), formed hold pair by hold pair (memory: one pair's fine
    edges); ends, starts: the sample index of each hold's end and start."""
    coarse, at = [np.array([mids[0]])], [np.zeros(1, np.int64)]
    n_fine, last = 1, mids[0]
    for k, f in enumerate(fine_pieces(t, mids, block_s)):
        a, b = mids[k], mids[k + 1]
        c = sorted_unique(_pair_coarse(t, a, b, ends[k], starts[k + 1], block_s))
        c = c[c > last]
        if c.size:
            last = c[-1]
        coarse.append(c)
        at.append(n_fine + np.searchsorted(f, c))
        n_fine += f.size
    return np.concatenate(coarse), np.concatenate(at)[:-1], n_fine


def relative_rotations(
    phi: np.ndarray, c: np.ndarray, at: np.ndarray, m: np.ndarray, budget: int = 1 << 10
) -> np.ndarray:
    """Body-frame rotation (...,K-1,4) from each mid to the next, with rates corrected by M^-1
    (m (3,3), or (P,3,3) for P matrices at once): block rotation vector M^-1 phi + det(M^-1) M^T c,
    since (A u) x (A v) = det(A) A^-T (u x v) carries the second-order term c through A = M^-1.
    Formed for consecutive hold pairs of up to budget blocks at a time (memory: P x budget
    quaternions, whatever the number of moves; a pair of more blocks is one group). The scan is
    O(n log n) in a group's n blocks, so small groups are faster too: the 24 h benchmark session's
    matrix fit (86k coarse blocks, P = 9) took 5.9 s and 27.5 MB (traced peak) with groups of 8192
    blocks, 3.5 s and 3.5 MB with 1024."""
    m_inv_t = np.swapaxes(np.linalg.inv(m), -1, -2)
    det = np.linalg.det(m)[..., None, None]
    out, i = [], 0
    while i < at.size - 1:
        j = max(i + 1, int(np.searchsorted(at, at[i] + budget, side="right")) - 1)
        lo, hi = at[i], at[j]
        ph = phi[lo:hi] @ m_inv_t + (c[lo:hi] @ m) / det
        ident = np.zeros((*ph.shape[:-2], 1, 4), ph.dtype)
        ident[..., 0] = 1.0
        q = quat_normalize(prefix_quat_product(np.concatenate([ident, quat_from_rotvec(ph)], axis=-2)))
        a = at[i : j + 1] - lo
        out.append(quat_normalize(quat_multiply(quat_conjugate(q[..., a[:-1], :]), q[..., a[1:], :])))
        i = j
    return np.concatenate(out, axis=-2)
