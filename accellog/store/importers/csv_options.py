"""Options of the generic CSV importer: column map, units, counts, time and rate, delimiter, comments.

Conversions (applied by ``accellog.store.importers.csv``, recorded in the session's meta.extra):

    accel_g   = a_g                 | a_mps2 / 9.80665         | (raw - count_offset) / lsb_per_g
                (times accel_scale for g and m/s^2: a full-scale mismatch of the logger)
    gyro_dps  = w_dps               | w_radps * 180 / pi       | (raw - gyro_offset) / gyro_lsb_per_dps
    t_s       = t * {s: 1, ms: 1e-3, us: 1e-6, ns: 1e-9}       | row / rate_hz (no time column)

Offset-binary ("unsigned") counts are centred on 32768: ``count_offset = 32768`` gives signed counts.
``count_offset`` is subtracted from every counts column (ax,ay,az with unit counts, gx,gy,gz with
gyro_unit counts); ``gyro_count_offset`` (when given) replaces it for the gyro columns:
gyro_offset = gyro_count_offset if given else count_offset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from accellog.core.errors import InputError
from accellog.core.plausible import RATE_MAX_HZ, RATE_MIN_HZ, rate_ok

ACCEL_UNITS = ("g", "m/s^2", "counts")
GYRO_UNITS = ("deg/s", "rad/s", "counts")
BAD_ROWS = ("refuse", "skip")
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_ALIASES = {
    "mps2": "m/s^2",
    "m/s2": "m/s^2",
    "m/s/s": "m/s^2",
    "dps": "deg/s",
    "deg": "deg/s",
    "radps": "rad/s",
    "rad": "rad/s",
    "raw": "counts",
    "sec": "s",
    "µs": "us",
}
FIELDS = (
    "t",
    "ax",
    "ay",
    "az",
    "temp",
    "gx",
    "gy",
    "gz",
    "pose",
    "true_x",
    "true_y",
    "true_z",
    "qw",
    "qx",
    "qy",
    "qz",
)
"""accellog's column names: time, accel, temperature (degC), gyro, pose label, up vector, quaternion."""
GROUPS = (("ax", "ay", "az"), ("gx", "gy", "gz"), ("true_x", "true_y", "true_z"), ("qw", "qx", "qy", "qz"))
OPTIONAL_VALUES = ("true_x", "true_y", "true_z", "qw", "qx", "qy", "qz")
"""Columns whose cells may be empty (NaN): they only matter during a labelled hold."""


def _unit(kind: str, value: str, allowed) -> str:
    v = _ALIASES.get(value.strip().lower(), value.strip())
    if v not in allowed:
        raise InputError(f"unknown {kind} {value!r}: use one of {', '.join(allowed)}")
    return v


def parse_columns(text: str | None) -> dict[str, str]:
    """'t=time,ax=acc_x,...' -> {'t': 'time', 'ax': 'acc_x', ...} (accellog name = file column name)."""
    out: dict[str, str] = {}
    for part in (text or "").split(","):
        if not part.strip():
            continue
        key, sep, val = part.partition("=")
        key, val = key.strip(), val.strip()
        if not sep or not val:
            raise InputError(f"--columns: {part.strip()!r} is not NAME=COLUMN (e.g. t=time,ax=acc_x)")
        if key not in FIELDS:
            raise InputError(f"--columns: unknown name {key!r}: use {', '.join(FIELDS)}")
        if key in out:
            raise InputError(f"--columns: {key!r} given twice")
        twice = [k for k, v in out.items() if v == val]
        if twice:  # ax=X,ay=X: one column read as two axes
            raise InputError(f"--columns: column {val!r} is mapped twice ({twice[0]} and {key})")
        out[key] = val
    return out


@dataclass(frozen=True)
class CsvOptions:
    """How to read one logger's CSV (see the module docstring for the conversions)."""

    unit: str = "g"
    lsb_per_g: float | None = None
    count_offset: float = 0.0
    accel_scale: float = 1.0
    """Multiplies accelerations in g or m/s^2 (a logger that converted with another range's LSB/g)."""
    gyro_unit: str = "deg/s"
    gyro_unit_given: bool = False
    """True when the user named the gyro unit (then whole-number deg/s are taken as they are)."""
    gyro_count_offset: float | None = None
    gyro_lsb_per_dps: float | None = None
    time_unit: str = "s"
    time_unit_given: bool = False
    """True when the user named the time unit (then whole-number stamps 1 s apart are taken as 1 Hz)."""
    rate_hz: float | None = None
    columns: dict[str, str] = field(default_factory=dict)
    delimiter: str = ","
    comment: str = "#"
    strict_time: bool = True
    """Refuse duplicated / backward stamps (False: keep them as they are, for ``accellog doctor``)."""
    check_units: bool = True
    """Refuse implausible units and rates (False: read as declared, for ``accellog doctor``)."""
    bad_rows: str = "refuse"
    """A row that does not parse (column count, empty or non-number cell, not UTF-8): 'refuse' the
    file with its line, or 'skip' it, each skipped row an event of the session (kind 'skipped_row')."""

    @classmethod
    def make(cls, *, columns: str | dict | None = None, **kw) -> CsvOptions:
        """Validated options (unit aliases such as 'dps', 'mps2', 'raw' accepted); raises InputError."""
        cols = parse_columns(columns) if isinstance(columns, str) or columns is None else dict(columns)
        unit = _unit("unit", kw.pop("unit", "g") or "g", ACCEL_UNITS)
        gyro_given = kw.get("gyro_unit") is not None
        time_given = kw.get("time_unit") is not None
        gyro = _unit("gyro unit", kw.pop("gyro_unit", "deg/s") or "deg/s", GYRO_UNITS)
        tu = _unit("time unit", kw.pop("time_unit", "s") or "s", tuple(TIME_UNITS))
        delim = kw.pop("delimiter", ",") or ","
        delim = {"tab": "\t", "\\t": "\t", "space": " ", "semicolon": ";"}.get(delim, delim)
        if len(delim) != 1:
            raise InputError(f"--delimiter must be one character (or tab/space), got {delim!r}")
        comment = kw.pop("comment", "#") or ""
        if len(comment) > 1:
            raise InputError(f"--comment must be one character, got {comment!r}")
        kw.setdefault("gyro_unit_given", gyro_given)
        kw.setdefault("time_unit_given", time_given)
        opts = cls(
            unit=unit, gyro_unit=gyro, time_unit=tu, columns=cols, delimiter=delim, comment=comment, **kw
        )
        opts.check()
        return opts

    def counts_lsb_per_g(self) -> float:
        """lsb_per_g of a --unit counts file (LSB/g; InputError when it was not given)."""
        if not self.lsb_per_g:
            raise InputError("--unit counts needs --lsb-per-g (e.g. 16384 for +-2 g)")
        return self.lsb_per_g

    def counts_lsb_per_dps(self) -> float:
        """gyro_lsb_per_dps of a --gyro-unit counts file (LSB/(deg/s); InputError when not given)."""
        if not self.gyro_lsb_per_dps:
            raise InputError("--gyro-unit counts needs --gyro-lsb-per-dps (e.g. 131 for +-250 deg/s)")
        return self.gyro_lsb_per_dps

    def check(self) -> None:
        if self.unit == "counts":
            self.counts_lsb_per_g()
        if self.lsb_per_g is not None and not 0 < self.lsb_per_g < math.inf:
            raise InputError(f"--lsb-per-g must be a positive number, got {self.lsb_per_g:g}")
        if self.gyro_unit == "counts":
            self.counts_lsb_per_dps()
        if self.gyro_lsb_per_dps is not None and not 0 < self.gyro_lsb_per_dps < math.inf:
            raise InputError(f"--gyro-lsb-per-dps must be a positive number, got {self.gyro_lsb_per_dps:g}")
        if not (0 < self.accel_scale < math.inf):
            raise InputError(f"--accel-scale must be a positive number, got {self.accel_scale:g}")
        if self.accel_scale != 1.0 and self.unit == "counts":
            raise InputError("--accel-scale is for --unit g or m/s^2: with counts give the right --lsb-per-g")
        for name, v in (
            ("--count-offset", self.count_offset),
            ("--gyro-count-offset", self.gyro_count_offset),
        ):
            if v is not None and not math.isfinite(v):
                raise InputError(f"{name} must be a finite number, got {v:g}")
        if self.count_offset and "counts" not in (self.unit, self.gyro_unit):
            raise InputError("--count-offset applies to counts: give --unit counts and/or --gyro-unit counts")
        if self.gyro_count_offset is not None and self.gyro_unit != "counts":
            raise InputError(
                "--gyro-count-offset applies to the gyro counts (gx,gy,gz): give --gyro-unit counts"
            )
        if self.bad_rows not in BAD_ROWS:
            raise InputError(f"--bad-rows must be one of {', '.join(BAD_ROWS)}, got {self.bad_rows!r}")
        if self.rate_hz is not None and not self.rate_hz > 0:
            raise InputError(f"--rate must be positive, got {self.rate_hz:g}")
        if self.rate_hz is not None and not rate_ok(self.rate_hz):
            raise InputError(
                f"--rate {self.rate_hz:g} Hz is not an IMU sample rate ({RATE_MIN_HZ:g} Hz .. {RATE_MAX_HZ:g} Hz)"
            )

    @property
    def gyro_offset(self) -> float:
        """Subtracted from gyro counts: gyro_count_offset when given, else count_offset."""
        return self.count_offset if self.gyro_count_offset is None else self.gyro_count_offset

    def offset_columns(self) -> str:
        """Which columns the count offsets are subtracted from, e.g. 'ax,ay,az - 32768; gx,gy,gz - 0'."""
        parts = []
        if self.unit == "counts":
            parts.append(f"ax,ay,az - {self.count_offset:g}")
        if self.gyro_unit == "counts":
            parts.append(f"gx,gy,gz - {self.gyro_offset:g}")
        return "; ".join(parts)

    def column(self, name: str) -> str:
        """The file's column holding accellog's ``name``."""
        return self.columns.get(name, name)

    def given_flags(self) -> set[str]:
        """Flags (with values) in use, so that hints never suggest them again."""
        flags = {f"--unit {self.unit}", f"--gyro-unit {self.gyro_unit}"}
        if self.count_offset:
            flags.add(f"--count-offset {self.count_offset:g}")
        if self.gyro_count_offset is not None:
            flags.add(f"--gyro-count-offset {self.gyro_count_offset:g}")
        if self.lsb_per_g:
            flags.add(f"--lsb-per-g {self.lsb_per_g:g}")
        if self.accel_scale != 1.0:
            flags.add(f"--accel-scale {self.accel_scale:g}")
        return flags
