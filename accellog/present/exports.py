"""A calibration in the forms other tools load: Kalibr imu.yaml, a ROS 2 parameter file, PX4 and
ArduPilot parameter files, plain YAML. Each export states what its target cannot hold.

accellog's model (accellog.calibrate.calibration): reading a' = S u + b (g) at reference conditions,
u = S^-1 (a' - b) in calibrated units, a = u * mps2_per_unit (m/s^2). With g0 = 9.80665:

    a = K (a'_mps2 - o),   K = (mps2_per_unit / g0) S^-1,   o = g0 b          (m/s^2)

PX4 (``Correct()``: (data - offset) .* scale) and ArduPilot (``_rotate_and_correct_accel``:
(accel - offset) .* scale) hold o and diag(K) only: the off-diagonal of K (cross-axis and
misalignment), temperature and any other model term are dropped, and the export reports the largest
error that causes at 1 g. Gyro: offsets = cal.gyro bias (rad/s); PX4/ArduPilot hold no gyro scale.
Kalibr's imu.yaml holds noise only (``accellog.calibrate.imu_noise``), not the calibration.
Sources and units: docs/interop.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from accellog.calibrate.calibration import Calibration
from accellog.calibrate.imu_noise import NoiseCharacterisation
from accellog.core.errors import InputError
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0

TARGETS = ("kalibr", "ros", "px4", "ardupilot", "yaml")
SUFFIX = {"kalibr": ".yaml", "ros": ".yaml", "px4": ".params", "ardupilot": ".parm", "yaml": ".yaml"}


@dataclass
class Export:
    """Text for one target, what it holds (with units) and what it cannot hold."""

    target: str
    text: str
    values: dict
    units: dict
    cannot_hold: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return asdict(self)


def linear_form(cal: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """K (3,3) and o (3,) m/s^2 with a = K (a'_mps2 - o) (module docstring)."""
    S, b = cal.S_b()
    return (cal.mps2_per_unit / G0) * np.linalg.inv(S), G0 * np.asarray(b, float)


def _dropped_terms(cal: Calibration) -> list[str]:
    return [t for t in cal.terms if t not in ("bias", "scale", "cross_axis", "misalignment_tri")]


def _gyro_bias_radps(cal: Calibration) -> np.ndarray | None:
    if cal.gyro is None:
        return None
    return np.deg2rad(np.asarray(cal.gyro.bias_dps, float))


def _diag_only(cal: Calibration, target: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    K, o = linear_form(cal)
    off = K - np.diag(np.diag(K))
    lost = []
    worst = float(np.max(np.abs(off).sum(axis=1))) * G0
    if worst > 0:
        lost.append(
            f"cross-axis/misalignment (off-diagonal of K): up to {worst:.4g} m/s^2 at 1 g is lost in {target}"
        )
    lost += [f"model term {t!r} (not a {target} parameter)" for t in _dropped_terms(cal)]
    g = cal.gyro
    if g is not None and not np.allclose(np.asarray(g.matrix, float), np.eye(3), equal_nan=False):
        lost.append(f"gyro scale/misalignment matrix ({target} holds gyro offsets only)")
    if g is not None and np.any(np.nan_to_num(np.asarray(g.temp_bias_dps_per_degC, float)) != 0):
        lost.append("gyro temperature bias")
    return np.diag(K), o, lost


def _params_px4(cal: Calibration) -> Export:
    scale, o, lost = _diag_only(cal, "PX4")
    vals = {}
    for i, ax in enumerate("XYZ"):
        vals[f"CAL_ACC0_{ax}OFF"] = float(o[i])
        vals[f"CAL_ACC0_{ax}SCALE"] = float(scale[i])
    gb = _gyro_bias_radps(cal)
    if gb is not None:
        vals.update({f"CAL_GYRO0_{ax}OFF": float(gb[i]) for i, ax in enumerate("XYZ")})
    lines = [
        "# Onboard parameters for Vehicle 1 (accellog export; QGroundControl .params format)",
        "# Set CAL_ACC0_ID / CAL_GYRO0_ID to your sensor's device id before loading.",
        *(f"# cannot hold: {x}" for x in lost),
        "#",
        "# Vehicle-Id Component-Id Name Value Type",
        *(f"1\t1\t{k}\t{v:.9g}\t9" for k, v in vals.items()),
    ]
    units = {
        k: ("m/s^2" if k.endswith("OFF") and "ACC" in k else "rad/s" if k.endswith("OFF") else "1")
        for k in vals
    }
    return Export("px4", "\n".join(lines) + "\n", vals, units, lost)


def _params_ardupilot(cal: Calibration) -> Export:
    scale, o, lost = _diag_only(cal, "ArduPilot")
    vals = {}
    for i, ax in enumerate("XYZ"):
        vals[f"INS_ACCOFFS_{ax}"] = float(o[i])
    for i, ax in enumerate("XYZ"):
        vals[f"INS_ACCSCAL_{ax}"] = float(scale[i])
    gb = _gyro_bias_radps(cal)
    if gb is not None:
        vals.update({f"INS_GYROFFS_{ax}": float(gb[i]) for i, ax in enumerate("XYZ")})
    bad = [k for k, v in vals.items() if k.startswith("INS_ACCSCAL") and not 0.8 <= v <= 1.2]
    if bad:
        lost.append(f"{', '.join(bad)} outside ArduPilot's accepted 0.8..1.2")
    lines = [
        "# ArduPilot parameters (accellog export; Mission Planner / MAVProxy NAME,VALUE format)",
        *(f"# cannot hold: {x}" for x in lost),
        *(f"{k},{v:.9g}" for k, v in vals.items()),
    ]
    units = {k: ("m/s/s" if "ACCOFFS" in k else "rad/s" if "GYROFFS" in k else "1") for k in vals}
    return Export("ardupilot", "\n".join(lines) + "\n", vals, units, lost)


def _yaml_value(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float, np.floating)):
        return f"{float(v):.9g}" if math.isfinite(float(v)) else ".nan"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_yaml_value(x) for x in np.asarray(v, dtype=object).ravel().tolist()) + "]"
    return '"' + str(v).replace('"', "'") + '"'


def _yaml(d: dict, indent: int = 0, comments: dict | None = None) -> list[str]:
    out = []
    for k, v in d.items():
        note = f"  # {comments[k]}" if comments and k in comments else ""
        if isinstance(v, dict):
            out.append(" " * indent + f"{k}:")
            out += _yaml(v, indent + 2, comments)
        else:
            out.append(" " * indent + f"{k}: {_yaml_value(v)}{note}")
    return out


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
    lost = ["the calibration itself (bias, scale, misalignment): Kalibr's imu.yaml holds noise only"]
    head = [
        f"# Kalibr IMU configuration (accellog export), noise from {noise.source} ({noise.duration_s:.0f} s)"
    ]
    return Export("kalibr", "\n".join(head + _yaml(vals, 0, comments)) + "\n", vals, units, lost)


def _ros(cal: Calibration, noise: NoiseCharacterisation | None, node: str, frame_id: str) -> Export:
    K, o = linear_form(cal)
    gb = _gyro_bias_radps(cal)
    p = {
        "frame_id": frame_id,
        "accel_offset_mps2": o.tolist(),
        "accel_correction_matrix": K.ravel().tolist(),
        "gyro_bias_radps": None if gb is None else gb.tolist(),
    }
    units = {"accel_offset_mps2": "m/s^2", "accel_correction_matrix": "1 (row-major; a = K (a_raw - o))",
             "gyro_bias_radps": "rad/s"}  # fmt: skip
    lost = [f"model term {t!r}" for t in _dropped_terms(cal)]
    if noise is not None:
        dt = 1.0 / noise.sample_rate_hz
        va = (noise.accelerometer_noise_density**2) / dt
        p["linear_acceleration_covariance"] = np.diag([va] * 3).ravel().tolist()
        units["linear_acceleration_covariance"] = "(m/s^2)^2 (discrete: density^2 / dt)"
        if noise.gyroscope_noise_density is not None:
            vg = (noise.gyroscope_noise_density**2) / dt
            p["angular_velocity_covariance"] = np.diag([vg] * 3).ravel().tolist()
            units["angular_velocity_covariance"] = "(rad/s)^2 (discrete: density^2 / dt)"
    else:
        lost.append("sensor_msgs/Imu covariances (give --noise-from STILL.mcap)")
    text = "# ROS 2 parameter file (accellog export): ros2 run ... --ros-args --params-file THIS\n"
    text += "\n".join(_yaml({node: {"ros__parameters": p}}, 0, units)) + "\n"
    return Export("ros", text, p, units, lost)


def _plain(cal: Calibration, noise: NoiseCharacterisation | None) -> Export:
    S, b = cal.S_b()
    d = {
        "format": "accellog.calibration.yaml",
        "equation": "reading_g = S u + b_g; u = S^-1 (reading_g - b_g); a_mps2 = u * mps2_per_unit",
        "model_terms": cal.terms,
        "S": np.asarray(S).ravel().tolist(),
        "b_g": list(b),
        "mps2_per_unit": cal.mps2_per_unit,
        "params": {n: {"value": float(v), "sigma": float(s), "unit": u}
                   for n, v, s, u in zip(cal.param_names, cal.theta, cal.sigma, cal.param_units, strict=True)},
        "gyro": {} if cal.gyro is None else cal.gyro.to_dict(),
    }  # fmt: skip
    if noise is not None:
        d["noise"] = noise.to_dict()
    text = "# accellog calibration as plain YAML (S row-major)\n" + "\n".join(_yaml(d)) + "\n"
    return Export("yaml", text, d, {"S": "1", "b_g": "g", "mps2_per_unit": "m/s^2 per unit"}, [])


def export_calibration(
    cal: Calibration,
    target: str,
    *,
    noise: NoiseCharacterisation | None = None,
    topic: str = "/imu/data",
    node: str = "imu_calibration",
    frame_id: str = "imu_link",
) -> Export:
    """The calibration (and noise, where the target holds it) as ``target`` text; see module docstring."""
    if target not in TARGETS:
        raise InputError(f"unknown export target {target!r}: use one of {', '.join(TARGETS)}")
    if target == "kalibr":
        return _kalibr(cal, noise, topic)
    if target == "ros":
        return _ros(cal, noise, node, frame_id)
    if target == "px4":
        return _params_px4(cal)
    if target == "ardupilot":
        return _params_ardupilot(cal)
    return _plain(cal, noise)
