"""Calibrated data as a ROS 2 bag: sensor_msgs/msg/Imu (+ Temperature, MagneticField) with honest
covariances (``accellog apply SESSION --cal CAL --ros2 OUT.mcap``).

Per sample, in SI units (REP 103):

    linear_acceleration = f * mps2_per_unit                     (m/s^2, f = cal.correct(reading))
    linear_acceleration_covariance = Sigma_noise + J C J^T      ((m/s^2)^2, row-major 3x3)

J = d(linear_acceleration)/d(theta) at the sample (central differences, steps 1e-3 sigma), C the
calibration's parameter covariance: the parameter part depends on the orientation, so it is per
sample. Sigma_noise is diagonal, the white-noise variance of each axis estimated from the session
itself with first differences, robustly: var = (1.4826 MAD(diff))^2 / 2 (slow motion and drift cancel
in the difference). angular_velocity: gyro corrected with cal.gyro when present (bias, temperature
bias, matrix), covariance = noise (same estimator) + bias variance (+ temperature-bias variance
times (T - T_ref)^2); without cal.gyro the raw gyro with its noise only. orientation_covariance[0]
= -1 (no orientation estimate). Temperature is written at <= 10 Hz, magnetometer at its own rate
(tesla; covariance zero = unknown).

Topics and frame_id: those of the bag the session came from (``accellog import ros2`` keeps them in
meta.extra), so a calibrated bag replaces the raw one in a launch file; --topic / --frame-id override.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.core.session import Session

CHUNK = 65536


@dataclass
class Ros2Export:
    """What was written; covariances are the medians over the session (per-sample ones are in the bag)."""

    path: str
    topic: str
    frame_id: str
    imu_messages: int
    temperature_messages: int
    mag_messages: int
    accel_noise_var_mps2sq: list[float]
    accel_param_var_mps2sq: list[float]
    gyro_noise_var_radps_sq: list[float]
    gyro_calibrated: bool

    def to_dict(self) -> dict:
        return asdict(self)


def white_noise_var(x: np.ndarray) -> np.ndarray:
    """(k,) white-noise variance per column from first differences: (1.4826 MAD(diff))^2 / 2."""
    d = np.diff(np.asarray(x, float), axis=0)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return (1.4826 * mad) ** 2 / 2.0


def param_cov_mps2(cal: Calibration, meas_g: np.ndarray, drivers: dict) -> np.ndarray:
    """(n,3,3) J C J^T in (m/s^2)^2 at each reading (central differences over theta)."""
    theta, C = cal.theta, cal.cov
    h = np.where(cal.sigma > 0, cal.sigma * 1e-3, 1e-9)
    model = cal.model
    J = np.empty((meas_g.shape[0], 3, theta.shape[0]))
    for k in range(theta.shape[0]):
        tp, tm = theta.copy(), theta.copy()
        tp[k] += h[k]
        tm[k] -= h[k]
        J[:, :, k] = (model.correct(tp, meas_g, drivers) - model.correct(tm, meas_g, drivers)) / (2 * h[k])
    J *= cal.mps2_per_unit
    return np.einsum("nik,kl,njl->nij", J, C, J)


def _gyro(cal: Calibration, s: Session):
    """Corrected gyro (n,3) deg/s and the parameter variance (n,3) (deg/s)^2, or raw and zeros."""
    if s.gyro_dps is None:
        return np.zeros((s.n, 3)), np.zeros((s.n, 3)), False
    g = cal.gyro
    if g is None:
        return s.gyro_dps, np.zeros((s.n, 3)), False
    w = g.correct(s.gyro_dps, s.temp_degC)
    var = np.broadcast_to(np.nan_to_num(g.bias_sigma_dps) ** 2, (s.n, 3)).copy()
    if s.temp_degC is not None and np.isfinite(g.temp_bias_sigma_dps_per_degC).all():
        dT = (s.temp_degC - g.t_ref_degC)[:, None]
        var += (g.temp_bias_sigma_dps_per_degC * dT) ** 2
    return w, var, True


def ros2_names(
    s: Session, topic: str | None = None, frame_id: str | None = None
) -> tuple[str, str, str, str]:
    """(IMU topic, temperature topic, magnetometer topic, frame_id): the given ones, else those of the
    bag the session was imported from (meta.extra ros2_*), else /imu/data, <namespace>/temperature,
    <namespace>/mag and imu_link."""
    from accellog.store.ros2_writer import IMU_TOPIC

    ex = s.meta.extra
    frames = [f for f in str(ex.get("ros2_frame_id", "")).split(",") if f]
    frame_id = frame_id or (frames[0] if len(frames) == 1 else "imu_link")
    kept = topic is None or topic == ex.get("ros2_topic")
    topic = topic or ex.get("ros2_topic") or IMU_TOPIC
    ns = topic.rsplit("/", 1)[0] if topic.count("/") > 1 else topic
    temp = (ex.get("ros2_temperature_topic") if kept else None) or f"{ns}/temperature"
    mag = (ex.get("ros2_mag_topic") if kept else None) or f"{ns}/mag"
    return topic, temp, mag, frame_id


def write_ros2(
    s: Session,
    cal: Calibration,
    out: str | Path,
    *,
    topic: str | None = None,
    frame_id: str | None = None,
    progress=None,
) -> Ros2Export:
    """Write the calibrated session as a ROS 2 bag (see the module docstring); returns a summary.
    topic, frame_id: default the input bag's (``ros2_names``); progress(done, total): called per chunk."""
    from accellog.calibrate.model.session_drivers import session_drivers
    from accellog.store.ros2_writer import Ros2BagWriter

    topic, temp_topic, mag_topic, frame_id = ros2_names(s, topic, frame_id)

    f_mps2 = cal.correct_mps2(s)
    drivers = dict(session_drivers(s, cal.model.required_drivers))
    noise_a = white_noise_var(f_mps2)
    w_dps, wvar_dps, gyro_cal = _gyro(cal, s)
    noise_g = white_noise_var(np.deg2rad(w_dps))
    stamp = int(s.meta.start_time_unix_ns) + np.round(s.t_s * 1e9).astype(np.int64)
    meta = {
        "accellog_source": s.path or s.meta.source,
        "accellog_calibration": cal.path or "",
        "accellog_covariance": "noise (first differences) + J C J^T of the calibration parameters",
    }
    pvar = []
    with Ros2BagWriter(out, frame_id=frame_id, metadata=meta) as w:
        for a in range(0, s.n, CHUNK):
            b = min(a + CHUNK, s.n)
            drv = {k: v[a:b] for k, v in drivers.items()}
            ca = param_cov_mps2(cal, s.accel_g[a:b], drv)
            pvar.append(np.median(np.diagonal(ca, axis1=1, axis2=2), axis=0))
            ca[:, [0, 1, 2], [0, 1, 2]] += noise_a
            cg = np.zeros((b - a, 3, 3))
            cg[:, [0, 1, 2], [0, 1, 2]] = np.deg2rad(1.0) ** 2 * wvar_dps[a:b] + noise_g
            w.write_imu(stamp[a:b], f_mps2[a:b], np.deg2rad(w_dps[a:b]), ca.reshape(-1, 9), cg.reshape(-1, 9),
                        topic=topic)  # fmt: skip
            if progress is not None:
                progress(b, s.n)
        n_temp = n_mag = 0
        if s.temp_degC is not None:
            dt = float(np.median(np.diff(s.t_s))) if s.n > 1 else 0.1
            step = max(1, round(0.1 / dt)) if dt > 0 else 1
            w.write_temperature(stamp[::step], s.temp_degC[::step], topic=temp_topic)
            n_temp = len(stamp[::step])
        if s.mag_t_s is not None and s.mag_uT is not None and s.mag_t_s.shape[0]:
            mstamp = int(s.meta.start_time_unix_ns) + np.round(s.mag_t_s * 1e9).astype(np.int64)
            w.write_mag(mstamp, s.mag_uT * 1e-6, topic=mag_topic)
            n_mag = int(mstamp.shape[0])
    return Ros2Export(
        path=str(out),
        topic=topic,
        frame_id=frame_id,
        imu_messages=s.n,
        temperature_messages=n_temp,
        mag_messages=n_mag,
        accel_noise_var_mps2sq=noise_a.tolist(),
        accel_param_var_mps2sq=np.median(np.array(pvar), axis=0).tolist(),
        gyro_noise_var_radps_sq=noise_g.tolist(),
        gyro_calibrated=gyro_cal,
    )
