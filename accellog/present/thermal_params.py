"""The temperature model of a calibration in the autopilots' thermal parameters (PX4 TC_A0_*/TC_G0_*,
ArduPilot INS_TCAL1_*), consistent with the offsets and scales of accellog.present.exports.

accellog's bias polynomial about T_ref, in the driver-rotated axes R (accellog.present.export_frames):

    p_a(T) = g0 R (bT dT + bT2 dT^2)        (m/s^2),    dT = T - T_ref        (accelerometer)
    p_g(T) = R (pi/180) (b_T dT + b_T2 dT^2) (rad/s),  dT = T - T_ref,g      (gyro)

so that a = K_R (R r - o_R - p_a(T)) and w = R w_meas - gb_R - p_g(T) (gyro matrix dropped).

PX4 (``TemperatureCompensation::calc_thermal_offsets_3D``; ``calibration::Accelerometer::Correct``:
rotation * ((data - thermal_offset - offset) .* scale); Gyroscope: data - thermal_offset - offset):
thermal = X0 + X1 dT + X2 dT^2 + X3 dT^3 with dT = clamp(T, TMIN, TMAX) - TREF, so X0 = 0 (as PX4's
own accel fit), X1, X2 = the coefficients of p, X3 = 0, TREF = T_ref, CAL_ACC0_*OFF = o_R at TREF.

ArduPilot (``AP_InertialSensor::TCal::correct_sensor``, then ``_rotate_and_correct_accel``:
(accel - offset) .* scale): accel -= q(T' - 35) - q(Tc' - 35), q(x) = (c1 x + c2 x^2 + c3 x^3) 1e-6,
T' and Tc' = CALTEMP clamped to TMIN..TMAX. With q_k the coefficients of p re-expanded about 35 degC
(p(T) = q0 + q(T - 35)) and CALTEMP = T_ref clamped to the range, INS_ACCOFFS = o_R + p_a(CALTEMP)
(the offset at CALTEMP) gives (r - o_R - p_a(T')) .* scale: the model. Gyro alike (INS_GYROFFS,
INS_GYR1_CALTEMP); TMIN/TMAX are shared by accelerometer and gyro.

TMIN..TMAX is the fitted temperature span (TemperatureInfo range; T_ref +- 10 degC when the
calibration did not record one, and the export says so). Both firmwares hold the correction at its
end value outside the span; PX4 republishes the offsets only after > 1 degC of change
(``update_offsets_accel``/``_gyro``), which leaves up to max|dp/dT| x 1 degC between updates.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0
from accellog.present.export_frames import bias_polynomial_g, linear_form, temperature_span

HELD_TERMS = ("temp_bias", "temp_bias2")
"""Library terms both autopilots hold exactly (a bias polynomial in temperature, order <= 3)."""
ARDUPILOT_T_REF_DEGC = 35.0
"""ArduPilot's fixed reference of the INS_TCAL polynomials (TEMP_REFERENCE)."""
ARDUPILOT_SCALE = 1e6
"""INS_TCAL coefficients are stored x 1e6 (SCALE_FACTOR)."""
PX4_STEP_DEGC = 1.0
"""PX4 republishes thermal offsets after more than this change of temperature (degC)."""


@dataclass(frozen=True)
class ThermalModel:
    """Bias polynomials in the rotated axes: coefficients (3 orders k = 1..3, 3 axes) of (T - t_ref)^k."""

    accel_mps2: np.ndarray
    """m/s^2 / degC^k, zero when the model has no temperature bias."""
    accel_t_ref_degC: float
    gyro_rps: np.ndarray
    """rad/s / degC^k, zero when the gyro has no temperature bias (or no gyro)."""
    gyro_t_ref_degC: float
    span_degC: tuple[float, float]
    """TMIN, TMAX (degC)."""
    span_observed: bool
    """True: the fitted span; False: T_ref +- 10 degC (the calibration did not record its range)."""

    @property
    def has_accel(self) -> bool:
        return bool(np.any(self.accel_mps2))

    @property
    def has_gyro(self) -> bool:
        return bool(np.any(self.gyro_rps))


def thermal_model(cal: Calibration, R: np.ndarray) -> ThermalModel | None:
    """The calibration's bias polynomials in the axes R (3x3) rotates to; None without temperature terms."""
    acc = G0 * np.asarray(bias_polynomial_g(cal, HELD_TERMS)) @ R.T
    g = cal.gyro
    gyr = np.zeros((3, 3))
    if g is not None:
        gyr[:2] = np.deg2rad(g.temp_poly_dps) @ R.T  # b_T, b_T2 per order, rotated
    if not (np.any(acc) or np.any(gyr)):
        return None
    span, observed = temperature_span(cal)
    return ThermalModel(
        accel_mps2=acc,
        accel_t_ref_degC=float(cal.model.t_ref_degC),
        gyro_rps=gyr,
        gyro_t_ref_degC=float(g.t_ref_degC) if g is not None else float(cal.model.t_ref_degC),
        span_degC=(float(span[0]), float(span[1])),
        span_observed=observed,
    )


def poly_eval(c: np.ndarray, x: np.ndarray | float) -> np.ndarray:
    """sum_k c[k-1] x^k, k = 1..3, per axis: (3,) for a scalar x, (n,3) for an (n,) x."""
    x = np.asarray(x, float)
    return np.multiply.outer(x, c[0]) + np.multiply.outer(x**2, c[1]) + np.multiply.outer(x**3, c[2])


def shifted(c: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray]:
    """(q0 (3,), q (3 orders, 3 axes)) with sum_k c_k (y + d)^k = q0 + sum_k q_k y^k (binomial)."""
    full = np.vstack([np.zeros(3), c])  # orders 0..3
    out = np.zeros((4, 3))
    for n in range(4):
        for j in range(n + 1):
            out[j] += full[n] * comb(n, j) * d ** (n - j)
    return out[0], out[1:]


def px4_values(tm: ThermalModel, acc_id: int | None, gyr_id: int | None) -> dict:
    """TC_A_ENABLE, TC_A0_* and TC_G_ENABLE, TC_G0_* (for the sensors that have a temperature bias)."""
    vals: dict = {}
    for kind, c, t_ref, dev in (("A", tm.accel_mps2, tm.accel_t_ref_degC, acc_id),
                                ("G", tm.gyro_rps, tm.gyro_t_ref_degC, gyr_id)):  # fmt: skip
        if not np.any(c):
            continue
        vals[f"TC_{kind}_ENABLE"] = 1
        if dev is not None:
            vals[f"TC_{kind}0_ID"] = dev
        for k in range(4):
            for i in range(3):
                vals[f"TC_{kind}0_X{k}_{i}"] = 0.0 if k == 0 else float(c[k - 1, i])
        vals[f"TC_{kind}0_TREF"] = t_ref
        vals[f"TC_{kind}0_TMIN"], vals[f"TC_{kind}0_TMAX"] = tm.span_degC
    return vals


def ardupilot_values(tm: ThermalModel, o_mps2: np.ndarray, gb_rps: np.ndarray | None):
    """(INS_TCAL1_* and INS_ACC1_CALTEMP / INS_GYR1_CALTEMP values, offsets at CALTEMP (m/s^2),
    gyro offsets at CALTEMP (rad/s) or None)."""
    lo, hi = tm.span_degC
    vals: dict = {"INS_TCAL1_ENABLE": 1, "INS_TCAL1_TMIN": lo, "INS_TCAL1_TMAX": hi}
    offsets = {}
    for kind, c, t_ref, off in (("ACC", tm.accel_mps2, tm.accel_t_ref_degC, o_mps2),
                                ("GYR", tm.gyro_rps, tm.gyro_t_ref_degC, gb_rps)):  # fmt: skip
        _, q = shifted(c, ARDUPILOT_T_REF_DEGC - t_ref)
        for k in range(3):
            for i, ax in enumerate("XYZ"):
                vals[f"INS_TCAL1_{kind}{k + 1}_{ax}"] = float(q[k, i] * ARDUPILOT_SCALE)
        if off is None:
            continue
        cal_temp = float(np.clip(t_ref, lo, hi))
        vals[f"INS_{kind}1_CALTEMP"] = cal_temp
        offsets[kind] = np.asarray(off, float) + poly_eval(c, cal_temp - t_ref)
    return vals, offsets["ACC"], offsets.get("GYR")


def step_losses(tm: ThermalModel) -> tuple[float, float]:
    """(m/s^2, rad/s): largest |dp/dT| x PX4_STEP_DEGC over the span, accelerometer and gyro."""
    out = []
    for c, t_ref in ((tm.accel_mps2, tm.accel_t_ref_degC), (tm.gyro_rps, tm.gyro_t_ref_degC)):
        x = np.linspace(*tm.span_degC, 201) - t_ref
        slope = np.multiply.outer(np.ones_like(x), c[0]) + np.multiply.outer(2 * x, c[1])
        slope += np.multiply.outer(3 * x**2, c[2])
        out.append(float(np.max(np.linalg.norm(slope, axis=1))) * PX4_STEP_DEGC)
    return out[0], out[1]


def thermal_notes(tm: ThermalModel, target: str) -> list[str]:
    """What the header says about the thermal parameters (span, clamping, reference)."""
    lo, hi = tm.span_degC
    span = "the fitted span" if tm.span_observed else "T_ref +- 10 degC (the calibration records no range)"
    notes = [f"thermal correction over {lo:.3g}..{hi:.3g} degC ({span}); outside it {target} holds the "
             "correction at its end value (clamped), where accellog's model extrapolates"]  # fmt: skip
    if target == "ardupilot":
        notes.append("INS_ACCOFFS / INS_GYROFFS hold the offsets at INS_ACC1_CALTEMP / INS_GYR1_CALTEMP "
                     f"(INS_TCAL1 polynomials about {ARDUPILOT_T_REF_DEGC:g} degC, stored x1e6)")  # fmt: skip
    else:
        notes.append("CAL_ACC0_*OFF / CAL_GYRO0_*OFF hold the offsets at TC_A0_TREF / TC_G0_TREF (X0 = 0)")
    return notes


def held_correction(cal: Calibration, reading_g: np.ndarray, temp_degC: np.ndarray, gyro_dps=None):
    """What an autopilot with this calibration's export computes (chip axes, ROTATION_NONE): accel
    diag(K) (r - o - p_a(T')) (m/s^2) and gyro w - gb - p_g(T') (deg/s, or None), T' = T clamped to
    the exported span (module doc: the firmware equations, tests/support/firmware.py checks them)."""
    K, o = linear_form(cal)
    tm = thermal_model(cal, np.eye(3))
    p_a: np.ndarray | float = 0.0
    p_g: np.ndarray | float = 0.0
    if tm is not None:
        Tc = np.clip(np.asarray(temp_degC, float), *tm.span_degC)
        p_a = poly_eval(tm.accel_mps2, Tc - tm.accel_t_ref_degC)
        p_g = np.rad2deg(poly_eval(tm.gyro_rps, Tc - tm.gyro_t_ref_degC))
    acc = np.diag(K) * (G0 * np.asarray(reading_g, float) - o - p_a)
    if gyro_dps is None or cal.gyro is None:
        return acc, None
    return acc, np.asarray(gyro_dps, float) - np.asarray(cal.gyro.bias_dps, float) - p_g
