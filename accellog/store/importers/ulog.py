"""PX4 ULog (.ulg) -> Session, with pyulog: one IMU, ``sensor_accel`` instance N (multi_id) with its
``temperature`` (degC) and ``device_id``, and the ``sensor_gyro`` of the same device (else the same
instance) interpolated onto the accelerometer's time stamps (``timestamp_sample``, else
``timestamp``: microseconds since boot). x, y, z in m/s^2 and rad/s, in the driver-rotated sensor
axes PX4 calibrates in (CAL_ACC*, TC_A*). A log with only ``sensor_combined`` (older PX4, or a
reduced logging profile) gives the first IMU without temperature or device id.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.store.importers.autopilot_log import log_session

AXES = ("x", "y", "z")


def _read(path: Path):
    try:
        from pyulog import ULog
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError("importing ULog needs pyulog (pip install pyulog)") from None
    if not path.is_file():
        raise InputError("no such file", where=str(path))
    try:
        return ULog(str(path), ["sensor_accel", "sensor_gyro", "sensor_combined"])
    except Exception as exc:  # pyulog raises bare exceptions on foreign or damaged files
        raise InputError(f"not a readable ULog file ({type(exc).__name__}: {exc})", where=str(path)) from None


def _stamp(d) -> np.ndarray:
    return np.asarray(d.data.get("timestamp_sample", d.data["timestamp"]), np.int64)


def import_ulog(path: str | Path, *, imu: int = 0) -> Session:
    """Instance ``imu`` of the log's sensor_accel (module docstring) -> Session; InputError naming the
    instances there are when it is missing."""
    path = Path(path)
    log = _read(path)
    accels = {d.multi_id: d for d in log.data_list if d.name == "sensor_accel"}
    gyros = {d.multi_id: d for d in log.data_list if d.name == "sensor_gyro"}
    if not accels:
        return _combined(path, log, imu)
    if imu not in accels:
        raise InputError(f"--imu {imu}: the log has sensor_accel instances {sorted(accels)}", where=str(path))
    a = accels[imu]
    t = _stamp(a)
    acc = np.column_stack([a.data[k] for k in AXES])
    acc_id = int(a.data["device_id"][0]) if "device_id" in a.data else None
    match = [g for g in gyros.values() if "device_id" in g.data and int(g.data["device_id"][0]) == acc_id]
    g = match[0] if match else gyros.get(imu)
    gyr, gyr_id = None, None
    if g is not None and len(g.data["timestamp"]) >= 2:
        tg = _stamp(g)
        gyr = np.column_stack([np.interp(t, tg, g.data[k]) for k in AXES])
        gyr_id = int(g.data["device_id"][0]) if "device_id" in g.data else None
    temp = np.asarray(a.data["temperature"], float) if "temperature" in a.data else None
    extra = {"imu": f"sensor_accel {imu}", "ulog_topic": f"sensor_accel/{imu}",
             "ulog_gyro_topic": "" if g is None else f"sensor_gyro/{g.multi_id}"}  # fmt: skip
    return log_session(path, "ulog", t, acc, gyr, temp, accel_id=acc_id, gyro_id=gyr_id, extra=extra)


def _combined(path: Path, log, imu: int) -> Session:
    """The first IMU from sensor_combined (no temperature, no device id)."""
    comb = [d for d in log.data_list if d.name == "sensor_combined"]
    if not comb:
        raise InputError("the log has no sensor_accel, sensor_gyro or sensor_combined topic", where=str(path))
    if imu != 0:
        raise InputError(
            f"--imu {imu}: the log has only sensor_combined (the first IMU, --imu 0)", where=str(path)
        )
    d = comb[0].data
    t = np.asarray(d["timestamp"], np.int64) + np.asarray(d["accelerometer_timestamp_relative"], np.int64)
    acc = np.column_stack([d[f"accelerometer_m_s2[{i}]"] for i in range(3)])
    gyr = np.column_stack([np.interp(t, d["timestamp"], d[f"gyro_rad[{i}]"]) for i in range(3)])
    extra = {"imu": "sensor_combined", "ulog_topic": "sensor_combined"}
    return log_session(path, "ulog", t, acc, gyr, None, accel_id=None, gyro_id=None, extra=extra)
