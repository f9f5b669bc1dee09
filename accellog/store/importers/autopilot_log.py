"""The session of one IMU read from an autopilot's log (accellog.store.importers.ulog for PX4 ULog,
accellog.store.importers.dataflash for ArduPilot DataFlash): the formats state their units (m/s^2,
rad/s, degC); the values are checked at the door as for CSV (accellog.store.importers.csv_checks) and
converted with g0 = 9.80665 (accel_g = a / g0, gyro_dps = w 180/pi).

The device id the autopilot gives the sensor (PX4 ``device_id``, ArduPilot ``INS_ACC_ID``) is kept in
meta.extra and names the session's device (meta.serial '<format>-device-<id>'), so sessions of two
sensors are told apart; a log without temperature is imported with a one-line note.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.notices import note
from accellog.core.session import Session, SessionMeta
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.importers.csv_checks import UnitsError, check_accel, check_gyro
from accellog.store.importers.csv_options import CsvOptions

CHECK_ROWS = 2000
"""Rows the unit checks judge (the first ones, as for CSV)."""


def _check_units(path, acc, gyr, imu: str) -> None:
    """csv_checks' tests on the first rows, in the units the format states (m/s^2, rad/s); the CSV
    flags of their hints do not apply to a log, so the message ends with what does. The time unit
    is the format's (us) and loggers subsample topics (PX4's default profile: sensor_accel at 1 Hz),
    so the rate is not judged."""
    opts = CsvOptions.make(unit="m/s^2", gyro_unit="rad/s")
    try:
        check_accel(path, acc[:CHECK_ROWS], opts)
        if gyr is not None:
            check_gyro(path, gyr[:CHECK_ROWS], opts)
    except UnitsError as exc:
        what = str(exc).removeprefix(f"{exc.where}: ").split(": use ")[0]
        raise UnitsError(f"{imu}: {what} (the format states m/s^2 and rad/s): a damaged log, or "
                         "another --imu?", where=str(path)) from None  # fmt: skip


def log_session(
    path: str | Path,
    fmt: str,
    t_us: np.ndarray,
    accel_mps2: np.ndarray,
    gyro_rps: np.ndarray | None,
    temp_degC: np.ndarray | None,
    *,
    accel_id: int | None,
    gyro_id: int | None,
    extra: dict[str, str],
) -> Session:
    """Session of one IMU: t_us (N,) microseconds since boot, accel (N,3) m/s^2, gyro (N,3) rad/s or
    None, temperature (N,) degC or None (all-NaN counts as none); units and rate checked."""
    where = str(path)
    t_us = np.asarray(t_us, np.int64)
    if t_us.shape[0] < 2:
        raise InputError(
            f"{extra.get('imu', 'IMU')}: {t_us.shape[0]} sample(s); need at least two", where=where
        )
    order = np.argsort(t_us, kind="stable")
    t_us, acc = t_us[order], np.asarray(accel_mps2, float)[order]
    gyr = None if gyro_rps is None else np.asarray(gyro_rps, float)[order]
    temp = None if temp_degC is None else np.asarray(temp_degC, float)[order]
    if temp is not None and not np.isfinite(temp).any():
        temp = None
    step = float(np.median(np.diff(t_us)))
    _check_units(path, acc, gyr, extra.get("imu", "IMU"))
    if temp is None:
        note(f"{Path(path).name}: the log has no IMU temperature: temperature terms cannot be fitted from it")
    t_s = (t_us - t_us[0]) / 1e6
    ids = {"accel_device_id": accel_id, "gyro_device_id": gyro_id}
    extra = {
        **extra,
        "source_unit": "m/s^2, rad/s, degC",
        **{k: str(v) for k, v in ids.items() if v is not None},
    }
    meta = SessionMeta(
        source=f"import:{fmt}",
        chip="unknown",
        sample_rate_hz=1e6 / step if step > 0 else 0.0,
        serial="" if accel_id is None else f"{fmt}-device-{accel_id}",
        extra=extra,
    )
    return Session(
        meta=meta,
        t_s=t_s,
        sample_index=np.arange(t_s.shape[0], dtype=np.int64),
        accel_g=acc / STANDARD_GRAVITY_MPS2,
        gyro_dps=None if gyr is None else np.rad2deg(gyr),
        temp_degC=temp,
    )
