"""Gyro rates -> rotations between holds, for the gyro matrix fit (accellog.calibrate.gyro.calibrate).

The rate is integrated once into ~10 ms trapezoid blocks; a gyro matrix M then corrects the blocks
instead of every sample (block rotation vector M^-1 phi + det(M^-1) M^T c, c the second-order
Baker-Campbell-Hausdorff term of the blocks merged inside a hold). The quaternion helpers are the
arithmetic of accellog.core.rotations written so that a complex step propagates through them.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

import numpy as np

from accellog.core.rotations import quat_multiply

if TYPE_CHECKING:
    from accellog.calibrate.gyro.model import GyroCalibration

DEG_PER_RAD = 180.0 / np.pi


def _block_edges(t: np.ndarray, mids: np.ndarray, ends: np.ndarray, starts: np.ndarray, block_s: float):
    """Fine and coarse block edges (sample indices) from mids[0] to mids[-1].

    Fine: between the mids a, b of consecutive holds, ~block_s blocks evenly spaced from a to b
    (np.linspace, rounded). Coarse: the fine edges of the move between the holds, but the fine
    blocks inside a hold (a .. end of hold a, start of hold b .. b) merged into one each."""
    fine, coarse = [np.array([mids[0]])], [np.array([mids[0]])]
    for f, c in _pair_edges(t, mids, ends, starts, block_s):
        fine.append(f)
        coarse.append(c)
    return _sorted_unique(np.concatenate(fine)), _sorted_unique(np.concatenate(coarse))


def _pair_edges(t, mids: np.ndarray, ends: np.ndarray, starts: np.ndarray, block_s: float):
    """_block_edges hold pair by hold pair: the fine edges after mids[k] up to mids[k+1] and the
    coarse ones among them (repeats not removed); t: sample times (anything indexable by sample)."""
    for k, (a, b) in enumerate(itertools.pairwise(mids)):
        yield _pair_fine(t, a, b, block_s)[1:], _pair_coarse(t, a, b, ends[k], starts[k + 1], block_s)


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
    """The fine edges of _block_edges as consecutive pieces, one per hold pair, without repeats:
    their concatenation after mids[0] is _block_edges' fine array (memory: one pair's edges)."""
    last = mids[0]
    for a, b in itertools.pairwise(mids):
        f = _sorted_unique(_pair_fine(t, a, b, block_s))
        f = f[f > last]
        if f.size:
            last = f[-1]
        yield f


def coarse_plan(t, mids: np.ndarray, ends: np.ndarray, starts: np.ndarray, block_s: float):
    """(coarse edges of _block_edges, index in the fine edges of each coarse edge but the last,
    number of fine edges), formed hold pair by hold pair (memory: one pair's fine edges)."""
    coarse, at = [np.array([mids[0]])], [np.zeros(1, np.int64)]
    n_fine, last = 1, mids[0]
    for k, f in enumerate(fine_pieces(t, mids, block_s)):
        a, b = mids[k], mids[k + 1]
        c = _sorted_unique(_pair_coarse(t, a, b, ends[k], starts[k + 1], block_s))
        c = c[c > last]
        if c.size:
            last = c[-1]
        coarse.append(c)
        at.append(n_fine + np.searchsorted(f, c))
        n_fine += f.size
    return np.concatenate(coarse), np.concatenate(at)[:-1], n_fine


def _sorted_unique(e: np.ndarray) -> np.ndarray:
    """np.unique of an already non-decreasing array, in one pass."""
    return e[np.concatenate([[True], e[1:] != e[:-1]])] if e.size else e


def _trapezoid_blocks(t: np.ndarray, x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Trapezoid integrals of x ((N,) or (N,k)) over [t[e_j], t[e_j+1]] for consecutive edges."""
    dt = np.diff(t)
    inc = x[:-1] + x[1:]
    inc *= (0.5 * dt)[:, None] if inc.ndim == 2 else 0.5 * dt
    return np.add.reduceat(inc, edges[:-1], axis=0)


def block_increments(
    t: np.ndarray,
    w_dps: np.ndarray,
    temp_degC: np.ndarray | None,
    base: GyroCalibration,
    holds: tuple[np.ndarray, np.ndarray, np.ndarray],
    block_s: float,
) -> tuple:
    """Rotation increments over the coarse blocks of _block_edges: (phi (B,3) rad, c (B,3) rad^2,
    block-edge index of each mid (K,)); holds = (mid, end, start) sample index of each hold.

    phi is the trapezoid integral of the bias-corrected rate over a block (body frame):
    int (w - b0 - b_T (T - T_ref)) dt = W - b0 dt - b_T (int T dt - T_ref dt), so only the raw
    rate and the temperature are integrated per sample. It is exact for rotation about a fixed
    axis (the protocol's moves) and second order in (rate x block_s) otherwise; it is linear in
    the rate, so a gyro matrix correction applies to the blocks instead of every sample. A coarse
    block that merges the fine blocks b_1..b_n of a static hold also carries their second-order
    term c = 1/2 sum_{i<j} b_i x b_j, so that exp(b_1) ... exp(b_n) = exp(phi + c) + O(|b|^3)
    (Baker-Campbell-Hausdorff; the product the dense integration forms). Cost: one pass over the
    samples from the first to the last mid, then O(fine blocks)."""
    mids, ends, starts = holds
    fine, coarse = _block_edges(t, mids, ends, starts, block_s)
    lo, hi = int(fine[0]), int(fine[-1])
    if hi == lo:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.searchsorted(coarse, mids)
    tt, fe = t[lo : hi + 1], fine - lo
    w_int = _trapezoid_blocks(tt, np.asarray(w_dps[lo : hi + 1], float), fe)
    temp_int = None
    if temp_degC is not None:
        temp_int = _trapezoid_blocks(tt, np.asarray(temp_degC[lo : hi + 1], float), fe)
    return _increments(w_int, temp_int, np.diff(tt[fe]), base, fine, coarse, mids)


def _increments(w_int, temp_int, span, base: GyroCalibration, fine, coarse, mids) -> tuple:
    """block_increments from the fine blocks' trapezoid integrals of the raw rate (deg) and the
    temperature (degC s) and their durations span (s)."""
    b = w_int - np.outer(span, base.bias_dps)
    if temp_int is not None:
        b -= np.outer(temp_int - base.t_ref_degC * span, base.temp_bias_dps_per_degC)
    b = np.deg2rad(b)
    p_excl = np.concatenate([np.zeros((1, 3)), np.cumsum(b, axis=0)[:-1]])  # sum of earlier blocks
    at = np.searchsorted(fine, coarse[:-1])  # first fine block of each coarse block
    phi = np.add.reduceat(b, at, axis=0)
    c = 0.5 * (np.add.reduceat(np.cross(p_excl, b), at, axis=0) - np.cross(p_excl[at], phi))
    return phi, c, np.searchsorted(coarse, mids)


# complex-safe quaternion helpers: the same arithmetic as accellog.core.rotations, written so that
# a complex step (x + i h) propagates through them (the Jacobian of the gyro matrix fit is exact to rounding)


def _qexp(phi: np.ndarray) -> np.ndarray:
    """Quaternions (...,4) from rotation vectors (...,3) (rad): (cos a/2, sin(a/2)/a phi)."""
    a = np.sqrt((phi * phi).sum(axis=-1, keepdims=True))
    big = a.real > 1e-12
    safe = np.where(big, a, 1.0)
    k = np.where(big, np.sin(0.5 * safe) / safe, 0.5 - a * a / 48.0)
    return np.concatenate([np.cos(0.5 * a), k * phi], axis=-1)


def _qnormalize(q: np.ndarray) -> np.ndarray:
    return q / np.sqrt((q * q).sum(axis=-1, keepdims=True))


def quat_conj_rows(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _prefix_product(dq: np.ndarray) -> np.ndarray:
    """Inclusive prefix product along axis -2 (Hillis-Steele scan, as rotations.prefix_quat_product)."""
    out = dq.copy()
    n = out.shape[-2]
    d = 1
    while d < n:
        out[..., d:, :] = quat_multiply(out[..., :-d, :], out[..., d:, :])
        d *= 2
    return out


def relative_rotations(
    phi: np.ndarray, c: np.ndarray, at: np.ndarray, m: np.ndarray, budget: int = 1 << 13
) -> np.ndarray:
    """Body-frame rotation (...,K-1,4) from each mid to the next, with rates corrected by M^-1
    (m (3,3), or (P,3,3) for P matrices at once): block rotation vector M^-1 phi + det(M^-1) M^T c,
    since (A u) x (A v) = det(A) A^-T (u x v) carries the second-order term c through A = M^-1.
    Formed for consecutive hold pairs of up to budget blocks at a time (memory: P x budget
    quaternions, whatever the number of moves; one group, the whole scan, for up to budget)."""
    m_inv_t = np.swapaxes(np.linalg.inv(m), -1, -2)
    det = np.linalg.det(m)[..., None, None]
    out, i = [], 0
    while i < at.size - 1:
        j = max(i + 1, int(np.searchsorted(at, at[i] + budget, side="right")) - 1)
        lo, hi = at[i], at[j]
        ph = phi[lo:hi] @ m_inv_t + (c[lo:hi] @ m) / det
        ident = np.zeros((*ph.shape[:-2], 1, 4), ph.dtype)
        ident[..., 0] = 1.0
        q = _qnormalize(_prefix_product(np.concatenate([ident, _qexp(ph)], axis=-2)))
        a = at[i : j + 1] - lo
        out.append(_qnormalize(quat_multiply(quat_conj_rows(q[..., a[:-1], :]), q[..., a[1:], :])))
        i = j
    return np.concatenate(out, axis=-2)


def rotate_inverse_rows(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """World vectors v (K,3) into the sensor frame by q (...,K,4): R(q)^T v."""
    q = _qnormalize(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
    return np.stack(
        [
            (1 - 2 * (y * y + z * z)) * v0 + 2 * (x * y + w * z) * v1 + 2 * (x * z - w * y) * v2,
            2 * (x * y - w * z) * v0 + (1 - 2 * (x * x + z * z)) * v1 + 2 * (y * z + w * x) * v2,
            2 * (x * z + w * y) * v0 + 2 * (y * z - w * x) * v1 + (1 - 2 * (x * x + y * y)) * v2,
        ],
        axis=-1,
    )


def rotvec_deg(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (deg) of unit quaternions (...,K,4), shortest arc."""
    q = q * np.where(q[..., :1].real < 0, -1.0, 1.0)
    s = np.sqrt((q[..., 1:] * q[..., 1:]).sum(axis=-1))
    w = q[..., 0]
    fwd = w.real > 0.5 * np.abs(s)
    ang = np.where(
        fwd, 2.0 * np.arctan(s / np.where(fwd, w, 1.0)), np.pi - 2.0 * np.arctan(w / np.where(fwd, 1.0, s))
    )
    tiny = np.abs(s) <= 1e-12
    k = np.where(tiny, 2.0 / np.where(tiny, w, 1.0), ang / np.where(tiny, 1.0, s))
    return DEG_PER_RAD * k[..., None] * q[..., 1:]
