"""The thermal parameters of `export --to px4|ardupilot` run through each firmware's own run-time
equations, written from the firmware sources (not from accellog's model), in float32 as the
firmware computes, over the fitted temperature span and beyond it, against accellog's correction.

The firmware equations (PX4's TemperatureCompensation / Accelerometer::Correct, ArduPilot's
TCal::correct_sensor / _rotate_and_correct_accel, with their source files) are in tests/support/firmware.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.firmware import F32, FIRMWARE, param_values, px4_correct

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.calfile.sections import TemperatureInfo
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.model.compose import build_model
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0
from accellog.present.export_frames import directions_26, rotation
from accellog.present.exports import export_calibration
from accellog.present.thermal_params import held_correction

SPAN = (5.0, 45.0)


def _cal(
    t_ref: float, terms: str = "bias+scale+temp_bias+temp_bias2", extra: dict | None = None
) -> Calibration:
    """A calibration with a quadratic bias in temperature (accel) and a linear one (gyro, M = I)."""
    m = build_model(terms, t_ref_degC=t_ref)
    vals = {"b_x": 0.021, "b_y": -0.034, "b_z": 0.048, "S_xx": 1.012, "S_yy": 0.986, "S_zz": 1.007,
            "bT_x": 1.1e-3, "bT_y": -6e-4, "bT_z": 8e-4, "bT2_x": 2e-5, "bT2_y": -1.2e-5, "bT2_z": 1.6e-5,
            **(extra or {})}  # fmt: skip
    theta = np.array([vals.get(n, 0.0) for n in m.param_names])
    gyro = GyroCalibration(
        bias_dps=np.array([2.1, -3.4, 0.7]),
        bias_sigma_dps=np.full(3, 0.002),
        temp_bias_dps_per_degC=np.array([0.05, -0.12, 0.09]),
        t_ref_degC=t_ref - 3.0,
    )
    return Calibration(
        model_spec=m.to_spec(),
        param_names=m.param_names,
        param_units=m.param_units,
        theta=theta,
        cov=np.zeros((theta.size, theta.size)),
        temperature=TemperatureInfo(t_ref_degC=t_ref, mean_degC=25.0, min_degC=SPAN[0], max_degC=SPAN[1]),
        gyro=gyro,
    )


def _readings(cal: Calibration, R: np.ndarray, T_grid: np.ndarray):
    """Raw accel (m/s^2) and gyro (rad/s) readings in the driver-rotated axes for the 26 directions at
    each temperature, with accellog's corrections of them in the same axes (m/s^2, rad/s)."""
    u = directions_26()
    f = np.tile(u, (len(T_grid), 1))
    T = np.repeat(T_grid, len(u))
    lo, hi = SPAN
    reading_g = cal.model.predict(cal.theta, f, {"temp_degC": T})
    raw_a = G0 * reading_g @ R.T
    want_a = cal.correct_mps2(reading_g, {"temp_degC": np.clip(T, lo, hi)}) @ R.T
    w_true = 20.0 * f  # deg/s
    w_meas = w_true + cal.gyro.bias_at(T)
    raw_g = np.deg2rad(w_meas) @ R.T
    want_g = np.deg2rad(cal.gyro.correct(w_meas, np.clip(T, lo, hi))) @ R.T
    return T, raw_a, want_a, raw_g, want_g


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
@pytest.mark.parametrize("t_ref", [25.0, 52.0])
@pytest.mark.parametrize("rot", ["ROTATION_NONE", "ROTATION_ROLL_180_YAW_90"])
def test_firmware_equations_reproduce_the_calibration(target, t_ref, rot):
    """Inside the span: equal to 1e-6 g and 1e-5 deg/s; outside: the correction at the span's end."""
    cal = _cal(t_ref)
    ex = export_calibration(cal, target, rotation=rot, device_id=2621474)
    p = param_values(ex.text, target)
    _, _, R = rotation(rot)
    T_grid = np.concatenate([np.linspace(*SPAN, 41), [-10.0, 0.0, 4.9, 45.1, 60.0]])
    T, raw_a, want_a, raw_g, want_g = _readings(cal, R, T_grid)
    got_a = FIRMWARE[target](raw_a, T, p, "accel")
    got_g = FIRMWARE[target](raw_g, T, p, "gyro")
    assert np.max(np.abs(got_a - want_a)) / G0 < 1e-6
    assert np.rad2deg(np.max(np.abs(got_g - want_g))) < 1e-5
    assert not any("temp_bias" in x or "temperature bias" in x for x in ex.cannot_hold), ex.cannot_hold


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
@pytest.mark.parametrize("gyro_quadratic", [False, True])
def test_held_correction_is_what_the_firmware_computes(target, gyro_quadratic):
    """thermal_params.held_correction (the `export --heldout` verdict's correction) against each
    firmware's equations on the same readings, inside and outside the span (chip axes)."""
    cal = _cal(25.0)
    if gyro_quadratic:
        cal.gyro.temp_bias2_dps_per_degC2 = np.array([2e-3, -1e-3, 1.5e-3])
    p = param_values(export_calibration(cal, target, device_id=1).text, target)
    T_grid = np.concatenate([np.linspace(*SPAN, 21), [0.0, 60.0]])
    T, raw_a, _, raw_g, _ = _readings(cal, np.eye(3), T_grid)
    acc, gyr = held_correction(cal, raw_a / G0, T, np.rad2deg(raw_g))
    assert np.max(np.abs(acc - FIRMWARE[target](raw_a, T, p, "accel"))) / G0 < 1e-6
    assert np.max(np.abs(gyr - np.rad2deg(FIRMWARE[target](raw_g, T, p, "gyro")))) < 1e-5


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_thermal_terms_off_leave_the_temperature_error(target):
    """The same files with the thermal correction disabled leave the bias curve: the test can fail."""
    cal = _cal(25.0)
    p = param_values(export_calibration(cal, target, device_id=1).text, target)
    thermal = ("TC_A0_X", "TC_G0_X", "INS_TCAL1_ACC", "INS_TCAL1_GYR")
    off = {k: (F32(0.0) if k.startswith(thermal) else v) for k, v in p.items()}
    T, raw_a, want_a, _, _ = _readings(cal, np.eye(3), np.linspace(*SPAN, 9))
    err = np.max(np.abs(FIRMWARE[target](raw_a, T, off, "accel") - want_a)) / G0
    assert err > 1e-3


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_temperature_scale_is_stated_and_covers_the_firmware_error(target):
    """temp_scale is not held: the header names it, and its stated size covers what remains."""
    cal = _cal(
        25.0, "bias+scale+temp_bias+temp_bias2+temp_scale", {"sT_x": 2e-4, "sT_y": -1e-4, "sT_z": 1.5e-4}
    )
    ex = export_calibration(cal, target, device_id=1)
    line = next(x for x in ex.cannot_hold if "temp_scale" in x)
    assert "temp_bias" not in line
    stated = float(line.split("up to ")[1].split(" m/s^2")[0])
    T, raw_a, want_a, _, _ = _readings(cal, np.eye(3), np.linspace(*SPAN, 41))
    err = np.max(
        np.linalg.norm(FIRMWARE[target](raw_a, T, param_values(ex.text, target), "accel") - want_a, axis=1)
    )
    assert 0.5 * stated < err <= 1.01 * stated


def test_px4_update_step_is_stated_and_bounds_the_lag():
    """TemperatureCompensation::update_offsets_accel republishes after fabsf(T - last) > 1 degC:
    offsets evaluated at the last published temperature stay within the stated size."""
    cal = _cal(25.0)
    ex = export_calibration(cal, "px4", device_id=1)
    line = next(x for x in ex.cannot_hold if "between PX4's updates" in x)
    stated = float(line.split("up to ")[1].split(" m/s^2")[0])
    path = np.linspace(*SPAN, 4001)
    last, published = path[0], []
    for t in path:
        if abs(t - last) > 1.0:
            last = t
        published.append(last)
    p = param_values(ex.text, "px4")
    zero = np.zeros((len(path), 3))
    lag = px4_correct(zero, np.array(published), p, "accel") - px4_correct(zero, path, p, "accel")
    assert 0.5 * stated < np.max(np.linalg.norm(lag, axis=1)) <= 1.01 * stated


def test_ardupilot_writes_caltemp_inside_the_span():
    """CALTEMP is always written (the firmware clamps an unset -300 to TMIN) and lies in TMIN..TMAX."""
    for t_ref in (25.0, 52.0, -3.0):
        v = export_calibration(_cal(t_ref), "ardupilot").values
        for k in ("INS_ACC1_CALTEMP", "INS_GYR1_CALTEMP"):
            assert v["INS_TCAL1_TMIN"] <= v[k] <= v["INS_TCAL1_TMAX"]
        assert (v["INS_TCAL1_TMIN"], v["INS_TCAL1_TMAX"]) == SPAN
