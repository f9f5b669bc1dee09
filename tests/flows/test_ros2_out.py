"""ROS 2 out: `accellog apply --ros2` written with rosbags, read back with an independent decoder
(mcap + mcap-ros2-support) and compared with the calibration applied in memory."""

from __future__ import annotations

import dataclasses

import numpy as np
from support.ros2_bags import decode

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.flows.ros2_out import white_noise_var, write_ros2
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session


def _ok(argv, capsys):
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    assert rc == 0, cap.err


def test_apply_ros2_round_trip_emulated(tmp_path, capsys):
    sim, cal, cop, bag = (tmp_path / n for n in ("sim.mcap", "cal.json", "cal_copy.mcap", "out.mcap"))
    sc = Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=11)
    sc.temperature = {"kind": "ramp", "T0": 20.0, "rate_degC_per_s": 0.2}
    simulate(sc, sim)
    _ok(["fit", sim, "-o", cal], capsys)
    _ok(["apply", sim, "--cal", cal, "-o", cop, "--ros2", bag], capsys)
    s, c = read_session(sim), load_calibration(cal)
    msgs = decode(bag)
    imu = msgs["/imu/data"]
    assert len(imu) == s.n
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in imu])
    assert np.array_equal(acc, c.correct_mps2(s))  # doubles in CDR: exact
    stamp = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in imu])
    assert np.array_equal(stamp, s.meta.start_time_unix_ns + np.round(s.t_s * 1e9).astype(np.int64))
    assert all(m.orientation_covariance[0] == -1.0 for m in imu)
    cov = np.array([m.linear_acceleration_covariance for m in imu]).reshape(-1, 3, 3)
    assert np.allclose(cov, cov.transpose(0, 2, 1))
    noise = white_noise_var(acc)
    diag = np.diagonal(cov, axis1=1, axis2=2)
    assert np.all(diag > noise) and np.all(diag < noise + 1e-3)  # + parameter part, (m/s^2)^2
    w = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in imu])
    if c.gyro is not None:
        ref = np.deg2rad(c.gyro.correct(s.gyro_dps, s.temp_degC))
    else:
        ref = np.deg2rad(s.gyro_dps)
    assert np.allclose(w, ref, rtol=0, atol=1e-15)
    temp = msgs["/imu/temperature"]
    assert temp[0].temperature == s.temp_degC[0] and 0 < len(temp) <= s.n // 15
    # magnetometer (the emulated session has none: add a 20 Hz field in uT) -> tesla
    rng = np.random.default_rng(0)
    mag_t = np.arange(0, s.t_s[-1], 0.05)
    s2 = dataclasses.replace(
        s, mag_t_s=mag_t, mag_uT=np.array([20.0, -5.0, 40.0]) + rng.normal(0, 0.3, (mag_t.size, 3))
    )
    write_ros2(s2, c, tmp_path / "mag.mcap")
    got = decode(tmp_path / "mag.mcap")["/imu/mag"]
    mag = np.array([[m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z] for m in got])
    assert np.allclose(mag, s2.mag_uT * 1e-6, rtol=1e-15, atol=0)
