"""Units and rates checked at the door of ``import csv``: values no IMU can produce in the declared
unit are refused with the likely fix (the flags to add), judged on the file's first rows; time
stamps beyond int64 nanoseconds are refused with their line. Thresholds: accellog.core.plausible.

The stamps and samples of every importer pass ``accellog.store.importers.door``.
"""

from __future__ import annotations

import numpy as np

from accellog.core.errors import InputError
from accellog.core.plausible import (
    GYRO_LSB_HINT,
    MAX_TIME_S,
    RATE_MAX_HZ,
    RATE_MIN_HZ,
    TIME_UNIT_NAME,
    TIME_UNIT_S,
    GravityTurns,
    accel_scale_guess,
    accel_unit_guess,
    gyro_counts_evidence,
    likely_time_unit,
    nearest_accel_lsb,
    rate_ok,
)
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.importers.csv_options import CsvOptions

_CENTRE = 32768.0
"""Centre of offset-binary ("unsigned") 16-bit counts."""


_RANGE = f"{RATE_MIN_HZ:g} Hz .. {RATE_MAX_HZ / 1e3:g} kHz"


class UnitsError(InputError):
    """Values whose unit or rate no IMU recording has (the message names the likely fix).
    ``accellog doctor`` reads such a file as declared and reports the defect instead."""


def check_rate(
    path, step: float, o: CsvOptions, column: str | None, header_rate: float | None, whole: bool = False
) -> None:
    """Refuse a median time step (``step``, in the declared unit) or a stated rate outside 1 Hz .. 100 kHz.
    Whole-number stamps one unit apart (1 Hz in s: a millisecond clock at 1 kHz, most often) are
    refused too unless the user named the time unit."""
    if column is None:  # rate from --rate (checked by CsvOptions) or the header line
        if header_rate and not rate_ok(header_rate):
            raise UnitsError(
                f"the header states a sample rate of {header_rate:g} Hz, not an IMU rate "
                f"({_RANGE}): give the rate with --rate HZ",
                where=str(path),
            )
        return
    rate = 1.0 / (step * TIME_UNIT_S[o.time_unit]) if step > 0 else 0.0
    edge = whole and not o.time_unit_given and rate <= RATE_MIN_HZ * (1 + 1e-9)
    if not step > 0 or (rate_ok(rate) and not edge):
        return
    u = likely_time_unit(step, o.time_unit, keep_declared=not edge)
    if edge and u is not None:
        raise UnitsError(
            f"time column {column!r} holds whole numbers {step:g} apart: read in {o.time_unit} that is "
            f"{rate:.3g} Hz, read in {u} {1.0 / (step * TIME_UNIT_S[u]):.3g} Hz: time column looks like "
            f"{TIME_UNIT_NAME[u]}: pass --time-unit {u} (or --time-unit {o.time_unit} if it is a {rate:.3g} Hz log)",
            where=str(path),
        )
    fix = (
        f"time column looks like {TIME_UNIT_NAME[u]}: pass --time-unit {u}"
        if u is not None
        else f"no time unit makes it one: check that column {column!r} holds the time (--columns t=NAME)"
    )
    raise UnitsError(
        f"time column {column!r} read in {o.time_unit} has a median step of {step:.4g} {o.time_unit}, "
        f"a rate of {rate:.3g} Hz (an IMU samples at {_RANGE}): {fix}",
        where=str(path),
    )


def check_time_range(path, t_raw: np.ndarray, t_s: np.ndarray, line_of) -> None:
    """Refuse a time stamp that int64 nanoseconds cannot hold (|t| >= MAX_TIME_S from the origin)."""
    far = np.flatnonzero(~(np.abs(t_s) < MAX_TIME_S))
    if far.size:
        i = int(far[0])
        raise InputError(
            f"time stamp {t_raw[i]} is {float(t_s[i]):.3g} s from the first stamp, beyond what int64 "
            f"nanoseconds hold (+-{MAX_TIME_S:.3g} s): a corrupt time value?",
            where=f"{path}:{line_of(i)}",
        )


def offset_hint(raw: np.ndarray, flag: str = "--count-offset") -> str:
    """' --count-offset 32768' when the values sit around 32768 (offset-binary 16-bit counts)."""
    return f" {flag} 32768" if abs(float(np.median(raw)) - _CENTRE) < 8192 else ""


def check_offsets(path, a: np.ndarray, w: np.ndarray | None, o: CsvOptions) -> None:
    """A count offset subtracted from columns that do not need it (signed counts centred on 0), or
    offset-binary gyro counts without one; the message says which columns each offset applies to."""
    gyro_too = o.gyro_unit == "counts" and o.gyro_count_offset is None
    if o.unit == "counts" and o.count_offset:
        lsb = o.counts_lsb_per_g()
        m0 = float(np.median(np.linalg.norm(a, axis=1))) / lsb
        m1 = float(np.median(np.linalg.norm(a - o.count_offset, axis=1))) / lsb
        if 0.5 <= m0 <= 2.0 and not 0.5 <= m1 <= 2.0:
            also = (
                f" (and --gyro-count-offset {o.count_offset:g} if gx,gy,gz need it)"
                if o.gyro_unit == "counts"
                else ""
            )
            raise UnitsError(
                f"--count-offset {o.count_offset:g} is subtracted from ax,ay,az{' and gx,gy,gz' if gyro_too else ''}"
                ", but ax,ay,az are signed "
                f"counts already (|a| = {m0:.3g} g without it, {m1:.3g} g with it): drop --count-offset{also}",
                where=str(path),
            )
    if w is None or o.gyro_unit != "counts":
        return
    med = np.median(w, axis=0)
    if o.gyro_offset and np.all(np.abs(med) < abs(o.gyro_offset) / 4):
        flag = "--count-offset" if gyro_too else "--gyro-count-offset"
        also = " (as from ax,ay,az)" if gyro_too and o.unit == "counts" else ""
        raise UnitsError(
            f"{flag} {o.gyro_offset:g} is subtracted from gx,gy,gz{also}, but gx,gy,gz are centred on 0 "
            f"(medians {', '.join(f'{v:.0f}' for v in med)}): use --gyro-count-offset 0",
            where=str(path),
        )
    if not o.gyro_offset and np.all(np.abs(med - _CENTRE) < 8192):
        raise UnitsError(
            f"gyro counts gx,gy,gz are centred on 32768 (medians {', '.join(f'{v:.0f}' for v in med)}): "
            "they look like offset-binary counts: use --gyro-count-offset 32768",
            where=str(path),
        )


def check_gyro(path, w: np.ndarray, o: CsvOptions) -> None:
    """Gyro values declared as deg/s or rad/s that only make sense as raw counts (whole numbers are
    taken as they are when the user named the unit with --gyro-unit)."""
    if o.gyro_unit == "counts":
        return
    to_dps = 180.0 / np.pi if o.gyro_unit == "rad/s" else 1.0
    why = gyro_counts_evidence(w, o.unit == "counts", to_dps)
    if why is None or (o.gyro_unit_given and why.startswith("are whole")):
        return
    off = ""
    if not o.count_offset and offset_hint(w):
        off = " --gyro-count-offset 32768" if o.unit == "counts" else " --count-offset 32768"
    keep = (
        f"; or --gyro-unit {o.gyro_unit} if they really are whole {o.gyro_unit}"
        if why.startswith("are whole")
        else ""
    )
    raise UnitsError(
        f"gyro values gx,gy,gz declared as {o.gyro_unit} {why}: they look like raw counts "
        f"({GYRO_LSB_HINT}{keep}): use --gyro-unit counts --gyro-lsb-per-dps LSB{off}",
        where=str(path),
    )


def check_gyro_motion(path, turns: GravityTurns, o: CsvOptions) -> None:
    """Refuse a gyro read as deg/s that integrates ~57x less than the turns gravity shows over the
    whole file (rad/s values; core.plausible.GravityTurns): judged after the last row, since the
    first rows are often still. Not when the user named the unit with --gyro-unit."""
    if o.gyro_unit_given or o.gyro_unit != "deg/s" or not turns.looks_like_rad_s():
        return
    raise UnitsError(
        f"gyro values gx,gy,gz read as deg/s integrate to {turns.gyro_deg:.3g} deg over the moves in which "
        f"gravity turns by {turns.turn_deg:.0f} deg ({turns.ratio():.3g}x less; 180/pi = 57.3): they look "
        "like rad/s: pass --gyro-unit rad/s (or --gyro-unit deg/s if they really are deg/s)",
        where=str(path),
    )


def check_accel(path, raw: np.ndarray, o: CsvOptions) -> None:
    """Refuse accelerations whose median |a| is not ~1 g in the declared unit; the hint names flags
    the user has not given yet (it never loops back to the options already in use)."""
    m = float(np.median(np.linalg.norm(raw - (o.count_offset if o.unit == "counts" else 0.0), axis=1)))
    to_g = {"g": 1.0, "m/s^2": 1.0 / STANDARD_GRAVITY_MPS2, "counts": 1.0 / (o.lsb_per_g or 1.0)}[o.unit]
    to_g *= o.accel_scale
    if 0.5 <= m * to_g <= 2.0:
        return
    offset = "" if o.count_offset else offset_hint(raw)
    guess = accel_unit_guess(m)
    scale = accel_scale_guess(m * to_g) if o.unit != "counts" else None
    if offset:
        lsb = nearest_accel_lsb(float(np.median(np.linalg.norm(raw - _CENTRE, axis=1))))
        why = "they look like offset-binary counts centred on 32768"
        flags = ["--unit counts", "--count-offset 32768", f"--lsb-per-g {o.lsb_per_g or lsb:g}"]
    elif guess is None and scale is not None:
        k = scale * o.accel_scale
        why = (
            f"x{scale:g} makes it {m * to_g * scale:.3g} g: a full-scale mismatch (the logger converted "
            "with another range's LSB/g, e.g. +-8 g counts at +-2 g's 16384)"
        )
        flags = [f"--accel-scale {k:g}"]
    elif guess is None:
        why, flags = "", []
    elif guess[0] == "counts":
        why = "they look like raw counts"
        if o.unit == "counts":
            why = f"with --lsb-per-g {o.lsb_per_g:g} that is {m * to_g:.3g} g"
        flags = ["--unit counts", f"--lsb-per-g {guess[1]:g}"]
    else:
        why, flags = f"they look like {guess[0]}", [f"--unit {guess[0]}"]
    new = [f for f in flags if f not in o.given_flags()]
    if new:
        hint = f"{why}: use {' '.join(flags)}"
    else:  # every flag the evidence points to is already given: never loop back to them
        hint = "no unit or scale makes this ~1 g at rest: check --columns and the file's units"
    raise UnitsError(
        f"accelerometer values declared as {o.unit} have a median magnitude of {m:.4g} "
        f"{o.unit}{' (after the offset)' if o.unit == 'counts' and o.count_offset else ''} "
        f"(a recording should read ~1 g at rest): {hint}",
        where=str(path),
    )
