"""Quaternion and rotation helpers (numpy, vectorised). Quaternions are (w, x, y, z), unit norm,
and rotate vectors from the sensor frame to the world frame: v_world = q * v_sensor * q^-1."""

from __future__ import annotations

import numpy as np


def _real_or_complex(x) -> np.ndarray:
    """float64 array, or complex when x is complex (complex-step derivatives pass through)."""
    x = np.asarray(x)
    return x if np.iscomplexobj(x) else x.astype(float, copy=False)


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p*q for (...,4) arrays (float, or complex for complex-step Jacobians)."""
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
    q = np.asarray(q, float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_from_axis_angle(axis, angle_rad) -> np.ndarray:
    """Quaternion(s) for a rotation of angle_rad about axis (any length, normalised here)."""
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * np.asarray(angle_rad, float)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Quaternion(s) from rotation vectors (rad); exact for small angles too."""
    rotvec = np.asarray(rotvec, float)
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a -> 1/2 as a -> 0
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), k * rotvec], axis=-1)


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


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate sensor-frame vectors v (...,3) into the world frame by q (...,4)."""
    return np.einsum("...ij,...j->...i", quat_to_matrix(q), np.asarray(v, float))


def rotate_inverse(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate world-frame vectors v (...,3) into the sensor frame by q (...,4)."""
    return np.einsum("...ji,...j->...i", quat_to_matrix(q), np.asarray(v, float))


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
    """Inclusive prefix product (N,4) -> (N,4): out_k = dq_0 * dq_1 * ... * dq_k (Hamilton, in order).

    Hillis-Steele scan: for d = 1, 2, 4, ...: out_k <- out_{k-d} * out_k for k >= d.
    Rounding error grows like log2 N products instead of N.
    """
    out = np.array(dq, float, copy=True)
    n = out.shape[0]
    d = 1
    while d < n:
        out[d:] = quat_multiply(out[:-d], out[d:])
        d *= 2
    return out
