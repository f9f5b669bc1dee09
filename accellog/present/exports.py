"""A calibration in the forms other tools load: Kalibr imu.yaml, imu_calib's accel_calib YAML (ROS),
PX4 and ArduPilot parameter files, accellog's own YAML. Every export states in its header what it
cannot hold and how large that loss is on this calibration (accellog.present.export_frames).

accellog's model (accellog.calibrate.calfile.calibration): reading a' = S u + b (g) at reference conditions,
u = S^-1 (a' - b) in calibrated units, a = u * mps2_per_unit (m/s^2). With g0 = 9.80665:

    a = K (a'_mps2 - o),   K = (mps2_per_unit / g0) S^-1,   o = g0 b          (m/s^2)

imu_calib (dpkoch/imu_calib, ``AccelCalib::applyCalib``): corrected = SM raw - bias (m/s^2), so
SM = K and bias = K o: the linear model exactly; it estimates its own gyro bias at start-up.
PX4 (``Correct()``: rotation ((data - offset) .* scale)) and ArduPilot (``_rotate_and_correct_accel``:
rotate to the board, (accel - offset) .* scale, rotate to the vehicle) hold o and diag(K) in the axes
after the driver's rotation (``--rotation``, default none): the off-diagonal of K, temperature and the
gyro matrix are dropped. Kalibr's imu.yaml holds noise only (``accellog.calibrate.noise.imu_noise``).
Sources and units: docs/interop.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
import yaml

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.noise.imu_noise import NoiseCharacterisation
from accellog.core.errors import InputError
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0
from accellog.present.export_frames import (
    diagonal_loss_mps2,
    directions_26,
    gyro_losses,
    linear_form,
    nonlinear_loss,
    rotation,
    sensor_ids,
)
from accellog.present.export_targets import TARGETS
from accellog.present.thermal_params import (
    HELD_TERMS,
    PX4_STEP_DEGC,
    ardupilot_values,
    px4_values,
    step_losses,
    thermal_model,
    thermal_notes,
)

__all__ = ["TARGETS", "Export", "export_calibration", "linear_form"]


@dataclass
class Export:
    """Text for one target, what it holds (with units) and what it cannot hold (with the size)."""

    target: str
    text: str
    values: dict
    units: dict
    cannot_hold: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


def _header(title: str, lost: list[str], notes: Sequence[str] = ()) -> list[str]:
    lines = [f"# {title}", *(f"# {n}" for n in notes)]
    return lines + ([f"# cannot hold: {x}" for x in lost] or ["# cannot hold: nothing of this calibration"])


def _nonlinear(cal: Calibration, target: str, held: tuple[str, ...] = ()) -> list[str]:
    nl = nonlinear_loss(cal, held)
    if nl is None:
        return []
    size, what = nl
    amount = "size unknown" if math.isnan(size) else f"up to {size:.3g} m/s^2 ({size / G0 * 1e3:.3g} mg)"
    return [f"non-linear model terms dropped ({what}): {amount}"]


def _autopilot(cal: Calibration, target: str, rot: str, device_id: int | None, verdict: Sequence[str] = ()):
    """Board-frame offsets o_R and scales diag(K_R), gyro offsets, the thermal model (None without
    temperature terms), what is lost, notes (verdict: held-out lines, flows.export_verdict, last), sensor ids."""
    name, num, R = rotation(rot)
    K, o = linear_form(cal)
    K_R, o_R = R @ K @ R.T, R @ o
    tm = thermal_model(cal, R)
    lost = []
    worst = diagonal_loss_mps2(K_R)
    if worst > 1e-12:
        lost.append(f"cross-axis/misalignment (off-diagonal of K) dropped: up to {worst:.3g} m/s^2 "
                    f"({worst / G0 * 1e3:.3g} mg) at 1 g")  # fmt: skip
    lost += _nonlinear(cal, target, HELD_TERMS) + gyro_losses(cal, keeps_temp=True)
    notes = [f"axes: the chip's, rotated by {name} ({num}), the rotation {target}'s driver applies before "
             "the offsets (--rotation; the board/vehicle rotation after them is unchanged)"]  # fmt: skip
    acc_id, gyr_id, how = sensor_ids(cal, target, device_id)
    id_names = {"px4": "CAL_ACC0_ID", "ardupilot": "INS_ACC_ID"}
    if acc_id is None:
        also = " and TC_A0_ID / TC_G0_ID" if target == "px4" and tm is not None else ""
        lost.append(f"{id_names[target]}{also} not written: {how}; give --device-id (the value your autopilot "
                    f"shows), without it {target} treats the sensor as uncalibrated")  # fmt: skip
    else:
        notes.append(f"{id_names[target]} {how}")
    if tm is not None:
        notes += thermal_notes(tm, target)
    notes += list(verdict)
    gb = None if cal.gyro is None else R @ np.deg2rad(np.asarray(cal.gyro.bias_dps, float))
    return np.diag(K_R), o_R, gb, tm, lost, notes, (acc_id, gyr_id)


def _px4_step_loss(tm) -> list[str]:
    """PX4 republishes the thermal offsets only after > 1 degC of change: the error between updates."""
    acc, gyr = step_losses(tm)
    parts = ([f"{acc:.3g} m/s^2 ({acc / G0 * 1e3:.3g} mg)"] if tm.has_accel else []) + (
        [f"{np.rad2deg(gyr):.3g} deg/s"] if tm.has_gyro else [])  # fmt: skip
    return [f"the thermal offsets between PX4's updates (republished after > {PX4_STEP_DEGC:g} degC of "
            f"change): up to {' and '.join(parts)}"]  # fmt: skip


def _params_px4(cal: Calibration, rot: str, device_id: int | None, verdict: Sequence[str] = ()) -> Export:
    scale, o, gb, tm, lost, notes, (acc_id, gyr_id) = _autopilot(cal, "px4", rot, device_id, verdict)
    vals: dict = {} if acc_id is None else {"CAL_ACC0_ID": acc_id}
    for i, ax in enumerate("XYZ"):
        vals[f"CAL_ACC0_{ax}OFF"] = float(o[i])
        vals[f"CAL_ACC0_{ax}SCALE"] = float(scale[i])
    if gb is not None:
        if gyr_id is not None:
            vals["CAL_GYRO0_ID"] = gyr_id
        vals.update({f"CAL_GYRO0_{ax}OFF": float(gb[i]) for i, ax in enumerate("XYZ")})
    if tm is not None:
        vals.update(px4_values(tm, acc_id, gyr_id))
        lost += _px4_step_loss(tm)
    lines = [
        *_header("Onboard parameters for Vehicle 1 (accellog export; QGroundControl .params format)", lost, notes),
        "#",
        "# Vehicle-Id Component-Id Name Value Type",
        *(f"1\t1\t{k}\t{v}\t6" if isinstance(v, int) else f"1\t1\t{k}\t{v:.9g}\t9" for k, v in vals.items()),
    ]  # fmt: skip
    units = {k: _px4_unit(k) for k in vals}
    return Export("px4", "\n".join(lines) + "\n", vals, units, lost, notes)


def _px4_unit(k: str) -> str:
    """Unit of a PX4 parameter this export writes."""
    if k.endswith("_ID") or k.endswith("_ENABLE"):
        return "id" if k.endswith("_ID") else "0/1"
    if k.startswith("TC_"):
        if k[-4:] in ("TREF", "TMIN", "TMAX"):
            return "degC"
        order = int(k.split("_X")[1][0])
        base = "m/s^2" if k.startswith("TC_A") else "rad/s"
        return base if order == 0 else f"{base}/degC^{order}"
    return "m/s^2" if "ACC" in k and k.endswith("OFF") else "rad/s" if k.endswith("OFF") else "1"


def _params_ardupilot(
    cal: Calibration, rot: str, device_id: int | None, verdict: Sequence[str] = ()
) -> Export:
    scale, o, gb, tm, lost, notes, (acc_id, gyr_id) = _autopilot(cal, "ardupilot", rot, device_id, verdict)
    thermal: dict = {}
    if tm is not None:
        thermal, o, gb = ardupilot_values(tm, o, gb)
    vals: dict = {} if acc_id is None else {"INS_ACC_ID": acc_id}
    vals.update({f"INS_ACCOFFS_{ax}": float(o[i]) for i, ax in enumerate("XYZ")})
    vals.update({f"INS_ACCSCAL_{ax}": float(scale[i]) for i, ax in enumerate("XYZ")})
    if gb is not None:
        if gyr_id is not None:
            vals["INS_GYR_ID"] = gyr_id
        vals.update({f"INS_GYROFFS_{ax}": float(gb[i]) for i, ax in enumerate("XYZ")})
    vals.update(thermal)
    bad = [k for k, v in vals.items() if k.startswith("INS_ACCSCAL") and not 0.8 <= v <= 1.2]
    if bad:
        lost.append(f"{', '.join(bad)} outside ArduPilot's accepted 0.8..1.2")
    lines = [
        *_header("ArduPilot parameters (accellog export; Mission Planner / MAVProxy NAME,VALUE format)", lost, notes),
        *(f"{k},{v}" if isinstance(v, int) else f"{k},{v:.9g}" for k, v in vals.items()),
    ]  # fmt: skip
    units = {k: _ardupilot_unit(k) for k in vals}
    return Export("ardupilot", "\n".join(lines) + "\n", vals, units, lost, notes)


def _ardupilot_unit(k: str) -> str:
    """Unit of an ArduPilot parameter this export writes."""
    if k.endswith("_ID") or k.endswith("_ENABLE"):
        return "id" if k.endswith("_ID") else "0/1"
    if k.endswith(("CALTEMP", "TMIN", "TMAX")):
        return "degC"
    if k.startswith("INS_TCAL1_"):
        order = int(k.split("_")[2][3])
        base = "m/s/s" if "_ACC" in k else "rad/s"
        return f"1e-6 {base}/degC^{order}"
    return "m/s/s" if "ACCOFFS" in k else "rad/s" if "GYROFFS" in k else "1"


class _Dumper(yaml.SafeDumper):
    """PyYAML's safe dumper, lists in flow style (``S: [1.0, 0.0, ...]``), mappings in block style."""


_Dumper.add_representer(
    list, lambda dumper, v: dumper.represent_sequence("tag:yaml.org,2002:seq", v, flow_style=True)
)


def _builtin(v):
    """``v`` with numpy scalars as Python's and every sequence (list, tuple, array, nested) as one flat
    row-major list: the types safe_dump writes, the shapes the exports have always had."""
    if isinstance(v, dict):
        return {k: _builtin(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_builtin(x) for x in np.asarray(v, dtype=object).ravel().tolist()]
    return v.item() if isinstance(v, np.generic) else v


def _yaml(d: dict, comments: dict | None = None) -> list[str]:
    """``d`` as YAML lines, keys in order, floats as repr (a reload gives the same float64);
    ``comments[k]`` goes after top-level key ``k``'s line (a scalar's: one line each)."""
    text = yaml.dump(_builtin(d), Dumper=_Dumper, sort_keys=False, default_flow_style=False, width=1 << 30)
    lines = text.splitlines()
    for i, line in enumerate(lines):
        key = line.split(":", 1)[0]
        if comments and key in comments and not line.startswith(" "):
            lines[i] = f"{line}  # {comments[key]}"
    return lines


def _raw_error_mps2(cal: Calibration) -> float:
    """Largest |raw reading - true| (m/s^2) at 1 g over the 26 face/edge/corner directions (linear model)."""
    S, b = cal.S_b()
    u = directions_26()
    return float(np.max(np.linalg.norm(G0 * (u @ np.asarray(S).T + b) - cal.mps2_per_unit * u, axis=1)))


def _kalibr(cal: Calibration, noise: NoiseCharacterisation | None, topic: str) -> Export:
    if noise is None:
        raise InputError(
            "a Kalibr imu.yaml holds noise densities and random walks: give a still recording with "
            "--noise-from STILL.mcap (a few minutes or more)"
        )
    if noise.gyroscope_noise_density is None:
        raise InputError("--noise-from recording has no gyro: Kalibr needs gyroscope noise too")
    vals = {
        "accelerometer_noise_density": noise.accelerometer_noise_density,
        "accelerometer_random_walk": noise.accelerometer_random_walk,
        "gyroscope_noise_density": noise.gyroscope_noise_density,
        "gyroscope_random_walk": noise.gyroscope_random_walk,
        "rostopic": topic,
        "update_rate": noise.sample_rate_hz,
    }
    units = {
        "accelerometer_noise_density": "m/s^2/sqrt(Hz)",
        "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
        "gyroscope_noise_density": "rad/s/sqrt(Hz)",
        "gyroscope_random_walk": "rad/s^2/sqrt(Hz)",
        "update_rate": "Hz",
    }
    bound = (
        " (upper bound: recording too short to see the +1/2 Allan slope)"
        if noise.random_walk_is_bound
        else ""
    )
    comments = {k: units[k] + (bound if "random_walk" in k else "") for k in units}
    lost = [f"the calibration itself (imu.yaml holds noise only): uncorrected readings are off by up to "
            f"{_raw_error_mps2(cal):.3g} m/s^2 at 1 g; feed Kalibr calibrated data (apply --ros2)"]  # fmt: skip
    lost += gyro_losses(cal, keeps_bias=False)
    title = (
        f"Kalibr IMU configuration (accellog export), noise from {noise.source} ({noise.duration_s:.0f} s)"
    )
    return Export("kalibr", "\n".join(_header(title, lost) + _yaml(vals, comments)) + "\n", vals, units, lost)


def _imu_calib(cal: Calibration) -> Export:
    """imu_calib's accel_calib file: corrected = SM raw - bias (m/s^2), SM = K, bias = K o."""
    K, o = linear_form(cal)
    vals = {"SM": K.ravel().tolist(), "bias": (K @ o).tolist()}
    units = {"SM": "1 (row-major 3x3)", "bias": "m/s^2"}
    lost = _nonlinear(cal, "imu_calib") + gyro_losses(cal, keeps_bias=False)
    lost += ["sensor_msgs/Imu covariances (apply_calib copies the raw message's)"]
    notes = ["apply_calib: corrected = SM * raw - bias (m/s^2, raw linear_acceleration); "
             "rosrun imu_calib apply_calib _calib_file:=THIS",
             "apply_calib measures its own gyro bias at start-up (calibrate_gyros, default true: keep the IMU still)"]  # fmt: skip
    text = "\n".join(
        _header("imu_calib accelerometer calibration (accellog export)", lost, notes) + _yaml(vals)
    )
    return Export("ros", text + "\n", vals, units, lost, notes)


def _plain(cal: Calibration, noise: NoiseCharacterisation | None) -> Export:
    S, b = cal.S_b()
    K, o = linear_form(cal)
    d = {
        "format": "accellog.calibration.yaml",
        "equation": "reading_g = S u + b_g; u = S^-1 (reading_g - b_g); a_mps2 = u * mps2_per_unit",
        "model_terms": cal.terms,
        "S": np.asarray(S).ravel().tolist(),
        "b_g": list(b),
        "mps2_per_unit": cal.mps2_per_unit,
        "K": K.ravel().tolist(),
        "o_mps2": o.tolist(),
        "params": {n: {"value": float(v), "sigma": float(s), "unit": u}
                   for n, v, s, u in zip(cal.param_names, cal.theta, cal.sigma, cal.param_units, strict=True)},
        "gyro": {} if cal.gyro is None else cal.gyro.to_dict(),
    }  # fmt: skip
    if noise is not None:
        d["noise"] = noise.to_dict()
    lost = []
    if cal.needs_user_code:
        lost.append(
            "the code of the user effects (the file keeps their parameters; apply needs --effects-file)"
        )
    head = _header("accellog calibration as plain YAML (S, K row-major; a_mps2 = K (reading_mps2 - o_mps2) "
                   "for the linear part)", lost)  # fmt: skip
    units = {"S": "1", "b_g": "g", "mps2_per_unit": "m/s^2 per unit", "K": "1", "o_mps2": "m/s^2"}
    return Export("yaml", "\n".join(head + _yaml(d)) + "\n", d, units, lost)


def export_calibration(
    cal: Calibration,
    target: str,
    *,
    noise: NoiseCharacterisation | None = None,
    topic: str = "/imu/data",
    rotation: str = "ROTATION_NONE",
    device_id: int | None = None,
    verdict: Sequence[str] = (),
) -> Export:
    """The calibration (and noise, where the target holds it) as ``target`` text; see module docstring.
    rotation, device_id, verdict (held-out lines for the header, flows.export_verdict): PX4 /
    ArduPilot only (export_frames.rotation, export_frames.sensor_ids)."""
    if target not in TARGETS:
        raise InputError(f"unknown export target {target!r}: use one of {', '.join(TARGETS)}")
    if target == "kalibr":
        return _kalibr(cal, noise, topic)
    if target == "ros":
        return _imu_calib(cal)
    if target == "px4":
        return _params_px4(cal, rotation, device_id, verdict)
    if target == "ardupilot":
        return _params_ardupilot(cal, rotation, device_id, verdict)
    return _plain(cal, noise)
