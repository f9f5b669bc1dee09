"""Physical sensor model, pose motion, temperature paths, clocks (seeded, simulated data)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from accellog.acquire.driver import Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
from accellog.acquire.emulator.temperature import TemperaturePath
from accellog.core.errors import InputError
from accellog.core.protocol import parse_protocol, six_position
from accellog.core.rotations import quat_conjugate, quat_multiply, rotate_inverse

ODR = 1000.0
KW = dict(
    accel_lsb_per_g=16384.0,
    gyro_lsb_per_dps=131.0,
    odr_hz=ODR,
    accel_bandwidth_hz=44.8,
    gyro_bandwidth_hz=41.0,
)


def still_z_up(**kw) -> PoseSequenceMotion:
    return PoseSequenceMotion(parse_protocol("+z", 1000.0), start_delay_s=0.0, **kw)


def counts_g(model: SensorModel, n: int, start: int = 0, **kw) -> np.ndarray:
    k = np.arange(start, start + n)
    return model.sample(k / ODR, index=k, **{**KW, **kw}).accel_counts / 16384.0


def test_bias_only_mean_and_noise_density():
    b = np.array([0.05, -0.03, 0.07])
    acc = AccelErrors(bias_g=b, noise_density_g_per_rtHz=300e-6)
    a = counts_g(SensorModel(still_z_up(), acc, seed=4), 200_000)
    sigma = 300e-6 * np.sqrt(np.pi / 2 * 44.8)  # density * sqrt(noise-equivalent bandwidth)
    np.testing.assert_allclose(a.std(axis=0), sigma, rtol=0.04)
    # mean = f + b to within the (correlated) noise: effective samples ~ n (1 - r) / (1 + r)
    r = np.exp(-2 * np.pi * 44.8 / ODR)
    se = sigma / np.sqrt(200_000 * (1 - r) / (1 + r))
    np.testing.assert_allclose(a.mean(axis=0), np.array([0, 0, 1]) + b, atol=5 * se + 1 / 16384)
    # DLPF: consecutive samples correlate like a first-order low-pass at 44.8 Hz
    d = a - a.mean(axis=0)
    lag1 = (d[1:] * d[:-1]).sum(axis=0) / (d * d).sum(axis=0)
    np.testing.assert_allclose(lag1, r, atol=0.02)


def test_noise_is_reproducible_and_independent_of_chunking():
    acc = AccelErrors.datasheet(3)
    m1 = SensorModel(still_z_up(), acc, GyroErrors.datasheet(3), seed=9)
    m2 = SensorModel(still_z_up(), acc, GyroErrors.datasheet(3), seed=9)
    m3 = SensorModel(still_z_up(), acc, GyroErrors.datasheet(3), seed=10)
    whole = counts_g(m1, 9000, start=1000)
    parts = np.concatenate([counts_g(m2, 3, 1000), counts_g(m2, 4997, 1003), counts_g(m2, 4000, 6000)])
    np.testing.assert_array_equal(whole, parts)
    assert not np.array_equal(whole, counts_g(m3, 9000, start=1000))


def test_measurement_equation_term_by_term():
    rng = np.random.default_rng(0)
    e = AccelErrors(
        bias_g=rng.normal(0, 0.05, 3),
        scale=rng.normal(0, 0.02, 3),
        cross_axis=rng.normal(0, 0.01, (3, 3)) * (1 - np.eye(3)),
        temp_bias_g_per_degC=rng.normal(0, 1e-3, 3),
        temp_bias2_g_per_degC2=rng.normal(0, 1e-5, 3),
        temp_scale_per_degC=rng.normal(0, 2e-4, 3),
        temp_scale2_per_degC2=rng.normal(0, 1e-6, 3),
        nonlin2_per_g=rng.normal(0, 1e-3, 3),
        nonlin3_per_g2=rng.normal(0, 1e-3, 3),
        g_cross_per_g=rng.normal(0, 1e-3, (3, 3)),
        time_drift_g_per_s=rng.normal(0, 1e-5, 3),
        warmup_g=rng.normal(0, 0.01, 3),
        warmup_tau_s=120.0,
    )
    f = rng.normal(0, 0.7, (5, 3))
    T = np.array([10.0, 25.0, 30.0, 45.0, 60.0])
    t = np.array([0.0, 10.0, 100.0, 500.0, 3000.0])
    got = e.apply(f, T, t)
    for i in range(5):  # straight from docs/architecture.md, one sample at a time
        fi, dT = f[i], T[i] - 25.0
        u = fi + e.nonlin2_per_g * fi**2 + e.nonlin3_per_g2 * fi**3
        u = u + e.g_cross_per_g @ np.array([fi[0] * fi[1], fi[0] * fi[2], fi[1] * fi[2]])
        S = np.diag(1 + e.scale + e.temp_scale_per_degC * dT + e.temp_scale2_per_degC2 * dT**2) + e.cross_axis
        bias = e.bias_g + e.temp_bias_g_per_degC * dT + e.temp_bias2_g_per_degC2 * dT**2
        bias = bias + e.time_drift_g_per_s * t[i] + e.warmup_g * (1 - np.exp(-t[i] / 120.0))
        np.testing.assert_allclose(got[i], S @ u + bias, rtol=0, atol=1e-13)


def test_saturation_quantisation_and_temperature_counts():
    acc = AccelErrors(bias_g=[3.0, -3.0, 0.0])
    model = SensorModel(still_z_up(), acc, temperature=TemperaturePath.constant(40.0), temp_noise_degC=0.0)
    blk = model.sample(np.arange(5) / ODR, **KW)
    np.testing.assert_array_equal(blk.accel_counts[0], [32767, -32768, 16384])
    assert blk.temp_counts[0] == round((40.0 - 21.0) * 333.87)
    assert blk.accel_counts.dtype == np.int16


def test_local_gravity_and_fixture_tilt_in_truth_not_labels():
    tilt = (1.0, -0.5)
    motion = PoseSequenceMotion(six_position(5.0), move_s=2.0, fixture_tilt_deg=tilt)
    model = SensorModel(motion, local_gravity_mps2=9.797)
    for lab in motion.labels():
        tr = model.truth(np.linspace(lab.start_s, lab.end_s, 7))
        np.testing.assert_allclose(np.linalg.norm(tr.specific_force_g, axis=1), 9.797 / 9.80665)
        np.testing.assert_allclose(tr.omega_dps, 0.0, atol=1e-12)
        ang = np.degrees(np.arccos(tr.specific_force_g @ np.array(lab.up_sensor) / (9.797 / 9.80665)))
        np.testing.assert_allclose(ang, np.hypot(*tilt), rtol=1e-3)  # small-angle tilt off nominal
        nominal = rotate_inverse(np.array(lab.q_sensor_to_world), np.array([0.0, 0, 1]))
        np.testing.assert_allclose(nominal, lab.up_sensor, atol=1e-12)  # labels stay nominal


def test_pose_moves_are_smooth_and_omega_matches_orientation():
    motion = PoseSequenceMotion(parse_protocol("+z,-z,+x@90,-y", 4.0), move_s=2.5, start_delay_s=0.5)
    labels = motion.labels()
    assert [lab.name for lab in labels] == ["+z", "-z", "+x@90", "-y"]
    assert labels[0].start_s == 0.5 and labels[1].start_s == pytest.approx(7.0)
    assert motion.duration_s == pytest.approx(0.5 + 4 * 4.0 + 3 * 2.5)
    t = np.linspace(0, motion.duration_s, 400_001)
    k = motion.kinematics(t)
    dt = t[1] - t[0]
    dq = quat_multiply(quat_conjugate(k.q_sensor_to_world[:-1]), k.q_sensor_to_world[1:])
    w_num = np.degrees(2 * dq[:, 1:] * np.sign(dq[:, :1]) / dt)
    np.testing.assert_allclose(w_num, 0.5 * (k.omega_dps[1:] + k.omega_dps[:-1]), atol=1e-3)
    assert np.abs(np.diff(k.omega_dps, axis=0)).max() < 0.01  # no jumps in rate
    np.testing.assert_array_equal(k.position_m, 0.0)


def test_datasheet_draws_within_figures_and_validation():
    a, b = AccelErrors.datasheet(5), AccelErrors.datasheet(5)
    assert np.array_equal(a.bias_g, b.bias_g) and not np.array_equal(
        a.bias_g, AccelErrors.datasheet(6).bias_g
    )
    assert np.all(np.abs(a.bias_g) <= [0.06, 0.06, 0.08]) and np.all(np.abs(a.scale) <= 0.03)
    assert np.all(np.abs(a.cross_axis) <= 0.02) and np.all(np.diag(a.cross_axis) == 0)
    assert np.all(np.abs(a.temp_bias_g_per_degC) <= 1.5e-3) and np.all(
        np.abs(a.temp_scale_per_degC) <= 2.6e-4
    )
    assert np.all(a.noise_density_g_per_rtHz == 300e-6)
    g = GyroErrors.datasheet(5)
    assert np.all(np.abs(g.bias_dps) <= 5) and np.all(g.noise_density_dps_per_rtHz == 0.01)
    p = AccelErrors.perfect()
    assert all(
        not np.any(getattr(p, f.name)) for f in dataclasses.fields(p) if f.name.endswith(("_g", "scale"))
    )
    with pytest.raises(InputError):
        AccelErrors(cross_axis=np.eye(3))
    with pytest.raises(InputError):
        AccelErrors(bias_g=[1.0, 2.0])


def test_temperature_paths():
    t = np.array([0.0, 100.0, 1e6])
    np.testing.assert_allclose(TemperaturePath.constant(30).degC(t), 30.0)
    np.testing.assert_allclose(TemperaturePath.warmup(20, 40, 100).degC(t), [20, 40 - 20 / np.e, 40])
    np.testing.assert_allclose(TemperaturePath.ramp(25, 0.01).degC(t[:2]), [25, 26])
    np.testing.assert_allclose(
        TemperaturePath.points([0, 10, 20], [25, 35, 30]).degC([-5, 5, 15, 99]), [25, 30, 32.5, 30]
    )
    with pytest.raises(InputError):
        TemperaturePath.points([0, 0], [1, 2])
    with pytest.raises(InputError):
        TemperaturePath.warmup(20, 40, 0)


def test_temperature_effects_reach_the_counts():
    acc = AccelErrors(temp_bias_g_per_degC=[1e-3, 0, 0])
    model = SensorModel(still_z_up(), acc, temperature=TemperaturePath.ramp(25.0, 0.1), temp_noise_degC=0.0)
    blk = model.sample(np.array([0.0, 100.0]), **KW)
    assert blk.accel_counts[1, 0] - blk.accel_counts[0, 0] == round(0.010 * 16384)
    assert blk.temp_counts[1] - blk.temp_counts[0] == pytest.approx(10 * 333.87, abs=1)


def test_session_truth_mapping_with_clock_error():
    clock = SimClock()
    model = SensorModel(PoseSequenceMotion(six_position(3.0), move_s=1.0), AccelErrors(clock_error=0.01))
    chip = EmulatedMpu9250(model, clock)
    drv = Mpu9250(chip, clock_ns=clock.now_ns)
    drv.configure()
    drv.start()
    n = 0
    while n < 15_000:
        clock.sleep(0.02)
        b = drv.read()
        n += b.n
    t_sess = b.t_ns / 1e9
    tr = chip.truth_for_session(t_sess)
    np.testing.assert_array_equal(tr.t_s, t_sess)
    np.testing.assert_allclose(b.accel_counts / 16384, tr.specific_force_g, atol=1 / 16384)
    # sensor time runs 1 % slow against true time; the inverse mapping round-trips
    mt = chip.motion_time_s(t_sess)
    assert (mt[-1] - mt[0]) / (t_sess[-1] - t_sess[0]) == pytest.approx(1.01)
    np.testing.assert_allclose(chip.session_time_s(mt), t_sess, atol=1e-9)
