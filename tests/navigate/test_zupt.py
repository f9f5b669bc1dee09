"""ZUPT: stop detection on a simulated robot run, velocity-error smoothing, no-stop refusal."""

from __future__ import annotations

import numpy as np
import pytest

from accellog.acquire.emulator.robot import RobotPathMotion, Segment, demo_loop, stop
from accellog.core.errors import InputError
from accellog.core.timeseries import cumtrapz
from accellog.navigate.strapdown import Track, strapdown
from accellog.navigate.zupt import apply_zupt, detect_stationary, zupt

HZ = 200.0


@pytest.fixture(scope="module")
def run():
    """Demo loop at 200 Hz with accel bias + cross-axis, gyro bias (removed) and white noise (seeded)."""
    m = demo_loop()
    t = np.arange(0.0, m.duration_s, 1.0 / HZ)
    k = m.kinematics(t)
    rng = np.random.default_rng(11)
    S = np.eye(3) + np.array([[0.0, 0.004, -0.003], [0.002, 0.0, 0.004], [-0.003, 0.002, 0.0]])
    a = k.specific_force_g @ S.T + np.array([0.004, -0.003, 0.005]) + rng.normal(0, 0.003, (t.size, 3))
    w = k.omega_dps + rng.normal(0, 0.05, (t.size, 3))
    return m, t, k, a, w


def test_detects_the_stops(run):
    m, t, _, a, w = run
    iv = detect_stationary(t, a, w)
    labels = m.labels()
    assert iv.shape == (len(labels), 2)
    for (lo, hi), lab in zip(iv, labels, strict=True):
        # every detected interval lies inside a true stop (to 0.15 s: the robot creeps at < 5 mm/s)
        assert t[lo] >= lab.start_s - 0.15 and t[hi - 1] <= lab.end_s + 0.15
        assert t[hi - 1] - t[lo] > 0.5 * (lab.end_s - lab.start_s)


def test_zupt_reduces_final_and_rms_error(run):
    _, t, k, a, w = run
    tr = strapdown(t, a, w, q0=k.q_sensor_to_world[0])
    z = zupt(tr, a, w)
    e_raw = np.linalg.norm(tr.position_m - k.position_m, axis=1)
    e_z = np.linalg.norm(z.track.position_m - k.position_m, axis=1)
    assert z.n_stops == 9
    assert e_z[-1] < 0.2 * e_raw[-1]
    assert np.sqrt(np.mean(e_z**2)) < 0.3 * np.sqrt(np.mean(e_raw**2))
    # the corrected velocity is exactly zero inside the stops
    for lo, hi in detect_stationary(t, a, w):
        np.testing.assert_allclose(z.track.velocity_mps[lo:hi], 0.0, atol=1e-12)
    assert np.linalg.norm(z.velocity_error_mps, axis=1).max() > 0.01  # there was an error to remove
    np.testing.assert_allclose(z.final_shift_m, z.track.position_m[-1] - tr.position_m[-1])


def test_linear_velocity_error_is_removed_exactly():
    """A constant accel bias between two stops makes a linear velocity error: ZUPT removes it."""
    t = np.linspace(0.0, 10.0, 1001)
    v_true = np.zeros((t.size, 3))
    v_true[(t > 2) & (t < 8), 0] = np.sin(np.pi * (t[(t > 2) & (t < 8)] - 2) / 6) ** 2
    err = 0.01 * np.clip(t - 2.0, 0.0, 6.0)[:, None] * np.array([1.0, -1.0, 0.5])
    v = v_true + err
    tr = Track(t, np.tile([1.0, 0, 0, 0], (t.size, 1)), v, cumtrapz(t, v))
    iv = np.array([[0, np.searchsorted(t, 2.0) + 1], [np.searchsorted(t, 8.0), t.size]])
    z = apply_zupt(tr, iv)
    np.testing.assert_allclose(z.track.velocity_mps, v_true, atol=1e-12)
    np.testing.assert_allclose(z.track.position_m, cumtrapz(t, v_true), atol=1e-12)


def test_no_stops_is_an_error_not_a_track():
    segs = [Segment(2.0, speed_mps=1.0), Segment(10.0), Segment(2.0, speed_mps=0.5)]
    m = RobotPathMotion(segs)
    t = np.arange(0.0, m.duration_s, 1.0 / HZ)
    k = m.kinematics(t)
    tr = strapdown(t, k.specific_force_g, k.omega_dps, q0=k.q_sensor_to_world[0], v0=k.velocity_mps[0])
    assert detect_stationary(t, k.specific_force_g, k.omega_dps).shape == (0, 2)
    with pytest.raises(InputError, match="no stationary intervals"):
        zupt(tr, k.specific_force_g, k.omega_dps)


def test_cruising_without_vibration_looks_static():
    """Why the robot vibrates: a constant-speed cruise is otherwise indistinguishable from a stop."""
    m = RobotPathMotion([stop(1.0), Segment(2.0, speed_mps=1.0), Segment(5.0)], vibration_m=0.0)
    t = np.arange(0.0, m.duration_s, 1.0 / HZ)
    k = m.kinematics(t)
    iv = detect_stationary(t, k.specific_force_g, k.omega_dps)
    assert any(t[lo] <= 5.0 <= t[hi - 1] for lo, hi in iv)  # the cruise counts as a stop
    m2 = RobotPathMotion([stop(1.0), Segment(2.0, speed_mps=1.0), Segment(5.0)])
    k2 = m2.kinematics(t)
    iv2 = detect_stationary(t, k2.specific_force_g, k2.omega_dps)
    assert all(t[hi - 1] < 1.2 for _, hi in iv2)
