"""Strapdown integration: gyro -> orientation, specific force -> world acceleration -> velocity -> position.

Orientation (sensor -> world, w,x,y,z): q_{k+1} = q_k * dq_k with the body-frame increment
dq_k = exp(phi_k / 2),  phi_k = (w_k + w_{k+1}) dt_k / 2 + (w_k x w_{k+1}) dt_k^2 / 12   (rad)
(trapezoid rotation vector plus the two-sample coning term: third order per step for a rate
linear in time). The cumulative product q_0 * dq_0 * ... * dq_{k-1} is a parallel prefix scan
(Hillis-Steele: ceil(log2 N) vectorised quaternion products), not a Python loop.

Navigation (world z up): a_k = R(q_k) f_k g0 + (0, 0, -g_local)  (m/s^2; f in g, g0 = 9.80665)
v = v0 + cumtrapz(a, t),  p = p0 + cumtrapz(v, t)  over the recorded (possibly uneven) t (s).
For a perfect sensor the track error is the integration error: O(dt^2) in the attitude (times the
path length for position) plus the trapezoid error ~ (T dt^2 / 12) max|da/dt| in velocity.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from accellog.core.errors import InputError
from accellog.core.rotations import (
    prefix_quat_product,
    quat_from_axis_angle,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
    rotate,
)
from accellog.core.timeseries import check_time, cumtrapz
from accellog.core.units import STANDARD_GRAVITY_MPS2

Corrector = Callable[[np.ndarray], np.ndarray]
"""A calibration's correction: (N,3) reading -> (N,3) corrected reading (same units)."""


@dataclass
class Track:
    """A navigated track: t_s (N,) s, q (N,4) sensor->world, velocity_mps / position_m (N,3) world."""

    t_s: np.ndarray
    q: np.ndarray
    velocity_mps: np.ndarray
    position_m: np.ndarray
    name: str = ""


def integrate_gyro(t_s: np.ndarray, gyro_dps: np.ndarray, q0) -> np.ndarray:
    """Orientation (N,4) from body rates gyro_dps (N,3, deg/s) at times t_s (N,), starting at q0."""
    t = np.asarray(t_s, float)
    w = np.deg2rad(np.asarray(gyro_dps, float))
    dt = np.diff(t)[:, None]
    phi = 0.5 * (w[:-1] + w[1:]) * dt + np.cross(w[:-1], w[1:]) * dt**2 / 12.0
    dq = np.concatenate([np.asarray(q0, float)[None, :], quat_from_rotvec(phi)])
    return quat_normalize(prefix_quat_product(dq))


def tilt_quaternion(accel_g: np.ndarray, yaw_rad: float = 0.0) -> np.ndarray:
    """q = q_z(yaw) q_y(pitch) q_x(roll) from the mean static reading (g).

    At rest f = R^T (0,0,1), i.e. f = (-sin th, sin phi cos th, cos phi cos th), so
    roll = atan2(f_y, f_z), pitch = atan2(-f_x, hypot(f_y, f_z)); yaw is not observable (given).
    """
    f = np.asarray(accel_g, float).reshape(-1, 3).mean(axis=0)
    roll = np.arctan2(f[1], f[2])
    pitch = np.arctan2(-f[0], np.hypot(f[1], f[2]))
    qz = quat_from_axis_angle([0.0, 0.0, 1.0], yaw_rad)
    qy = quat_from_axis_angle([0.0, 1.0, 0.0], pitch)
    qx = quat_from_axis_angle([1.0, 0.0, 0.0], roll)
    return quat_multiply(qz, quat_multiply(qy, qx))


def yaw_of(q) -> float:
    """Heading (rad) of the sensor x axis projected on the world horizontal, for q (4,)."""
    x = rotate(np.asarray(q, float), np.array([1.0, 0.0, 0.0]))
    return float(np.arctan2(x[1], x[0]))


def initial_orientation(
    t_s: np.ndarray, accel_g: np.ndarray, *, window_s: float = 1.0, yaw_rad: float = 0.0
) -> np.ndarray:
    """q0 from the first window_s seconds (assumed static): roll/pitch from the accel, yaw given."""
    t = np.asarray(t_s, float)
    sel = t <= t[0] + window_s
    if sel.sum() < 2:
        raise InputError(f"initial static window of {window_s} s holds fewer than 2 samples")
    return tilt_quaternion(np.asarray(accel_g)[sel], yaw_rad)


def strapdown(
    t_s: np.ndarray,
    accel_g: np.ndarray,
    gyro_dps: np.ndarray,
    *,
    q0,
    local_gravity_mps2: float = STANDARD_GRAVITY_MPS2,
    v0=0.0,
    p0=0.0,
    correct_accel: Corrector | None = None,
    correct_gyro: Corrector | None = None,
    name: str = "",
) -> Track:
    """Integrate one track. accel_g (N,3) specific force in g, gyro_dps (N,3) deg/s, sensor frame.

    q0: initial orientation (4,) sensor->world; v0 (m/s), p0 (m): initial velocity / position (world).
    correct_accel / correct_gyro: optional calibration corrections applied to the readings first.
    Times may be uneven but must increase strictly.
    """
    t = np.asarray(t_s, float)
    a = np.asarray(accel_g, float)
    w = np.asarray(gyro_dps, float)
    if t.ndim != 1 or a.shape != (t.size, 3) or w.shape != (t.size, 3):
        raise InputError(
            f"strapdown needs t (N,), accel (N,3), gyro (N,3); got {t.shape}, {a.shape}, {w.shape}"
        )
    check_time(t)
    if not (np.isfinite(a).all() and np.isfinite(w).all()):
        raise InputError("accel or gyro holds NaN/inf samples")
    if correct_accel is not None:
        a = np.asarray(correct_accel(a), float)
    if correct_gyro is not None:
        w = np.asarray(correct_gyro(w), float)
    q = integrate_gyro(t, w, q0)
    acc = rotate(q, a * STANDARD_GRAVITY_MPS2)
    acc[:, 2] -= local_gravity_mps2
    vel = np.asarray(v0, float) + cumtrapz(t, acc)
    pos = np.asarray(p0, float) + cumtrapz(t, vel)
    return Track(t_s=t, q=q, velocity_mps=vel, position_m=pos, name=name)
