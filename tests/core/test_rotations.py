"""accellog.core.rotations against scipy's Rotation (an independent implementation, scalar-last) and
the complex step the gyro matrix fit differentiates with."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from accellog.core.rotations import (
    prefix_quat_product,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
    quat_to_rotvec,
    rotate,
    rotate_inverse,
)


def _scipy(q: np.ndarray) -> Rotation:
    return Rotation.from_quat(q[..., [1, 2, 3, 0]])


def test_rotations_agree_with_scipy():
    rng = np.random.default_rng(4)
    q = quat_normalize(rng.normal(size=(500, 4)))
    v = rng.normal(size=(500, 3))
    np.testing.assert_allclose(rotate(q, v), _scipy(q).apply(v), atol=1e-12)
    np.testing.assert_allclose(rotate_inverse(q, v), _scipy(q).apply(v, inverse=True), atol=1e-12)
    np.testing.assert_allclose(rotate(q[0], v), _scipy(q[0]).apply(v), atol=1e-12)  # one q, many v
    rv = rng.normal(size=(500, 3)) * np.r_[np.full(250, 1.0), np.full(250, 1e-13)][:, None]
    np.testing.assert_allclose(
        quat_from_rotvec(rv)[:, [1, 2, 3, 0]], Rotation.from_rotvec(rv).as_quat(), atol=1e-15
    )
    np.testing.assert_allclose(quat_to_rotvec(q), _scipy(q).as_rotvec(), atol=1e-12)
    np.testing.assert_allclose(
        quat_to_rotvec(-q), _scipy(q).as_rotvec(), atol=1e-12
    )  # q and -q: one rotation
    scan, r = prefix_quat_product(q[:50]), Rotation.identity()
    for k in range(50):  # q_0 q_1 ... q_k, one product at a time
        r = r * _scipy(q[k])
        assert abs(np.dot(scan[k], r.as_quat()[[3, 0, 1, 2]])) > 1 - 1e-12


def test_complex_step_gives_the_derivative():
    """d/dh f(x + i h)/h at h = 1e-30 equals a central difference: nothing takes |q| or drops the
    imaginary part (the gyro matrix fit's Jacobian relies on it)."""
    rng = np.random.default_rng(5)
    phi, v, q0 = rng.normal(size=(20, 3)), rng.normal(size=(20, 3)), quat_normalize(rng.normal(size=4))

    def f(p):
        q = quat_normalize(prefix_quat_product(quat_multiply(q0, quat_from_rotvec(p))))
        return np.concatenate([rotate_inverse(q, v), quat_to_rotvec(q)], axis=-1)

    d = np.zeros_like(phi)
    d[3, 1] = 1.0
    step = f(phi + 1e-30j * d).imag / 1e-30
    central = (f(phi + 1e-6 * d) - f(phi - 1e-6 * d)) / 2e-6
    assert np.abs(step).max() > 0.1
    np.testing.assert_allclose(step, central, atol=1e-8)
