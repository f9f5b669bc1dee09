"""The noise values other tools take (Kalibr's continuous-time convention), from accellog's noise model.

Kalibr per axis (wiki "IMU Noise Model"): w_meas = w + b + n, n white with density sigma, b' = sigma_b w.
sigma is the Allan white-noise coefficient N (accel m/s^2/sqrt(Hz), gyro rad/s/sqrt(Hz)) and sigma_b the
rate-random-walk coefficient K (m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz)) of `accellog noise`
(accellog.calibrate.noise.noise_model, fitted to the overlapping Allan deviation). Kalibr takes one number per
sensor: the worst axis. A random walk the recording is too short to resolve is given as its 2-sigma upper
bound (``random_walk_is_bound``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from accellog.calibrate.calfile.noise_section import NoiseSection
from accellog.calibrate.noise.noise_model import NoiseModel
from accellog.core.errors import InputError


@dataclass
class NoiseCharacterisation:
    """Kalibr-convention noise of one still recording (the worst axis of each sensor)."""

    accelerometer_noise_density: float
    accelerometer_random_walk: float
    gyroscope_noise_density: float | None
    gyroscope_random_walk: float | None
    random_walk_is_bound: bool
    sample_rate_hz: float
    duration_s: float
    source: str

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_model(cls, m: NoiseModel) -> NoiseCharacterisation:
        """From a fitted noise model (flows.characterise.characterise_noise)."""
        if m.accel is None:
            raise InputError("the noise characterisation has no accelerometer terms", where=m.source)
        k = m.kalibr()
        bound = any(not a.random_walk.detected for s in m.sensors() for a in s.axes)
        return cls._from_values(k, bound, m.rate_hz, m.duration_s, m.source)

    @classmethod
    def from_section(cls, d: NoiseSection) -> NoiseCharacterisation:
        """From the 'noise' section of a calibration file (written by `accellog noise --cal`)."""
        k = dict(d.kalibr or {})
        if "accelerometer_noise_density" not in k:
            raise InputError("the calibration's noise section has no Kalibr values: rerun `accellog noise`")
        if d.rate_hz is None or d.duration_s is None:
            raise InputError(
                "the calibration's noise section has no rate_hz or duration_s: rerun `accellog noise`"
            )
        bound = True if d.kalibr_random_walk_is_bound is None else d.kalibr_random_walk_is_bound
        return cls._from_values(k, bound, float(d.rate_hz), float(d.duration_s), d.source or "")

    @classmethod
    def _from_values(cls, k: dict, bound: bool, rate_hz: float, duration_s: float, source: str):
        return cls(
            accelerometer_noise_density=float(k["accelerometer_noise_density"]),
            accelerometer_random_walk=float(k["accelerometer_random_walk"]),
            gyroscope_noise_density=k.get("gyroscope_noise_density"),
            gyroscope_random_walk=k.get("gyroscope_random_walk"),
            random_walk_is_bound=bound,
            sample_rate_hz=rate_hz,
            duration_s=duration_s,
            source=source,
        )
