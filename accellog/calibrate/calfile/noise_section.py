"""The calibration file's `noise` section, typed (written by `accellog noise --cal`).

Per sensor (accel, gyro) and axis (x, y, z) the four Allan-deviation terms of
accellog.calibrate.noise.noise_model, each a value with its 1-sigma in SI units (the section's `units`):

    white N (accel m/s^2/sqrt(Hz), gyro rad/s/sqrt(Hz)),   ADEV(tau) = N / sqrt(tau)
    bias_instability B,  random_walk K,  quantisation Q

plus Kalibr's four values (worst axis, continuous time; what exporters read). The JSON form is an
interface: read and written again it is the same text (accellog.calibrate.calfile.sections.Section).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from accellog.calibrate.calfile.sections import Section, json_field
from accellog.core.errors import InputError

NOISE_SECTION_VERSION = 1
AXES = ("x", "y", "z")


@dataclass(frozen=True)
class NoiseTerm(Section):
    """One fitted noise term of one axis: value and 1-sigma (units: the sensor's `units`)."""

    NAME: ClassVar[str] = "term"

    value: float | None = json_field("num")
    sigma: float | None = json_field("num")


@dataclass(frozen=True)
class AxisNoiseTerms(Section):
    """The four Allan terms of one axis."""

    NAME: ClassVar[str] = "axis"

    white: NoiseTerm | None = json_field(NoiseTerm)  # noqa: RUF009 (a dataclasses.field)
    bias_instability: NoiseTerm | None = json_field(NoiseTerm)  # noqa: RUF009 (a dataclasses.field)
    random_walk: NoiseTerm | None = json_field(NoiseTerm)  # noqa: RUF009 (a dataclasses.field)
    quantisation: NoiseTerm | None = json_field(NoiseTerm)  # noqa: RUF009 (a dataclasses.field)


@dataclass(frozen=True)
class SensorNoiseTerms(Section):
    """Noise terms of one sensor: units per term name, terms per axis ('x', 'y', 'z')."""

    NAME: ClassVar[str] = "sensor"

    units: Mapping[str, str] | None = json_field("strmap")
    axes: Mapping[str, AxisNoiseTerms] | None = json_field(("map", AxisNoiseTerms))

    def white(self) -> np.ndarray:
        """(3,) white noise N of the x, y, z axes (SI units; NaN where not given)."""
        out = []
        for ax in AXES:
            t = (self.axes or {}).get(ax)
            v = None if t is None or t.white is None else t.white.value
            out.append(np.nan if v is None else float(v))
        return np.array(out)


@dataclass(frozen=True)
class NoiseSection(Section):
    """The `noise` section: the session it came from, Kalibr's values, and per sensor the terms."""

    NAME: ClassVar[str] = "noise"

    version: int | None = json_field("int")
    source: str | None = json_field("str")
    """The still recording characterised."""
    duration_s: float | None = json_field("num")
    rate_hz: float | None = json_field("num")
    """Sample rate of that recording (Hz)."""
    convention: str | None = json_field("str")
    kalibr: Mapping[str, float] | None = json_field("nummap")
    """accelerometer_noise_density, accelerometer_random_walk, gyroscope_noise_density, gyroscope_random_walk."""
    kalibr_random_walk_is_bound: bool | None = json_field("bool")
    """True when a random walk was not resolved and Kalibr's value is its 2-sigma bound."""
    accel: SensorNoiseTerms | None = json_field(SensorNoiseTerms, optional=True)  # noqa: RUF009 (a dataclasses.field)
    gyro: SensorNoiseTerms | None = json_field(SensorNoiseTerms, optional=True)  # noqa: RUF009 (a dataclasses.field)

    @classmethod
    def from_dict(cls, d: Any, where: str | None = None, *, name: str | None = None) -> NoiseSection:
        """The section, checked: an integer version this accellog reads and, per sensor present,
        numeric white values of axes x, y, z (one-line InputError otherwise)."""
        if not isinstance(d, Mapping) or not isinstance(d.get("version"), int):
            raise InputError("calibration 'noise' section has no integer version", where=where)
        if d["version"] > NOISE_SECTION_VERSION:
            raise InputError(
                f"calibration 'noise' section version {d['version']} is newer than this accellog "
                f"(reads <= {NOISE_SECTION_VERSION})",
                where=where,
            )
        sec = super().from_dict(d, where, name=name)
        for s, sensor in ((sec.accel, "accel"), (sec.gyro, "gyro")):
            if s is not None and not np.isfinite(s.white()).all():
                raise InputError(f"calibration 'noise.{sensor}' lacks axes x/y/z white values", where=where)
        return sec

    def white_noise(self, sensor: str = "accel") -> np.ndarray | None:
        """(3,) white noise N per axis (m/s^2/sqrt(Hz) or rad/s/sqrt(Hz)), None without that sensor."""
        s = self.accel if sensor == "accel" else self.gyro
        return None if s is None else s.white()
