"""RobotPathMotion: exact self-consistency of the truth kinematics, closure, labels, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from accellog.acquire.emulator.robot import (
    RobotPathMotion,
    Segment,
    demo_loop,
    drive,
    long_run,
    parked_run,
    stop,
    turn,
)
from accellog.core.errors import InputError
from accellog.core.rotations import quat_conjugate, quat_multiply, rotate
from accellog.core.units import STANDARD_GRAVITY_MPS2

H = 1e-4
"""Finite-difference step (s) for the consistency checks."""


@pytest.fixture(scope="module")
def loop():
    return demo_loop(local_gravity_mps2=9.797)


def _triplets(m, n: int = 20000, seed: int = 0):
    """Kinematics at n random times t and at t -/+ H (seeded): (before, at, after)."""
    t = np.random.default_rng(seed).uniform(H, m.duration_s - H, n)
    return m.kinematics(t - H), m.kinematics(t), m.kinematics(t + H)


def _central(before: np.ndarray, after: np.ndarray) -> np.ndarray:
    return (after - before) / (2 * H)


@pytest.fixture(scope="module")
def trip(loop):
    return _triplets(loop)


def test_velocity_is_derivative_of_position(trip):
    b, k, a = trip
    # central difference error ~ H^2/6 |d3p/dt3| (vibration dominates: A0 W^3 ~ 150 m/s^3) -> 2.5e-7
    assert np.abs(_central(b.position_m, a.position_m) - k.velocity_mps).max() < 1e-6


def test_specific_force_matches_velocity_derivative(trip):
    b, k, a = trip
    a_world = rotate(k.q_sensor_to_world, k.specific_force_g * STANDARD_GRAVITY_MPS2)
    a_world[:, 2] -= 9.797  # f = R^T (a - g_world) / g0, g_world = (0, 0, -g_local)
    # central difference error ~ H^2/6 |d4p/dt4| ~ 1.7e-9 * A0 W^4 (~ 2.2e4 m/s^4) -> 3.6e-5
    assert np.abs(_central(b.velocity_mps, a.velocity_mps) - a_world).max() < 1e-4
    assert np.abs(a_world).max() > 0.3  # the check is not vacuous


def test_omega_matches_orientation_derivative(trip):
    b, k, a = trip
    dq = quat_multiply(quat_conjugate(b.q_sensor_to_world), a.q_sensor_to_world)  # body rotation over 2H
    w_fd = np.rad2deg(2.0 * dq[:, 1:] * np.sign(dq[:, :1]) / (2 * H))
    assert np.abs(k.omega_dps).max() > 50.0  # the loop really turns
    assert np.abs(w_fd - k.omega_dps).max() < 1e-4


def test_loop_closes_and_moves(loop):
    k = loop.kinematics(np.array([0.0, 20.0, loop.duration_s]))
    np.testing.assert_allclose(k.position_m[-1], k.position_m[0], atol=1e-9)
    assert np.linalg.norm(k.position_m[1]) > 3.0
    # heading back at the start (q or -q)
    assert abs(abs(np.dot(k.q_sensor_to_world[0], k.q_sensor_to_world[-1])) - 1.0) < 1e-12
    full = loop.kinematics(np.linspace(0, loop.duration_s, 20001))
    assert full.position_m[:, 2].max() > 0.3  # the ramp goes up
    assert np.abs(full.omega_dps[:, 0]).max() > 1.0  # the banked section rolls


def test_stops_are_static_and_labelled(loop):
    labels = loop.labels()
    assert len(labels) == 9
    for lab in labels:
        t = np.linspace(lab.start_s, lab.end_s, 50)
        k = loop.kinematics(t)
        np.testing.assert_allclose(k.velocity_mps, 0.0, atol=1e-12)
        np.testing.assert_allclose(k.omega_dps, 0.0, atol=1e-12)
        # a perfect accelerometer reads g_local/g0 along the label's up vector
        expected = np.broadcast_to(np.array(lab.up_sensor) * 9.797 / STANDARD_GRAVITY_MPS2, (50, 3))
        np.testing.assert_allclose(k.specific_force_g, expected, atol=1e-12)
        np.testing.assert_allclose(
            abs(np.dot(k.q_sensor_to_world[0], lab.q_sensor_to_world)), 1.0, atol=1e-12
        )


def test_straight_run_covers_distance():
    m = RobotPathMotion([stop(1.0), *drive(5.0, 0.5, 2.0), stop(1.0)], vibration_m=0.0)
    k = m.kinematics(np.array([m.duration_s]))
    np.testing.assert_allclose(k.position_m[0], [5.0, 0.0, 0.0], atol=1e-10)


def test_turn_while_moving_is_consistent():
    segs = [
        stop(1.0),
        Segment(2.0, speed_mps=1.0),
        Segment(3.0, yaw_deg=120.0, grade_deg=3.0),
        Segment(2.0, speed_mps=0.0),
    ]
    m = RobotPathMotion(segs)
    b, k, a = _triplets(m, 5000, seed=1)
    a_world = rotate(k.q_sensor_to_world, k.specific_force_g * STANDARD_GRAVITY_MPS2)
    a_world[:, 2] -= STANDARD_GRAVITY_MPS2
    assert np.abs(_central(b.velocity_mps, a.velocity_mps) - a_world).max() < 1e-4
    assert np.abs(_central(b.position_m, a.position_m) - k.velocity_mps).max() < 1e-6
    assert np.linalg.norm(k.position_m, axis=1).max() > 2.0


def test_long_run_lasts():
    m = long_run(600.0)
    assert m.duration_s >= 600.0
    k = m.kinematics(np.array([0.0, m.duration_s]))
    np.testing.assert_allclose(k.position_m[-1], k.position_m[0], atol=1e-8)


def test_parked_run_stops_on_slopes_and_stands_still():
    """parked_run: a level start, then 30 stops, each standing still (zero rate, gravity only) z-up
    tilted 2-15 deg, the tilts differing between stops and between seeds."""
    m = parked_run(seed=3)
    first, *labels = m.labels()
    assert first.up_sensor == (0.0, 0.0, 1.0) and len(labels) == 30 and 550.0 < m.duration_s < 700.0
    tilt = np.rad2deg(np.arccos([p.up_sensor[2] for p in labels]))
    assert tilt.min() > 1.9 and tilt.max() < 15.1 and np.ptp(tilt) > 8.0
    t = np.concatenate([np.linspace(p.start_s, p.end_s, 5) for p in labels])
    k = m.kinematics(t)
    assert np.abs(k.omega_dps).max() < 1e-9 and np.abs(k.velocity_mps).max() < 1e-9
    up = np.repeat([p.up_sensor for p in labels], 5, axis=0)
    np.testing.assert_allclose(k.specific_force_g, up, atol=1e-9)
    assert labels[0].up_sensor != parked_run(seed=4).labels()[1].up_sensor


def test_bad_input():
    with pytest.raises(InputError):
        RobotPathMotion([])
    with pytest.raises(InputError):
        RobotPathMotion([Segment(-1.0)])
    with pytest.raises(InputError):
        RobotPathMotion([Segment(1.0, speed_mps=1.0), stop(1.0)])  # stop while moving
    with pytest.raises(InputError):
        drive(0.5, 1.0, 2.0)
    m = RobotPathMotion([stop(1.0), turn(90.0)])
    with pytest.raises(InputError):
        m.kinematics(np.array([m.duration_s + 1.0]))
