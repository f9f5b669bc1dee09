"""Each autopilot firmware's run-time thermal correction, written from the firmware sources (not from
accellog's model), in float32 as the firmware computes it.

PX4 (PX4/PX4-Autopilot):
- src/modules/temperature_compensation/TemperatureCompensation.cpp, ``calc_thermal_offsets_3D``:
  delta_temp = measured_temp clipped to [min_temp, max_temp] minus ref_temp;
  offset[i] = x0[i] + x1[i] dT + x2[i] dT^2 + x3[i] dT^3.
- src/lib/sensor_calibration/Accelerometer.hpp, ``Correct``:
  _rotation * ((data - _thermal_offset - _offset).emult(_scale));
  Gyroscope.hpp, ``Correct``: _rotation * (data - _thermal_offset - _offset).
ArduPilot (ArduPilot/ardupilot):
- libraries/AP_InertialSensor/AP_InertialSensor_tempcal.cpp, ``TCal::polynomial_eval``:
  (c[0] + (c[1] + c[2] tdiff) tdiff) tdiff * 1e-6; ``TCal::correct_sensor``: temperature and cal_temp
  constrained to [temp_min, temp_max]; v -= P(temperature - 35); v += P(cal_temp - 35).
- libraries/AP_InertialSensor/AP_InertialSensor_Backend.cpp, ``_rotate_and_correct_accel``: rotate by
  the sensor orientation, tcal correct_accel(temperature, caltemp_accel), accel -= offset,
  accel *= scale per axis, rotate to the board; ``_rotate_and_correct_gyro``: the same rotation,
  correct_gyro(temperature, caltemp_gyro), gyro -= offset.
The board rotation after the correction is the identity here (it is the same for both sides).
"""

from __future__ import annotations

import numpy as np

F32 = np.float32


def param_values(text: str, target: str) -> dict[str, np.float32]:
    """The parameter file as the autopilot loads it: every value a float32."""
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    pairs = [ln.split("\t")[2:4] if target == "px4" else ln.split(",") for ln in rows]
    return {k: F32(float(v)) for k, v in pairs}


def _vec(p: dict, fmt: str) -> np.ndarray:
    return np.array([p[fmt.format(i=i, ax=ax)] for i, ax in enumerate("XYZ")], F32)


def px4_correct(data: np.ndarray, T: np.ndarray, p: dict, sensor: str) -> np.ndarray:
    """calc_thermal_offsets_3D then Accelerometer/Gyroscope::Correct (float32, per sample)."""
    tc, cal = ("TC_A0", "CAL_ACC0") if sensor == "accel" else ("TC_G0", "CAL_GYRO0")
    x = [_vec(p, f"{tc}_X{k}_{{i}}") for k in range(4)]
    off = _vec(p, f"{cal}_{{ax}}OFF")
    scale = _vec(p, f"{cal}_{{ax}}SCALE") if sensor == "accel" else np.ones(3, F32)
    out = np.empty_like(data, dtype=F32)
    for n, (d, t) in enumerate(zip(data.astype(F32), T.astype(F32), strict=True)):
        if t > p[f"{tc}_TMAX"]:
            dt = p[f"{tc}_TMAX"] - p[f"{tc}_TREF"]
        elif t < p[f"{tc}_TMIN"]:
            dt = p[f"{tc}_TMIN"] - p[f"{tc}_TREF"]
        else:
            dt = t - p[f"{tc}_TREF"]
        dt2 = dt * dt
        dt3 = dt2 * dt
        thermal = x[0] + x[1] * dt + x[2] * dt2 + x[3] * dt3
        out[n] = (d - thermal - off) * scale
    return out


def ardupilot_correct(data: np.ndarray, T: np.ndarray, p: dict, sensor: str) -> np.ndarray:
    """TCal::correct_sensor then the offsets (and scale) of _rotate_and_correct_accel/_gyro (float32)."""
    kind = "ACC" if sensor == "accel" else "GYR"
    c = [_vec(p, f"INS_TCAL1_{kind}{k}_{{ax}}") for k in (1, 2, 3)]
    tmin, tmax = p["INS_TCAL1_TMIN"], p["INS_TCAL1_TMAX"]
    cal_temp = min(max(p[f"INS_{kind}1_CALTEMP"], tmin), tmax)
    off = _vec(p, "INS_ACCOFFS_{ax}") if sensor == "accel" else _vec(p, "INS_GYROFFS_{ax}")
    scale = _vec(p, "INS_ACCSCAL_{ax}") if sensor == "accel" else np.ones(3, F32)

    def poly(tdiff):
        return (c[0] + (c[1] + c[2] * tdiff) * tdiff) * tdiff * F32(1.0e-6)

    assert p["INS_TCAL1_ENABLE"] == 1
    out = np.empty_like(data, dtype=F32)
    for n, (d, t) in enumerate(zip(data.astype(F32), T.astype(F32), strict=True)):
        t = min(max(t, tmin), tmax)
        v = d - poly(t - F32(35.0))
        v = v + poly(cal_temp - F32(35.0))
        out[n] = (v - off) * scale
    return out


FIRMWARE = {"px4": px4_correct, "ardupilot": ardupilot_correct}
