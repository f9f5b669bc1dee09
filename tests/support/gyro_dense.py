"""The dense gyro scale/misalignment fit as it was before the moves-only rewrite (kept verbatim,
apart from passing least_squares options through): every ~10 ms block from mid to mid integrated
for every residual call, forward-difference Jacobian. tests/calibrate/test_gyro_cal.py checks the fast
accellog.calibrate.gyro.calibrate.fit_gyro_matrix against it."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from accellog.calibrate.gyro.model import PARAM_NAMES, GyroCalibration
from accellog.core.errors import InputError, ModelError
from accellog.core.rotations import (
    prefix_quat_product,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
    rotate_inverse,
)
from accellog.core.session import PoseLabel


def _block_increments(t: np.ndarray, w_dps: np.ndarray, mids: np.ndarray, block_s: float) -> tuple:
    """Trapezoid rotation increments (rad, body frame) summed over blocks of ~block_s, with block
    edges on every mid index; returns (increments (B,3), block index of each mid (K,)).

    Summing increments inside a block is exact for rotation about a fixed axis (the protocol's
    moves) and second order in (rate x block_s) otherwise; the increments are linear in the
    rate, so a gyro matrix correction can be applied to the blocks instead of every sample."""
    w = np.deg2rad(w_dps)
    inc = 0.5 * (w[:-1] + w[1:]) * np.diff(t)[:, None]  # step i: from sample i to i+1
    edges = [int(mids[0])]
    for a, b in itertools.pairwise(mids):
        n = max(1, int(np.ceil((t[b] - t[a]) / block_s)))
        edges.extend(np.linspace(a, b, n + 1).round().astype(int)[1:].tolist())
    edges = np.unique(np.asarray(edges))
    csum = np.concatenate([np.zeros((1, 3)), np.cumsum(inc, axis=0)])
    blocks = np.diff(csum[edges], axis=0)
    return blocks, np.searchsorted(edges, mids)


def _relative_rotations(blocks: np.ndarray, at: np.ndarray, m_inv: np.ndarray) -> np.ndarray:
    """Body-frame rotation (K-1,4) from each mid to the next, with rates corrected by m_inv."""
    phi = blocks @ m_inv.T
    dq = np.concatenate([[[1.0, 0.0, 0.0, 0.0]], quat_from_rotvec(phi)])
    q = quat_normalize(prefix_quat_product(dq))
    return quat_normalize(quat_multiply(quat_conjugate(q[at[:-1]]), q[at[1:]]))


def _rotvec_deg(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (deg) of unit quaternions (K,4), shortest arc."""
    q = q * np.where(q[:, :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(q[:, 1:], axis=1)
    ang = 2.0 * np.arctan2(s, q[:, 0])
    k = np.where(s > 1e-12, ang / np.where(s > 1e-12, s, 1.0), 2.0)
    return np.rad2deg(k[:, None] * q[:, 1:])


def fit_gyro_matrix(
    t_s: np.ndarray,
    gyro_dps: np.ndarray,
    poses: Sequence[PoseLabel],
    base: GyroCalibration,
    temp_degC: np.ndarray | None = None,
    *,
    model: str = "full",
    floor_deg: float = 0.05,
    reference: str = "gravity",
    **lsq_kw,
) -> GyroCalibration:
    """Scale ('scale': diag M) or scale + cross-axis ('full': all of M) from rotations between
    consecutive labelled poses (see module doc). Returns a copy of base with matrix,
    matrix_sigma, undetermined and rotation_rms_deg filled in.

    reference: 'gravity' (default) compares only what gravity sees: the up vector of hold a,
    carried through the integrated rotation, must land on the up vector of hold b (residual
    dq_int^-1 up_a - up_b, deg; rotations about the vertical are not used, so an operator who
    turns the sensor freely between holds does no harm); 'orientation' compares the whole
    nominal rotation q_a^-1 q_b (for fixtures or vehicles whose heading is known).
    floor_deg: smallest residual scatter assumed (deg, nominal pose orientation error).
    """
    from scipy.optimize import least_squares

    if model not in ("scale", "full"):
        raise InputError(f"unknown gyro model {model!r}: use 'scale' or 'full'")
    if reference not in ("gravity", "orientation"):
        raise InputError(f"unknown gyro reference {reference!r}: use 'gravity' or 'orientation'")
    known = [p for p in poses if reference == "gravity" or p.q_sensor_to_world is not None]
    if len(known) < 2:
        raise InputError("fewer than 2 labelled poses with known orientation: gyro scale cannot be fitted")
    t = np.asarray(t_s, float)
    w_unb = np.asarray(gyro_dps, float) - base.bias_at(
        temp_degC if np.any(base.temp_bias_dps_per_degC != 0) else None
    )
    mids = np.searchsorted(t, [0.5 * (p.start_s + p.end_s) for p in known])
    mids = np.clip(mids, 0, t.size - 1)
    if reference == "orientation":
        qn = np.array([p.q_sensor_to_world for p in known], float)
        dq_nom = quat_multiply(quat_conjugate(qn[:-1]), qn[1:])
    else:
        up = np.array([p.up_sensor for p in known], float)
        up /= np.linalg.norm(up, axis=1, keepdims=True)
    diag_idx = [0, 4, 8]
    free_all = diag_idx if model == "scale" else list(range(9))

    blocks, at = _block_increments(t, w_unb, mids, block_s=0.01)

    def residuals(p: np.ndarray, free: list[int]) -> np.ndarray:
        m = np.eye(3).ravel()
        m[free] = p
        dq_int = _relative_rotations(blocks, at, np.linalg.inv(m.reshape(3, 3)))
        if reference == "orientation":
            return _rotvec_deg(quat_multiply(quat_conjugate(dq_nom), dq_int)).ravel()
        # up_a (world-fixed) seen from the sensor at hold b: v_b = dq_int^-1 v_a; the difference of
        # unit vectors is the tilt error in rad for small errors (and, unlike a cross product,
        # it does not vanish for a vector pointing the opposite way)
        pred = rotate_inverse(dq_int, up[:-1])
        return np.rad2deg(pred - up[1:]).ravel()

    # which entries of M do the rotations excite? (finite-difference sensitivity at M = I)
    p_init = np.eye(3).ravel()[free_all]
    r0 = residuals(p_init, free_all)
    h = 1e-4
    sens = np.array(
        [
            np.linalg.norm(residuals(p_init + h * np.eye(len(free_all))[i], free_all) - r0) / h
            for i in range(len(free_all))
        ]
    )
    # a 1 % error in M_ij must move some rotation by > 10 floor_deg-ish to be determinable
    free = [f for f, s in zip(free_all, sens, strict=True) if s * 0.01 > floor_deg]
    undetermined = [PARAM_NAMES[f] for f in free_all if f not in free]
    if not free:
        raise ModelError("the rotations between labelled poses are too small to determine any gyro scale")
    sol = least_squares(residuals, np.eye(3).ravel()[free], args=(free,), x_scale=0.01, **lsq_kw)
    r = sol.fun
    dof = r.size - len(free)
    s2 = max(float(r @ r) / dof, floor_deg**2) if dof > 0 else floor_deg**2
    jtj = sol.jac.T @ sol.jac
    if np.linalg.cond(jtj) > 1e12:
        raise ModelError(f"gyro {model} model is not determined by these rotations (rank deficient)")
    cov = s2 * np.linalg.inv(jtj)
    m = np.eye(3).ravel()
    m[free] = sol.x
    msig = np.full(9, np.nan)
    msig[free] = np.sqrt(np.diag(cov))
    offdiag_free = [f for f in free if f not in diag_idx]
    effects = [e for e in base.effects if e not in ("scale", "cross_axis")] + ["scale"]
    if offdiag_free:
        effects.append("cross_axis")
    return GyroCalibration(
        bias_dps=base.bias_dps,
        bias_sigma_dps=base.bias_sigma_dps,
        temp_bias_dps_per_degC=base.temp_bias_dps_per_degC,
        temp_bias_sigma_dps_per_degC=base.temp_bias_sigma_dps_per_degC,
        t_ref_degC=base.t_ref_degC,
        matrix=m.reshape(3, 3),
        matrix_sigma=msig.reshape(3, 3),
        effects=effects,
        undetermined=undetermined,
        n_holds=base.n_holds,
        rotation_rms_deg=float(np.sqrt(np.mean(r**2))),
    )
