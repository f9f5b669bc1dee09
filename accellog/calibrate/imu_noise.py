"""IMU noise characterisation of a still recording in Kalibr's continuous-time convention.

Kalibr's model per axis (wiki "IMU Noise Model"): w_meas = w + b + n, n white with density sigma
(noise density, one number per sensor), b' = sigma_b w (random walk). The discrete standard deviation
of n at sample time dt is sigma_d = sigma / sqrt(dt), so

    noise density        sigma = sigma_d * sqrt(dt)          (accel m/s^2/sqrt(Hz), gyro rad/s/sqrt(Hz))

sigma_d is estimated robustly from first differences (var(diff) = 2 sigma_d^2 for white noise;
slow bias motion cancels). The random walk sigma_b (accel m/s^3/sqrt(Hz), gyro rad/s^2/sqrt(Hz)) is
read from the overlapping Allan deviation: a rate random walk gives sigma_A(tau) = sigma_b
sqrt(tau/3), a +1/2 slope. Where the slope reaches +1/2 (>= 0.35 in log-log over the last octaves),
sigma_b = sigma_A(tau) sqrt(3/tau) there; otherwise the recording is too short to see it and
sigma_A(tau_max) sqrt(3/tau_max) is reported as an upper bound (``random_walk_is_bound``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.core.units import STANDARD_GRAVITY_MPS2


def overlapping_allan_dev(x: np.ndarray, dt: float, taus_n: np.ndarray) -> np.ndarray:
    """(len(taus_n), k) overlapping Allan deviation of rate samples x (n,k) at cluster sizes taus_n."""
    theta = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)]) * dt
    out = np.empty((taus_n.shape[0], x.shape[1]))
    for i, m in enumerate(taus_n):
        d = theta[2 * m :] - 2 * theta[m:-m] + theta[: -2 * m]
        out[i] = np.sqrt(np.mean(d * d, axis=0) / (2.0 * (m * dt) ** 2))
    return out


def _random_walk(x: np.ndarray, dt: float) -> tuple[np.ndarray, bool]:
    n = x.shape[0]
    m_max = n // 9
    if m_max < 4:
        raise InputError(f"{n} samples: too short for an Allan deviation (needs >= 36)")
    taus_n = np.unique(np.round(np.logspace(0, np.log10(m_max), 24)).astype(int))
    adev = overlapping_allan_dev(x, dt, taus_n)
    tau = taus_n * dt
    k = max(3, taus_n.shape[0] // 6)
    slope = np.polyfit(np.log(tau[-k:]), np.log(adev[-k:]), 1)[0]  # (k_axes,)
    rw = adev[-1] * np.sqrt(3.0 / tau[-1])
    return rw, bool(np.any(slope < 0.35))


@dataclass
class NoiseCharacterisation:
    """Kalibr-convention noise of one still recording (per axis and the max over axes)."""

    accelerometer_noise_density: float
    accelerometer_random_walk: float
    gyroscope_noise_density: float | None
    gyroscope_random_walk: float | None
    random_walk_is_bound: bool
    sample_rate_hz: float
    duration_s: float
    per_axis: dict
    source: str

    def to_dict(self) -> dict:
        return asdict(self)


def characterise_noise(s: Session) -> NoiseCharacterisation:
    """Noise densities and random walks (Kalibr units) of a still session; see the module docstring."""
    if s.n < 100:
        raise InputError(f"{s.n} samples: a noise characterisation needs a still recording", where=s.path)
    dt = float(np.median(np.diff(s.t_s)))
    acc = s.accel_g * STANDARD_GRAVITY_MPS2
    if float(np.max(np.std(acc, axis=0))) > 0.5:
        raise InputError("the recording moves (accel std > 0.5 m/s^2): use a still recording", where=s.path)

    def sigma_d(x):
        d = np.diff(x, axis=0)
        mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
        return 1.4826 * mad / np.sqrt(2.0)

    a_nd = sigma_d(acc) * np.sqrt(dt)
    a_rw, a_bound = _random_walk(acc, dt)
    per = {"accel_noise_density": a_nd.tolist(), "accel_random_walk": a_rw.tolist()}
    g_nd = g_rw = None
    g_bound = False
    if s.gyro_dps is not None:
        w = np.deg2rad(s.gyro_dps)
        g_nd_ax = sigma_d(w) * np.sqrt(dt)
        g_rw_ax, g_bound = _random_walk(w, dt)
        per.update(gyro_noise_density=g_nd_ax.tolist(), gyro_random_walk=g_rw_ax.tolist())
        g_nd, g_rw = float(g_nd_ax.max()), float(g_rw_ax.max())
    return NoiseCharacterisation(
        accelerometer_noise_density=float(a_nd.max()),
        accelerometer_random_walk=float(a_rw.max()),
        gyroscope_noise_density=g_nd,
        gyroscope_random_walk=g_rw,
        random_walk_is_bound=a_bound or g_bound,
        sample_rate_hz=1.0 / dt,
        duration_s=float(s.t_s[-1] - s.t_s[0]),
        per_axis=per,
        source=s.path or s.meta.source,
    )
