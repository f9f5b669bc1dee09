"""Gyro calibration: bias (+ temperature slope) from holds, scale/misalignment from known rotations."""

from __future__ import annotations

import json

import numpy as np
import pytest

from accellog.acquire.emulator.robot import demo_loop
from accellog.calibrate.gyro.calibrate import calibrate_gyro, fit_gyro_bias, fit_gyro_matrix
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.core.errors import InputError
from accellog.core.protocol import six_position
from accellog.core.rotations import quat_conjugate, quat_multiply
from accellog.core.session import PoseLabel

HZ = 200.0
M_TRUE = np.array([[1.02, 0.008, -0.012], [-0.006, 0.985, 0.01], [0.015, -0.007, 1.03]])
B_TRUE = np.array([0.8, -1.2, 0.4])  # deg/s at 25 degC
BT_TRUE = np.array([0.02, -0.015, 0.03])  # deg/s/degC


def _rotvec(q: np.ndarray) -> np.ndarray:
    q = q * np.sign(q[0] if q[0] != 0 else 1.0)
    s = np.linalg.norm(q[1:])
    return q[1:] * (2 * np.arctan2(s, q[0]) / s if s > 1e-12 else 2.0)


def _pose_sequence(hold_s: float = 6.0, move_s: float = 3.0, noise_dps: float = 0.05, seed: int = 0):
    """Six face poses, then the same again (12 holds), smooth rotations in between.

    Between holds a and b the body rotates about the fixed body axis r = rotvec(q_a^-1 q_b) with
    angle s(u) |r| (smootherstep), so the true rate is r s'(u)/move_s. Gyro: M w + b + b_T dT + n;
    temperature ramps 20 -> 40 degC.
    """
    specs = six_position(hold_s) * 2
    qs = np.array([p.q_sensor_to_world for p in specs])
    t_all, w_all, labels, t0 = [], [], [], 0.0
    for i in range(len(specs)):
        th = np.arange(0.0, hold_s, 1.0 / HZ)
        t_all.append(t0 + th)
        w_all.append(np.zeros((th.size, 3)))
        labels.append(PoseLabel(specs[i].name, t0, t0 + hold_s, specs[i].up_sensor, tuple(qs[i]), i))
        t0 += hold_s
        if i + 1 < len(specs):
            r = _rotvec(quat_multiply(quat_conjugate(qs[i]), qs[i + 1]))
            tm = np.arange(0.0, move_s, 1.0 / HZ)
            u = tm / move_s
            ds = 30 * u**2 * (1 - u) ** 2 / move_s
            t_all.append(t0 + tm)
            w_all.append(np.rad2deg(np.outer(ds, r)))
            t0 += move_s
    t = np.concatenate(t_all)
    w_true = np.concatenate(w_all)
    temp = 20.0 + 20.0 * t / t[-1]
    rng = np.random.default_rng(seed)
    w = (
        w_true @ M_TRUE.T
        + B_TRUE
        + np.multiply.outer(temp - 25.0, BT_TRUE)
        + rng.normal(0, noise_dps, w_true.shape)
    )
    return t, w, temp, labels


@pytest.fixture(scope="module")
def seq():
    return _pose_sequence()


def test_bias_and_temperature_slope(seq):
    t, w, temp, labels = seq
    cal = fit_gyro_bias(t, w, labels, temp)
    assert cal.effects == ["bias", "temp_bias"]
    z_b = (cal.bias_dps - B_TRUE) / cal.bias_sigma_dps
    z_t = (cal.temp_bias_dps_per_degC - BT_TRUE) / cal.temp_bias_sigma_dps_per_degC
    assert np.all(np.abs(z_b) < 5) and np.all(np.abs(z_t) < 5)
    assert np.all(cal.bias_sigma_dps < 0.01) and np.all(cal.temp_bias_sigma_dps_per_degC < 1e-3)
    # without temperature only the bias is fitted, and it is the mean over the holds
    cal0 = fit_gyro_bias(t, w, labels)
    assert cal0.effects == ["bias"] and np.all(cal0.temp_bias_dps_per_degC == 0)


def test_scale_and_misalignment_from_known_rotations(seq):
    t, w, temp, labels = seq
    cal = calibrate_gyro(t, w, labels, temp, model="full")
    assert cal.undetermined == []
    assert "cross_axis" in cal.effects
    err = cal.matrix - M_TRUE
    assert np.abs(err).max() < 2e-3
    assert np.all(np.abs(err / cal.matrix_sigma) < 6)
    assert cal.rotation_rms_deg < 0.2
    # corrected rates: a static hold reads zero, a rotation reads the true rate
    wc = cal.correct(w, temp)
    hold = (t > labels[3].start_s + 0.5) & (t < labels[3].end_s - 0.5)
    assert np.abs(wc[hold].mean(axis=0)).max() < 0.01
    scale_only = fit_gyro_matrix(t, w, labels, cal, temp, model="scale")
    assert np.abs(np.diag(scale_only.matrix) - np.diag(M_TRUE)).max() < 0.01
    assert np.isnan(scale_only.matrix_sigma[0, 1])


def test_robot_turns_determine_only_the_z_column():
    """The demo loop turns about z only: x/y scale are reported undetermined, not guessed."""
    m = demo_loop()
    t = np.arange(0.0, m.duration_s, 1.0 / HZ)
    k = m.kinematics(t)
    rng = np.random.default_rng(2)
    w = k.omega_dps @ M_TRUE.T + B_TRUE + rng.normal(0, 0.05, (t.size, 3))
    cal = calibrate_gyro(t, w, m.labels(), model="full", reference="orientation")
    assert {"Mxx", "Myy", "Mxy", "Myx"} <= set(cal.undetermined)
    assert "Mzz" not in cal.undetermined
    assert abs(cal.matrix[2, 2] - M_TRUE[2, 2]) < 3 * cal.matrix_sigma[2, 2] + 1e-3
    assert cal.matrix[0, 0] == 1.0 and np.isnan(cal.matrix_sigma[0, 0])


def test_dict_round_trip(seq):
    t, w, temp, labels = seq
    cal = calibrate_gyro(t, w, labels, temp, model="scale")
    d = json.loads(json.dumps(cal.to_dict()))  # strict JSON: NaN became null
    back = GyroCalibration.from_dict(d)
    np.testing.assert_array_equal(back.matrix, cal.matrix)
    np.testing.assert_array_equal(back.bias_dps, cal.bias_dps)
    np.testing.assert_array_equal(np.isnan(back.matrix_sigma), np.isnan(cal.matrix_sigma))
    assert back.effects == cal.effects and back.undetermined == cal.undetermined
    np.testing.assert_allclose(back.correct(w[:50], temp[:50]), cal.correct(w[:50], temp[:50]))


def test_bad_input(seq):
    t, w, _temp, labels = seq
    with pytest.raises(InputError, match="no static holds"):
        fit_gyro_bias(t, w, [])
    with pytest.raises(InputError, match="fewer than 2 windows"):
        fit_gyro_bias(t, w, np.array([[0.0, 0.5]]))
    with pytest.raises(InputError, match="known orientation"):
        fit_gyro_matrix(t, w, labels[:1], fit_gyro_bias(t, w, labels))
    with pytest.raises(InputError, match="unknown gyro model"):
        fit_gyro_matrix(t, w, labels, fit_gyro_bias(t, w, labels), model="banana")
    with pytest.raises(InputError):
        GyroCalibration.from_dict({"bias_dps": [1, 2]})


@pytest.mark.parametrize("case", ["gravity-full", "orientation-full", "gravity-scale", "robot"])
def test_moves_only_fit_equals_the_dense_fit(seq, case):
    """The moves-only fit (holds as one block each, complex-step Jacobian) gives the dense fit's
    result (every 10 ms block from mid to mid, finite differences; tests/support/gyro_dense.py),
    both converged to the optimum: M within 1e-9 of its scale (the rest is the dense path's
    rounding in its running sum over the session), sigma within 1e-6 (the dense fit's
    forward-difference Jacobian is itself good to ~1e-7)."""
    from support.gyro_dense import fit_gyro_matrix as dense_fit

    if case == "robot":
        m = demo_loop()
        t = np.arange(0.0, m.duration_s, 1.0 / HZ)
        rng = np.random.default_rng(2)
        w = m.kinematics(t).omega_dps @ M_TRUE.T + B_TRUE + rng.normal(0, 0.05, (t.size, 3))
        labels, temp, ref, model = m.labels(), None, "orientation", "full"
    else:
        t, w, temp, labels = seq
        ref, model = case.split("-")
    base = fit_gyro_bias(t, w, labels, temp)
    tight = {"ftol": 1e-12, "xtol": 1e-12, "gtol": 1e-12}
    old = dense_fit(t, w, labels, base, temp, model=model, reference=ref, **tight)
    new = fit_gyro_matrix(t, w, labels, base, temp, model=model, reference=ref)
    assert new.undetermined == old.undetermined and new.effects == old.effects
    np.testing.assert_allclose(new.matrix, old.matrix, rtol=0, atol=1e-9 * np.abs(old.matrix).max())
    np.testing.assert_allclose(new.matrix_sigma, old.matrix_sigma, rtol=1e-6, equal_nan=True)
    assert new.rotation_rms_deg == pytest.approx(old.rotation_rms_deg, rel=1e-6)


def test_relative_rotations_in_groups_of_hold_pairs_equal_one_scan():
    """relative_rotations formed a few hold pairs at a time (bounded memory) equals the one scan
    over all blocks to rounding, for one matrix and for a stack of complex-stepped ones."""
    from accellog.calibrate.gyro.rotation import relative_rotations

    rng = np.random.default_rng(4)
    at = np.concatenate([[0], np.cumsum(rng.integers(1, 40, 15))])
    phi, c = rng.normal(0, 0.02, (at[-1], 3)), rng.normal(0, 1e-5, (at[-1], 3))
    m = M_TRUE + 1j * 1e-30 * rng.normal(size=(4, 3, 3))
    for mm in (M_TRUE, m):
        whole = relative_rotations(phi, c, at, mm, budget=10**9)
        for budget in (1, 7, 50):
            part = relative_rotations(phi, c, at, mm, budget=budget)
            np.testing.assert_allclose(part.real, whole.real, rtol=0, atol=1e-14)
            np.testing.assert_allclose(part.imag, whole.imag, rtol=1e-9, atol=1e-45)
