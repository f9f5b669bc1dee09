"""Quaternions and rotations, accellog's one set (numpy, batched over any leading axes). Quaternions
are (w, x, y, z), unit norm, and rotate vectors from the sensor frame to the world frame:
v_world = q * v_sensor * q^-1.

Every function also takes complex arrays, so that a complex step (x + i h) propagates through it:
the gyro matrix fit (accellog.calibrate.gyro.fit) gets its Jacobian exact to rounding that way.
Norms are therefore sqrt(sum q*q), never |q| (for real arrays the same arithmetic as
np.linalg.norm), and branches test the real part.

Hand-written rather than scipy.spatial.transform.Rotation: Rotation is real only (no complex
step), stores (x, y, z, w) and has no prefix product (prefix_quat_product, the strapdown's scan).
On 1e6 rows (2-core test machine) Rotation's apply(inverse=True) took 97 ms against rotate_inverse's
111 ms and from_rotvec 35 ms against quat_from_rotvec's 61 ms, small beside the 1.2 s scan of
accellog.navigate.strapdown.integrate_gyro, which has no scipy counterpart.
"""

from __future__ import annotations

import numpy as np


def _real_or_complex(x) -> np.ndarray:
    """float64 array, or complex when x is complex (complex-step derivatives pass through)."""
    x = np.asarray(x)
    return x if np.iscomplexobj(x) else x.astype(float, copy=False)


def _norm(x: np.ndarray) -> np.ndarray:
    """sqrt(sum x*x) over the last axis, kept as a length-1 axis (analytic: complex steps pass)."""
    return np.sqrt((x * x).sum(axis=-1, keepdims=True))


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p*q for (...,4) arrays."""
    pw, px, py, pz = np.moveaxis(_real_or_complex(p), -1, 0)
    qw, qx, qy, qz = np.moveaxis(_real_or_complex(q), -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """(w, -x, -y, -z): the inverse of a unit quaternion."""
    return _real_or_complex(q) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """q / sqrt(sum q*q) over the last axis."""
    q = _real_or_complex(q)
    return q / _norm(q)


def quat_from_axis_angle(axis, angle_rad) -> np.ndarray:
    """Quaternion(s) for a rotation of angle_rad about axis (any length, normalised here)."""
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(angle_rad, float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Quaternion(s) (cos a/2, sin(a/2)/a phi) from rotation vectors phi (...,3) (rad), a = |phi|;
    sin(a/2)/a -> 1/2 - a^2/48 below a = 1e-12, so exact for small angles too."""
    rotvec = _real_or_complex(rotvec)
    angle = _norm(rotvec)
    half = 0.5 * angle
    big = angle.real > 1e-12
    k = np.where(big, np.sin(half) / np.where(big, angle, 1.0), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), k * rotvec], axis=-1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (...,3) (rad) of unit quaternions (...,4), shortest arc (|angle| <= pi).

    angle = 2 atan(s / w) with s = |(x, y, z)|, w >= 0 after the sign flip, written as
    pi - 2 atan(w / s) when w < s/2 (no arctan2: it has no complex form); 2 / w below s = 1e-12."""
    q = _real_or_complex(q)
    q = q * np.where(q[..., :1].real < 0, -1.0, 1.0)
    s = _norm(q[..., 1:])[..., 0]
    w = q[..., 0]
    fwd = w.real > 0.5 * np.abs(s)
    ang = np.where(
        fwd, 2.0 * np.arctan(s / np.where(fwd, w, 1.0)), np.pi - 2.0 * np.arctan(w / np.where(fwd, 1.0, s))
    )
    tiny = np.abs(s) <= 1e-12
    k = np.where(tiny, 2.0 / np.where(tiny, w, 1.0), ang / np.where(tiny, 1.0, s))
    return k[..., None] * q[..., 1:]


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(...,4) -> (...,3,3) rotation matrices R with v_world = R @ v_sensor."""
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def _apply(q: np.ndarray, v: np.ndarray, inverse: bool) -> np.ndarray:
    """R(q) v, or R(q)^T v, row by row without forming R (same sums, in the same order, as
    quat_to_matrix @ v; q (...,4) and v (...,3) broadcast against each other)."""
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    v0, v1, v2 = np.moveaxis(_real_or_complex(v), -1, 0)
    wx, wy, wz = w * x, w * y, w * z
    if inverse:  # R^T: the w terms of the off-diagonal change sign (exactly: a - (-b) is a + b)
        wx, wy, wz = -wx, -wy, -wz
    return np.stack(
        [
            (1 - 2 * (y * y + z * z)) * v0 + 2 * (x * y - wz) * v1 + 2 * (x * z + wy) * v2,
            2 * (x * y + wz) * v0 + (1 - 2 * (x * x + z * z)) * v1 + 2 * (y * z - wx) * v2,
            2 * (x * z - wy) * v0 + 2 * (y * z + wx) * v1 + (1 - 2 * (x * x + y * y)) * v2,
        ],
        axis=-1,
    )


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate sensor-frame vectors v (...,3) into the world frame by q (...,4): R(q) v."""
    return _apply(q, v, inverse=False)


def rotate_inverse(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate world-frame vectors v (...,3) into the sensor frame by q (...,4): R(q)^T v."""
    return _apply(q, v, inverse=True)


def quat_between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc quaternion q with rotate(q, u) parallel to v (u, v non-zero 3-vectors)."""
    u = np.asarray(u, float) / np.linalg.norm(u)
    v = np.asarray(v, float) / np.linalg.norm(v)
    d = float(np.dot(u, v))
    if d < -1 + 1e-12:
        axis = np.cross(u, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(u, [0.0, 1.0, 0.0])
        return quat_from_axis_angle(axis, np.pi)
    q = np.concatenate([[1.0 + d], np.cross(u, v)])
    return q / np.linalg.norm(q)


def prefix_quat_product(dq: np.ndarray) -> np.ndarray:
    """Inclusive prefix product along axis -2, (...,N,4) -> (...,N,4):
    out_k = dq_0 * dq_1 * ... * dq_k (Hamilton, in order).

    Hillis-Steele scan: for d = 1, 2, 4, ...: out_k <- out_{k-d} * out_k for k >= d.
    Rounding error grows like log2 N products instead of N.
    """
    out = _real_or_complex(dq).copy()
    n = out.shape[-2]
    d = 1
    while d < n:
        out[..., d:, :] = quat_multiply(out[..., :-d, :], out[..., d:, :])
        d *= 2
    return out
