"""`accellog magcal`: the magnetometer calibration of a session that rotates the sensor.

Reads the session, takes its AK8963 readings (uT, after ASA), fits ``calibrate.magnetometer`` and gives it
the drivers of the residual diagnosis: time, die temperature and rotation rate |omega| (deg/s) at the
magnetometer times (linear interpolation of the IMU samples).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from accellog.calibrate.mag.magnetometer import MagCalibration, fit_magnetometer
from accellog.core.errors import InputError
from accellog.core.session import Session


def mag_drivers(s: Session) -> dict[str, tuple[np.ndarray, str]]:
    """Driver signals at the magnetometer sample times."""
    t = s.mag_t_s
    if t is None:
        raise InputError("the session has no magnetometer samples")
    d: dict[str, tuple[np.ndarray, str]] = {"time": (t, "s")}
    if s.temp_degC is not None:
        d["temperature"] = (np.interp(t, s.t_s, s.temp_degC), "degC")
    if s.gyro_dps is not None:
        d["rotation rate"] = (np.interp(t, s.t_s, np.linalg.norm(s.gyro_dps, axis=1)), "deg/s")
    return d


def run_magcal(
    path: str | os.PathLike, form: str = "sym", expected_field_uT: float | None = None
) -> tuple[MagCalibration, Session]:
    """Fit the magnetometer of the session at ``path``; returns the calibration and the session."""
    from accellog.store.source import open_source

    s = open_source(path, what="magcal").whole()
    if s.mag_uT is None or s.mag_t_s is None or s.mag_uT.shape[0] == 0:
        raise InputError(
            "session has no magnetometer samples (record with the AK8963 enabled)", where=str(Path(path))
        )
    try:
        return fit_magnetometer(
            s.mag_uT, form, expected_field_uT=expected_field_uT, drivers=mag_drivers(s)
        ), s
    except InputError as exc:
        raise InputError(str(exc), where=str(path)) from None
