"""The checks of a simulated scenario that come before any work (accellog.flows.simulate): each key's
type, every number finite, seeds >= 0, a local gravity on Earth, and a session that can run: at most
MAX_SESSION_S long, its die temperature inside the MPU-9250's operating range all along, no
disconnect longer than it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from accellog.core.errors import InputError, did_you_mean
from accellog.core.units import EARTH_GRAVITY_RANGE_MPS2

MAX_SESSION_S = 86400.0
"""Longest simulated session (s): one day (a longer one is a typo, not a plan)."""
OPERATING_RANGE_DEGC = (-40.0, 85.0)
"""The MPU-9250's operating temperature range (PS section 3.1, degC)."""


def finite_numbers(value: Any) -> bool:
    """True when every number in value (a number, or nested lists / tables of them) is finite."""
    if isinstance(value, dict):
        return all(finite_numbers(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return all(finite_numbers(v) for v in value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return math.isfinite(value)
    return True


_FLOAT_KEYS = {"hold_s", "move_s", "sample_rate_hz", "local_gravity_mps2", "label_margin_s"}
_INT_KEYS = {"accel_range_g", "gyro_range_dps", "chip_seed", "seed"}
_STR_KEYS = {"protocol", "errors", "gyro_errors", "motion", "robot_path"}
_TABLE_KEYS = {"set", "gyro_set", "temperature", "magnetometer", "faults"}


def check_type(key: str, value: Any, where: str) -> None:
    """One-line InputError when a scenario value has the wrong type (TOML is typed; the fault keys
    are FaultPlan.from_mapping's to check)."""

    def bad(expected: str) -> InputError:
        return InputError(f"scenario key {key!r} must be {expected}, got {value!r}", where=where)

    is_num = isinstance(value, (int, float)) and not isinstance(value, bool)
    if key in _FLOAT_KEYS and not is_num:
        raise bad("a number")
    if key in _INT_KEYS and (not isinstance(value, int) or isinstance(value, bool)):
        raise bad("an integer")
    if key in _STR_KEYS and not isinstance(value, str):
        raise bad("a string")
    if key in _TABLE_KEYS and not isinstance(value, dict):
        raise bad("a table")
    if key == "fixture_tilt_deg" and not (
        isinstance(value, (list, tuple))
        and len(value) == 2
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    ):
        raise bad("two numbers [about x, about y] in degrees")


def check_numbers(sc: Any, where: str) -> None:
    """InputError naming the first non-finite number of the scenario (NaN or inf anywhere: a field,
    an error override, the temperature or magnetometer table), a negative seed or a local gravity
    that is not on Earth (EARTH_GRAVITY_RANGE_MPS2)."""
    for f in dataclasses.fields(sc):
        value = getattr(sc, f.name)
        if not finite_numbers(value):
            raise InputError(f"{f.name}={value!r} must be finite (no NaN or inf)", where=where)
    for key in ("seed", "chip_seed"):
        if getattr(sc, key) < 0:
            raise InputError(f"{key}={getattr(sc, key)} must be >= 0", where=where)
    if any(abs(a) > 90.0 for a in sc.fixture_tilt_deg):
        raise InputError(f"fixture_tilt_deg={list(sc.fixture_tilt_deg)} must be within +-90 deg", where=where)
    lo, hi = EARTH_GRAVITY_RANGE_MPS2
    if not lo <= sc.local_gravity_mps2 <= hi:
        raise InputError(
            f"local_gravity_mps2={sc.local_gravity_mps2:g} is not a gravity on Earth ({lo}-{hi} m/s^2)",
            where=where,
        )


def check_session_runs(sc: Any, temperature: Any, session_s: float) -> None:
    """InputError unless a session of session_s (s) can be simulated: at most MAX_SESSION_S, a die
    temperature inside the chip's operating range all along, no disconnect longer than the session."""
    if not 0 < session_s <= MAX_SESSION_S:
        raise InputError(
            f"the session would last {session_s:g} s; at most {MAX_SESSION_S:g} s", where="scenario"
        )
    t = np.linspace(0.0, session_s, 2001)
    temp_degC = temperature.degC(t)
    lo, hi = OPERATING_RANGE_DEGC
    bad = ~((temp_degC >= lo) & (temp_degC <= hi))
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(
            f"temperature {temperature.description} reaches {temp_degC[k]:.4g} degC at t = {t[k]:.4g} s, outside "
            f"the MPU-9250's operating range {lo:g}..{hi:g} degC",
            where="scenario",
        )
    sc.fault_plan().check_session(session_s)


ERROR_LIMITS = {  # field: (low, high) of every element; beyond them the loaders refuse the calibration
    "bias_g": (-1.0, 1.0),
    "scale": (-0.5, 0.5),
    "cross_axis": (-0.3, 0.3),
    "warmup_g": (-1.0, 1.0),
    "warmup_tau_s": (1e-3, 86400.0),
    "temp_bias_g_per_degC": (-0.01, 0.01),  # datasheet draws +-1.5 mg/degC; 0.01 g/degC: 1 g over 100 degC
    "temp_bias2_g_per_degC2": (-3e-4, 3e-4),  # 1 g at 60 degC from the reference
    "temp_scale_per_degC": (-3e-3, 3e-3),  # datasheet draws +-0.026 %/degC
    "temp_scale2_per_degC2": (-1e-4, 1e-4),  # 36 % at 60 degC from the reference
    "nonlin2_per_g": (-0.1, 0.1),  # 10 % of the reading at 1 g
    "nonlin3_per_g2": (-0.1, 0.1),
    "g_cross_per_g": (-0.1, 0.1),
    "time_drift_g_per_s": (-1e-4, 1e-4),  # 0.36 g an hour
    "temp_rate_bias_g_per_degC_per_s": (-1.0, 1.0),
    "temp_hysteresis_g": (-1.0, 1.0),
    "temp_hysteresis_width_degC": (0.0, 125.0),  # the operating range
    "noise_density_g_per_rtHz": (0.0, 0.1),
    "bias_instability_g": (0.0, 0.1),
    "random_walk_g_per_s_rtHz": (0.0, 0.1),
    "clock_error": (-0.1, 0.1),  # the sample clock 10 % off
    "t_ref_degC": OPERATING_RANGE_DEGC,
}
GYRO_ERROR_LIMITS = {
    "bias_dps": (-2000.0, 2000.0),  # full scale at +-2000 deg/s (datasheet draws +-5 deg/s)
    "scale": (-0.5, 0.5),
    "cross_axis": (-0.3, 0.3),
    "temp_bias_dps_per_degC": (-1.0, 1.0),  # datasheet draws +-0.24 deg/s/degC
    "temp_bias2_dps_per_degC2": (-0.05, 0.05),  # 180 deg/s at 60 degC from the reference
    "noise_density_dps_per_rtHz": (0.0, 10.0),
    "bias_instability_dps": (0.0, 100.0),
    "random_walk_dps_per_s_rtHz": (0.0, 100.0),
    "t_ref_degC": OPERATING_RANGE_DEGC,
}


def check_errors(errors: Any, limits: Mapping[str, tuple[float, float]], where: str = "scenario") -> None:
    """InputError when an error field of the emulated chip (AccelErrors with ERROR_LIMITS, GyroErrors
    with GYRO_ERROR_LIMITS, after the scenario's [set] / [gyro_set]) is outside its limits: a session
    that saturates, or that no calibration loader would accept."""
    check_error_values({k: getattr(errors, k) for k in limits}, limits, where)


def check_error_values(
    values: Mapping[str, Any], limits: Mapping[str, tuple[float, float]], where: str
) -> None:
    """check_errors on the fields given (a scenario's [set] table; values that are not numbers are
    left to overridden_errors, which names them)."""
    for name, value in values.items():
        if name not in limits:
            continue
        try:
            v = np.asarray(value, float)
        except (TypeError, ValueError):
            continue
        lo, hi = limits[name]
        if not ((v >= lo) & (v <= hi)).all():
            raise InputError(
                f"error field {name} = {np.round(v, 6).tolist()} outside its physical range {lo:g}..{hi:g}",
                where=where,
            )


def overridden_errors(errors, values: Mapping[str, Any], what: str):
    """errors (AccelErrors | GyroErrors) with the scenario's [set] / [gyro_set] fields replaced (checked)."""
    known = {f.name for f in dataclasses.fields(errors)}
    bad = sorted(set(values) - known)
    if bad:
        raise InputError(
            f"unknown {what} error field(s) {bad}{did_you_mean(bad, known)}; known: {sorted(known)}"
        )
    out: dict[str, Any] = {}  # fields: floats or arrays
    for k, v in values.items():
        try:
            arr = np.asarray(v, float)
        except (TypeError, ValueError):
            raise InputError(f"error field {k!r}: {v!r} is not a number or a list of numbers") from None
        default = np.asarray(getattr(errors, k), float)
        if arr.shape != default.shape and arr.ndim != 0:
            raise InputError(
                f"{k} must be {default.size} numbers (shape {default.shape}), got shape {arr.shape}"
            )
        out[k] = float(arr) if default.ndim == 0 else np.broadcast_to(arr, default.shape).copy()
    return dataclasses.replace(errors, **out)
