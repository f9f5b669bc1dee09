"""sensor_msgs/msg/Imu CDR messages decoded many at a time with numpy (rosbags' deserialize_cdr is
~3 us a message in Python; this is ~0.1 us).

Layout (little-endian CDR, encapsulation 00 01; alignment counted after those 4 bytes), the inverse of
accellog.store.ros2_writer.imu_cdr: stamp sec int32, nanosec uint32, frame_id (uint32 length with the
NUL, bytes, NUL), padding to 8, then 37 float64: orientation (4), orientation_covariance (9),
angular_velocity (3), its covariance (9), linear_acceleration (3), its covariance (9).

Messages of one length and one frame_id length are decoded together through strided views; anything
else (big-endian CDR, a length that does not match the layout, a frame_id without its NUL) is left
to the caller (``None``), which decodes with rosbags.
"""

from __future__ import annotations

import numpy as np

_N_F64 = 37
_GYRO, _ACCEL, _COV_G, _COV_A = 13, 25, 16, 28  # float64 indices of the fields in the 37


def _fields(buf: bytes, n: int, length: int, start: int) -> tuple:
    """Fields of n rows of ``length`` bytes each, the float64 block at byte ``start`` of a row."""

    def col(offset: int, dtype: str, width: int) -> np.ndarray:
        return np.ndarray(
            (n, width), dtype=dtype, buffer=buf, offset=offset, strides=(length, np.dtype(dtype).itemsize)
        )

    sec = col(4, "<i4", 1)[:, 0].astype(np.int64)
    nsec = col(8, "<u4", 1)[:, 0].astype(np.int64)
    gyro = col(start + 8 * _GYRO, "<f8", 3).astype(np.float64)
    accel = col(start + 8 * _ACCEL, "<f8", 3).astype(np.float64)
    cov_a = col(start + 8 * _COV_A, "<f8", 9)[0].astype(np.float64)
    cov_g = col(start + 8 * _COV_G, "<f8", 9)[0].astype(np.float64)
    return sec * 1_000_000_000 + nsec, accel, gyro, cov_a, cov_g


def decode_imu(raws: list) -> tuple | None:
    """(stamp ns (n,) int64, accel m/s^2 (n,3), gyro rad/s (n,3), frame ids, first covariances (9,)
    linear acceleration and angular velocity) of raw Imu CDR messages, or None when they are not all
    little-endian messages of one length and one frame_id length (then decode them one by one)."""
    n = len(raws)
    if n == 0:
        return None
    length = len(raws[0])
    if length < 16:
        return None
    buf = b"".join(raws)
    if len(buf) != n * length:
        return None
    rows = np.ndarray((n, length), dtype=np.uint8, buffer=buf)
    name_len = int.from_bytes(raws[0][12:16], "little")
    start = 4 + (12 + name_len + 7) // 8 * 8
    if (
        start + 8 * _N_F64 != length
        or name_len < 1
        or not (rows[:, 0] == 0).all()
        or not (rows[:, 1] == 1).all()
        or not (rows[:, 12:16] == rows[0, 12:16]).all()
        or not (rows[:, 15 + name_len] == 0).all()
    ):
        return None
    names = rows[:, 16 : 15 + name_len]
    same = (names == names[0]).all()
    frames = {bytes(names[0]).decode()} if same else {bytes(r).decode() for r in np.unique(names, axis=0)}
    stamp, accel, gyro, cov_a, cov_g = _fields(buf, n, length, start)
    return stamp, accel, gyro, frames, cov_a, cov_g
