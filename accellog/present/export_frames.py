"""What an export cannot hold, and how large that loss is on one calibration; the board rotations and
sensor IDs of the autopilots (PX4, ArduPilot).

Accelerometer (m/s^2, g0 = 9.80665): accellog applies a = K (r - o), K = (mps2_per_unit / g0) S^-1,
o = g0 b. A target that holds only D (diagonal) and o applies a' = D (r - o), so for a true specific
force a (|a| = 1 g) the error is

    a' - a = (D - K) K^-1 a,    largest over all directions = ||(D - K) K^-1||_2 * g      (m/s^2)

Non-linear model terms (temperature, time): the largest |correct(r; drivers) - kept(r; drivers)| over
the 26 face/edge/corner directions at 1 g, with each driver at the ends of its range (temperature: 7
points over the calibration's observed range, else T_ref +- 10 degC; time: 0-600 s; temperature rate:
+-0.05 degC/s). kept = S^-1 (r - b - p(dT)) is what the target applies: the linear part, less the
bias polynomial p(dT) = bT dT + bT2 dT^2 for targets that hold it (PX4 TC_A*, ArduPilot INS_TCAL*).

Gyro (w_meas = M w + b0 + b_T (T - T_ref)): dropping M leaves (M - I) w, up to ||M - I||_2 of the rate
(relative); dropping b_T leaves |b_T| max|T - T_ref| (deg/s).

Rotation (both autopilots rotate the chip axes with the driver's rotation before the offsets, then to
the vehicle after them): for chip -> rotated axes R, the rotated calibration is K_R = R K R^T,
o_R = R o (a_R = K_R (R r - o_R) = R a). R = Rz(yaw) Ry(pitch) Rx(roll) from the targets' shared
rotation table (PX4 ``src/lib/conversion/rotation.h`` rot_lookup; ArduPilot ``enum Rotation``, same
names and numbers up to 37).

Sensor IDs (PX4 ``DeviceStructure``, ArduPilot ``AP_HAL::Device::DeviceStructure``):
id = bus_type | bus << 3 | address << 8 | devtype << 16, bus_type 1 = I2C; devtype for the
MPU-9250: PX4 DRV_IMU_DEVTYPE_MPU9250 0x24 (accel and gyro), ArduPilot DEVTYPE_ACC_MPU9250 0x16 and
DEVTYPE_GYR_MPU9250 0x24.
"""

from __future__ import annotations

import itertools
import re

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.core.errors import InputError
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0

LINEAR_TERMS = ("bias", "scale", "cross_axis", "misalignment_tri")

_ROT = [(0, 0, 0), (0, 0, 45), (0, 0, 90), (0, 0, 135), (0, 0, 180), (0, 0, 225), (0, 0, 270), (0, 0, 315),
        (180, 0, 0), (180, 0, 45), (180, 0, 90), (180, 0, 135), (0, 180, 0), (180, 0, 225), (180, 0, 270),
        (180, 0, 315), (90, 0, 0), (90, 0, 45), (90, 0, 90), (90, 0, 135), (270, 0, 0), (270, 0, 45),
        (270, 0, 90), (270, 0, 135), (0, 90, 0), (0, 270, 0), (0, 180, 90), (0, 180, 270), (90, 90, 0),
        (180, 90, 0), (270, 90, 0), (90, 180, 0), (270, 180, 0), (90, 270, 0), (180, 270, 0),
        (270, 270, 0), (90, 180, 90), (90, 0, 270)]  # fmt: skip
"""(roll, pitch, yaw) deg of rotation numbers 0..37 (PX4 rot_lookup = ArduPilot enum Rotation)."""


def _rotation_name(rpy: tuple[int, int, int]) -> str:
    parts = [f"{n}_{v}" for n, v in zip(("ROLL", "PITCH", "YAW"), rpy, strict=True) if v]
    return "ROTATION_" + ("_".join(parts) or "NONE")


ROTATIONS = {_rotation_name(r): (k, r) for k, r in enumerate(_ROT)}
"""Name ('ROTATION_ROLL_180_YAW_90') -> (number, (roll, pitch, yaw) deg)."""


def rotation(name: str | int) -> tuple[str, int, np.ndarray]:
    """(name, number, R 3x3) of a rotation given by name ('ROTATION_YAW_90', 'yaw_90', 'none') or number."""
    key = str(name).strip().upper().replace("-", "_")
    if re.fullmatch(r"\d+", key) and int(key) < len(_ROT):
        key = _rotation_name(_ROT[int(key)])
    key = key if key.startswith("ROTATION_") else f"ROTATION_{key}"
    if key not in ROTATIONS:
        raise InputError(
            f"--rotation {name}: not a PX4/ArduPilot rotation (e.g. ROTATION_NONE, ROTATION_YAW_90, "
            f"ROTATION_ROLL_180_YAW_270, or its number 0-{len(_ROT) - 1})"
        )
    num, (r, p, y) = ROTATIONS[key]
    cr, sr, cp, sp, cy, sy = (f(np.deg2rad(a)) for a in (r, p, y) for f in (np.cos, np.sin))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return key, num, np.round(rz @ ry @ rx, 15)


def linear_form(cal: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """K (3,3) and o (3,) m/s^2 with a = K (r_mps2 - o) (module docstring)."""
    S, b = cal.S_b()
    return (cal.mps2_per_unit / G0) * np.linalg.inv(S), G0 * np.asarray(b, float)


def diagonal_loss_mps2(K: np.ndarray) -> float:
    """Largest error (m/s^2 at 1 g) of keeping only diag(K): ||(D - K) K^-1||_2 g0."""
    D = np.diag(np.diag(K))
    return float(np.linalg.norm((D - K) @ np.linalg.inv(K), 2)) * G0


def directions_26() -> np.ndarray:
    """The 26 unit face, edge and corner directions."""
    v = [np.array(c, float) for c in itertools.product((-1, 0, 1), repeat=3) if any(c)]
    return np.array([x / np.linalg.norm(x) for x in v])


def temperature_span(cal: Calibration) -> tuple[tuple[float, float], bool]:
    """((lo, hi) degC, observed): the calibration's observed temperature range, else T_ref +- 10 degC."""
    t = cal.temperature
    ref = t.t_ref_degC if t.t_ref_degC is not None else 25.0
    rng = t.range_degC
    return (rng, True) if rng else ((ref - 10.0, ref + 10.0), False)


def bias_polynomial_g(cal: Calibration, held: tuple[str, ...]) -> np.ndarray:
    """(3 orders, 3 axes) g/degC^k: the coefficients of dT, dT^2, dT^3 (dT = T - T_ref) of the
    bias terms in ``held`` (temp_bias: bT, temp_bias2: bT2); zero where the model lacks them."""
    c = np.zeros((3, 3))
    if cal.needs_user_code:
        return c
    p = cal.model.params_dict(cal.theta)
    for k, (term, name) in enumerate((("temp_bias", "bT"), ("temp_bias2", "bT2"))):
        if term in held and term in cal.terms:
            c[k] = [p[f"{name}_{a}"] for a in "xyz"]
    return c


def nonlinear_loss(cal: Calibration, held: tuple[str, ...] = ()) -> tuple[float, str] | None:
    """(largest m/s^2, the driver ranges used) of the model's non-linear terms a target drops: all
    but the bias polynomial terms in ``held``, which the target applies (bias_polynomial_g) before
    the linear part; None when nothing is dropped. Temperature: 7 points over its range."""
    extra = [t for t in cal.terms if t not in LINEAR_TERMS and t not in held]
    if not extra:
        return None
    if cal.needs_user_code:
        return float("nan"), f"user effects {', '.join(extra)} (give --effects-file to size them)"
    rng, _ = temperature_span(cal)
    ref = cal.model.t_ref_degC
    ranges = {"temp_degC": tuple(np.linspace(rng[0], rng[1], 7)), "t_s": (0.0, 600.0),
              "t_in_pose_s": (0.0, 600.0), "dtemp_degC_per_s": (-0.05, 0.05)}  # fmt: skip
    S, b = cal.S_b()
    Sinv = np.linalg.inv(np.asarray(S, float))
    poly = bias_polynomial_g(cal, held)
    u = directions_26()
    r = u @ np.asarray(S).T + b  # readings (g) of the linear model at these directions
    worst = 0.0
    needed = cal.model.required_drivers
    for ends in itertools.product(*(ranges.get(d, (0.0,)) for d in needed)):
        drv = {d: np.full(len(u), v) for d, v in zip(needed, ends, strict=True)}
        dT = drv.get("temp_degC", np.full(len(u), ref))[0] - ref
        kept = u - Sinv @ (poly.T @ dT ** np.arange(1, 4))  # what the target applies (g)
        worst = max(worst, float(np.max(np.linalg.norm(cal.correct(r, drv) - kept, axis=1))))
    used = ", ".join(f"{d} {ranges[d][0]:.3g}..{ranges[d][-1]:.3g}" for d in needed if d in ranges)
    return worst * cal.mps2_per_unit, f"terms {', '.join(extra)} over {used}"


def gyro_losses(cal: Calibration, *, keeps_bias: bool = True, keeps_temp: bool = False) -> list[str]:
    """What dropping the gyro matrix, the temperature bias (unless kept) and the bias (unless kept) costs."""
    g = cal.gyro
    if g is None:
        return []
    out = []
    M = np.asarray(g.matrix, float)
    rel = float(np.linalg.norm(M - np.eye(3), 2))
    if rel > 0:
        out.append(f"gyro scale/misalignment matrix dropped: up to {100 * rel:.3g} % rate error")
    bt = g.temp_poly_dps
    if np.any(bt != 0) and not keeps_temp:
        lo, hi = cal.temperature.range_degC or (g.t_ref_degC - 10.0, g.t_ref_degC + 10.0)
        dT = np.linspace(lo, hi, 65) - g.t_ref_degC
        worst = np.max(np.abs(np.multiply.outer(dT, bt[0]) + np.multiply.outer(dT**2, bt[1])))
        out.append(f"gyro temperature bias dropped: up to {worst:.3g} deg/s over {lo:.3g}..{hi:.3g} degC")
    if not keeps_bias:
        out.append(f"gyro bias dropped: up to {np.max(np.abs(g.bias_dps)):.3g} deg/s")
    return out


_DEVTYPES = {"px4": (0x24, 0x24), "ardupilot": (0x16, 0x24)}  # (accel, gyro) for the MPU-9250


def sensor_ids(cal: Calibration, target: str, device_id: int | None) -> tuple[int | None, int | None, str]:
    """(accel id, gyro id, how they were found): the given device_id (both), else from the calibration's
    device (I2C bus number and address of an MPU-9250/9255), else (None, None, why not)."""
    if device_id is not None:
        return device_id, device_id, "given with --device-id"
    d = cal.device
    m = re.search(r"(\d+)$", d.i2c_bus or "")
    if m is None or d.i2c_address is None or d.who_am_i not in (0x71, 0x73):
        return None, None, "the calibration does not say on which I2C bus the MPU-9250 sits"
    bus, addr = int(m.group(1)), int(d.i2c_address)
    acc, gyr = (1 | bus << 3 | addr << 8 | dt << 16 for dt in _DEVTYPES[target])
    return acc, gyr, f"computed from the calibration's device (I2C bus {bus}, address 0x{addr:02X}, MPU-9250)"
