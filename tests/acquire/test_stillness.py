"""Stillness detection: still at the noise floor, not still while turning or shaking."""

from __future__ import annotations

import numpy as np

from accellog.acquire.stillness import StillnessDetector


def _feed(
    det: StillnessDetector, t: np.ndarray, a: np.ndarray, w: np.ndarray | None, batch: int = 20
) -> list[bool]:
    out = []
    for i in range(0, len(t), batch):
        out.append(det.update(t[i : i + batch], a[i : i + batch], None if w is None else w[i : i + batch]))
    return out


def test_still_sensor_settles_after_settle_time():
    rng = np.random.default_rng(0)
    t = np.arange(3000) / 1000.0
    a = np.array([0.05, -0.02, 1.01]) + 0.007 * rng.standard_normal((3000, 3))  # bias + 7 mg noise
    w = np.array([3.0, -1.0, 2.0]) + 0.1 * rng.standard_normal((3000, 3))  # gyro bias is not motion
    det = StillnessDetector()
    states = _feed(det, t, a, w)
    assert states[-1] and det.settled
    assert det.still_for_s >= 2.0


def test_moving_sensor_is_not_still_and_resets():
    rng = np.random.default_rng(1)
    t = np.arange(4000) / 1000.0
    a = np.tile([0.0, 0.0, 1.0], (4000, 1)) + 0.007 * rng.standard_normal((4000, 3))
    w = 0.1 * rng.standard_normal((4000, 3))
    # a 1 s turn in the middle: 90 deg about x at 90 deg/s, gravity moves from z to y
    turn = (t >= 2.0) & (t < 3.0)
    ang = np.clip(t - 2.0, 0, 1) * np.pi / 2
    a[:, 1] += np.sin(ang) * (t >= 2.0)
    a[:, 2] += (np.cos(ang) - 1) * (t >= 2.0)
    w[turn, 0] += 90.0
    det = StillnessDetector()
    states = []
    for i in range(0, 4000, 20):
        states.append((t[i], det.update(t[i : i + 20], a[i : i + 20], w[i : i + 20])))
    during = [s for ti, s in states if 2.3 <= ti < 3.0]
    assert not any(during)
    assert states[-1][1] and 0.0 < det.still_for_s < 1.1  # still again only since the turn ended


def test_gyro_only_rotation_is_detected_without_accel_change():
    # rotating about the vertical leaves the accelerometer unchanged: only the gyro sees it
    t = np.arange(2000) / 1000.0
    a = np.tile([0.0, 0.0, 1.0], (2000, 1))
    w = np.zeros((2000, 3))
    w[:, 2] = 30.0 * np.sin(2 * np.pi * 1.0 * t)
    det = StillnessDetector()
    assert not any(_feed(det, t, a, w)[10:])
