"""Fitted noise parameters of a rate sensor from its Allan variance, with 1-sigma uncertainties and units.

Model of the Allan variance (IEEE Std 952-1997 Annex C; one term per power law):

    AVAR(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3

- Q  quantisation noise (u s), white phase: ADEV slope -1;
- N  white noise density, VRW (accel) / ARW (gyro), u / sqrt(Hz) = u sqrt(s): slope -1/2, N = ADEV(1 s);
- B  bias instability (u), flicker: flat floor ADEV = 0.664 B;
- K  rate random walk, u / s / sqrt(Hz) = u / sqrt(s): slope +1/2, K = ADEV(3 s).

u is m/s^2 for the accelerometer, rad/s for the gyro. N is the Allan / IEEE / Kalibr convention
(ADEV(tau) = N / sqrt(tau); a discrete sensor at f_s Hz has per-sample sigma N sqrt(f_s)); a datasheet's
one-sided noise spectral density is sqrt(2) N (reported too, as ``density_one_sided``).

The four coefficients c = (3Q^2, N^2, 0.4413 B^2, K^2/3) enter linearly: weighted non-negative least squares
on the AVAR points (weights edf / (2 AVAR_model^2), var(AVAR) = 2 AVAR^2 / edf, iterated with the noise type
alpha of the dominant term), covariance (A^T W A)^-1 inflated by the reduced chi-square when > 1 and by
``CORRELATION_INFLATION`` for the correlation of octave-spaced overlapping estimates. Taus below
``tau_min_s`` (the sensor's low-pass filter correlates neighbouring samples) are not fitted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from accellog.calibrate.calfile.noise_section import (
    NOISE_SECTION_VERSION,
    AxisNoiseTerms,
    NoiseSection,
    NoiseTerm,
    SensorNoiseTerms,
)
from accellog.calibrate.noise.allan import (
    ALPHA_FLICKER_FM,
    ALPHA_RW_FM,
    ALPHA_WHITE_FM,
    ALPHA_WHITE_PM,
    AllanCurve,
    edf_simple,
)
from accellog.core.units import STANDARD_GRAVITY_MPS2

BI_FACTOR = 2.0 * math.log(2.0) / math.pi
"""AVAR floor of flicker noise per B^2: ADEV = sqrt(2 ln 2 / pi) B = 0.664 B."""
CORRELATION_INFLATION = 2.0
"""Sigma inflation for the correlation between overlapping AVAR estimates at octave taus (adjacent octaves
share half their data), which the weighted fit treats as independent. Empirical: with 1.5 the pulls
(estimate - truth) / sigma of N, B, K over 12 emulated 2 h sessions had rms 1.2, 1.1, 1.6; the coverage
test (tests/calibrate/test_allan.py) checks 2.0 on other seeds."""
EDF_TARGET = 32.0
"""EDF at the characteristic tau that a parameter needs (ADEV known to 1/sqrt(2 edf) = 12.5 %)."""
_ALPHAS = np.array([ALPHA_WHITE_PM, ALPHA_WHITE_FM, ALPHA_FLICKER_FM, ALPHA_RW_FM])
RAD_PER_DEG = math.pi / 180.0


def design(tau_s: np.ndarray) -> np.ndarray:
    """(t, 4) columns 1/tau^2, 1/tau, 1, tau of the AVAR model for c = (3Q^2, N^2, 0.4413 B^2, K^2/3)."""
    t = np.asarray(tau_s, float)
    return np.stack([1.0 / t**2, 1.0 / t, np.ones_like(t), t], axis=1)


@dataclass
class Param:
    """One fitted parameter: value and 1-sigma (SI unit ``unit``), and the session length it needs."""

    value: float
    sigma: float
    unit: str
    min_duration_s: float | None = None
    """Session length giving EDF >= 32 where this term dominates; None: the term is not seen."""
    detected: bool = False
    """value > 2 sigma."""

    def to_dict(self) -> dict:
        return {
            "value": self.value,
            "sigma": self.sigma,
            "unit": self.unit,
            "detected": self.detected,
            "min_duration_s": self.min_duration_s,
        }


@dataclass
class AxisNoise:
    """Fitted noise terms of one axis (SI units) and its Allan curve with confidence intervals."""

    axis: str
    quantisation: Param
    white: Param
    bias_instability: Param
    random_walk: Param
    tau_s: np.ndarray
    adev: np.ndarray
    adev_lo: np.ndarray
    adev_hi: np.ndarray
    fitted: np.ndarray
    """(t,) bool: taus used by the fit."""
    chi2_reduced: float

    def model_adev(self, tau_s: np.ndarray) -> np.ndarray:
        c = np.array(
            [
                3 * self.quantisation.value**2,
                self.white.value**2,
                BI_FACTOR * self.bias_instability.value**2,
                self.random_walk.value**2 / 3,
            ]
        )
        return np.sqrt(design(tau_s) @ c)


def _dominant_alpha(c: np.ndarray, tau_s: np.ndarray) -> np.ndarray:
    return _ALPHAS[np.argmax(design(tau_s) * c, axis=1)]


def fit_axis(
    curve: AllanCurve, col: int, axis: str, unit: str, tau_min_s: float, fit_quantisation: bool = False
) -> AxisNoise:
    """Fit the AVAR model to column ``col`` of ``curve`` (taus >= tau_min_s, >= 2 points).

    Q is fitted only when ``fit_quantisation`` (the readings move by a few LSB): above the low-pass
    corner it is not observable and would only trade off against N (it is then reported as 0, not
    resolved)."""
    from scipy.optimize import nnls

    tau, avar = curve.tau_s, curve.avar[:, col]
    use = (tau >= tau_min_s) & (avar > 0) & (curve.n_terms >= 8)
    if use.sum() < 2:
        use = avar > 0
    A, v = design(tau[use]), avar[use]
    if not fit_quantisation:
        A[:, 0] = 0.0  # Q fixed at 0: its column never enters the solution
    scale = np.abs(A).max(axis=0)  # column scaling: taus span decades
    scale[scale == 0] = 1.0
    w = np.ones_like(v) / v**2
    c = np.zeros(4)
    for _ in range(4):
        sw = np.sqrt(w)
        cs, _ = nnls(A / scale * sw[:, None], v * sw)
        c = cs / scale
        model = np.maximum(A @ c, 1e-300)
        edf = edf_simple(curve.n_phase, curve.m[use], _dominant_alpha(c, tau[use]))
        w = edf / (2.0 * model**2)
    resid = (v - A @ c) * np.sqrt(w)
    dof = max(int(use.sum()) - int(np.count_nonzero(c)), 1)
    chi2r = float(resid @ resid / dof)
    active = c > 0
    cov = np.zeros((4, 4))
    Aw = A / scale * np.sqrt(w)[:, None]
    info = Aw.T @ Aw
    try:
        full = np.linalg.pinv(info) / np.outer(scale, scale)
        if active.any():
            ia = np.flatnonzero(active)
            cov_a = np.linalg.pinv(info[np.ix_(ia, ia)]) / np.outer(scale[ia], scale[ia])
            cov[np.ix_(ia, ia)] = cov_a
        for j in np.flatnonzero(~active):  # clamped at 0: sigma of the free estimate (an upper scale)
            cov[j, j] = max(full[j, j], 0.0) if A[:, j].any() else np.nan
    except np.linalg.LinAlgError:
        cov[:] = np.nan
    cov *= max(chi2r, 1.0) * CORRELATION_INFLATION**2
    factors = np.array([3.0, 1.0, BI_FACTOR, 1.0 / 3.0])
    params = []
    dominant = _dominant_alpha(c, tau)
    for i, name_unit in enumerate([f"{unit} s", f"{unit}/sqrt(Hz)", unit, f"{unit}/s/sqrt(Hz)"]):
        p = math.sqrt(c[i] / factors[i])
        sv = math.sqrt(cov[i, i]) / factors[i] if np.isfinite(cov[i, i]) else float("nan")  # sigma of p^2
        # p = sqrt(p^2): sigma_p = sigma_v / (2 p); unresolved (sigma_v >= p^2): sqrt(sigma_v), the scale
        # the data can resolve
        sigma = sv / (2 * p) if p > 0 and sv < p**2 else math.sqrt(sv) if sv == sv else float("nan")
        detected = p > 2 * sigma
        params.append(
            Param(
                p,
                float(sigma),
                name_unit,
                _min_duration(curve, tau, dominant, _ALPHAS[i], use) if detected else None,
                bool(detected),
            )
        )
    lo, hi = curve.interval(_dominant_alpha(c, tau)[:, None] * np.ones((1, curve.adev.shape[1]), int))
    quant, white, bias, walk = params
    return AxisNoise(
        axis, quant, white, bias, walk, tau, curve.adev[:, col], lo[:, col], hi[:, col], use, chi2r
    )


def _min_duration(
    curve: AllanCurve, tau: np.ndarray, dominant: np.ndarray, alpha: int, fitted: np.ndarray
) -> float | None:
    """Shortest session with EDF >= EDF_TARGET at the characteristic tau of noise type alpha.

    Characteristic tau (among the fitted taus): the smallest where the term dominates for white and
    quantisation noise, the largest for flicker (the floor) and random walk (where its slope is clear)."""
    where = np.flatnonzero((dominant == alpha) & fitted)
    if where.size == 0:
        return None
    i = where[0] if alpha in (ALPHA_WHITE_PM, ALPHA_WHITE_FM) else where[-1]
    m = float(curve.m[i])
    tau0 = 1.0 / curve.rate_hz
    for n in np.geomspace(max(3 * m, 4), 1e4 * m + 10, 400):
        if edf_simple(int(n), m, alpha) >= EDF_TARGET:
            return float(n * tau0)
    return None


@dataclass
class SensorNoise:
    """Noise of one three-axis sensor ('accel' in m/s^2, 'gyro' in rad/s)."""

    sensor: str
    axes: list[AxisNoise]
    quantum_si: float | None = None
    quantisation_flag: bool = False
    """The reading moves by a few quanta only (sample sigma < 2 LSB) or Q is detected."""

    @property
    def si_unit(self) -> str:
        return "m/s^2" if self.sensor == "accel" else "rad/s"

    def datasheet(self, ax: AxisNoise) -> dict[str, float]:
        """The axis's terms in datasheet units (accel: ug/sqrt(Hz), ug, ug/s/sqrt(Hz); gyro: deg/sqrt(h),
        deg/h, deg/h/sqrt(h)) plus the one-sided density sqrt(2) N."""
        if self.sensor == "accel":
            k = 1e6 / STANDARD_GRAVITY_MPS2  # m/s^2 -> ug
            return {
                "white_ug_per_rtHz": ax.white.value * k,
                "white_sigma_ug_per_rtHz": ax.white.sigma * k,
                "density_one_sided_ug_per_rtHz": math.sqrt(2) * ax.white.value * k,
                "bias_instability_ug": ax.bias_instability.value * k,
                "bias_instability_sigma_ug": ax.bias_instability.sigma * k,
                "random_walk_ug_per_s_rtHz": ax.random_walk.value * k,
                "random_walk_sigma_ug_per_s_rtHz": ax.random_walk.sigma * k,
            }
        d = 1.0 / RAD_PER_DEG
        return {
            "arw_deg_per_rth": ax.white.value * d * 60.0,
            "arw_sigma_deg_per_rth": ax.white.sigma * d * 60.0,
            "density_one_sided_dps_per_rtHz": math.sqrt(2) * ax.white.value * d,
            "bias_instability_deg_per_h": ax.bias_instability.value * d * 3600.0,
            "bias_instability_sigma_deg_per_h": ax.bias_instability.sigma * d * 3600.0,
            "rrw_deg_per_h_rth": ax.random_walk.value * d * 3600.0 * 60.0,
            "rrw_sigma_deg_per_h_rth": ax.random_walk.sigma * d * 3600.0 * 60.0,
        }

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"sensor": self.sensor, "unit": self.si_unit, "quantum": self.quantum_si}
        out["quantisation_flag"] = self.quantisation_flag
        out["axes"] = [
            {
                "axis": a.axis,
                "quantisation": a.quantisation.to_dict(),
                "white": a.white.to_dict(),
                "bias_instability": a.bias_instability.to_dict(),
                "random_walk": a.random_walk.to_dict(),
                "datasheet_units": self.datasheet(a),
                "chi2_reduced": a.chi2_reduced,
                "allan": {
                    "tau_s": a.tau_s.tolist(),
                    "adev": a.adev.tolist(),
                    "adev_lo": a.adev_lo.tolist(),
                    "adev_hi": a.adev_hi.tolist(),
                    "fitted": a.fitted.tolist(),
                },
            }
            for a in self.axes
        ]
        return out

    def worst(self, name: str) -> Param:
        """The axis with the largest value of parameter ``name`` (conservative for a filter)."""
        return max((getattr(a, name) for a in self.axes), key=lambda p: p.value)


@dataclass
class TempSegment:
    """A stretch where the die temperature changes fast enough to drive the bias (long-tau ADEV)."""

    start_s: float
    end_s: float
    rate_degC_per_min: float

    def to_dict(self) -> dict:
        return {"start_s": self.start_s, "end_s": self.end_s, "rate_degC_per_min": self.rate_degC_per_min}


@dataclass
class NoiseModel:
    """The noise characterisation of a static session: accel and gyro terms, flags, provenance."""

    source: str
    duration_s: float
    rate_hz: float
    n_samples: int
    accel: SensorNoise | None
    gyro: SensorNoise | None
    temp_range_degC: tuple[float, float] | None = None
    temp_segments: list[TempSegment] = field(default_factory=list)
    gaps: int = 0
    """Sample-index jumps (> 1) found; the stream is analysed as if contiguous."""
    notes: list[str] = field(default_factory=list)
    version: int = 1

    def sensors(self) -> list[SensorNoise]:
        return [s for s in (self.accel, self.gyro) if s is not None]

    def kalibr(self) -> dict[str, float]:
        """Kalibr's four IMU noise values (continuous time, worst axis): accelerometer_noise_density
        (m/s^2/sqrt(Hz)), accelerometer_random_walk (m/s^3/sqrt(Hz)), gyroscope_noise_density
        (rad/s/sqrt(Hz)), gyroscope_random_walk (rad/s^2/sqrt(Hz)). A random walk that the session does
        not resolve is given as its 2-sigma upper bound (value + 2 sigma)."""
        out: dict[str, float] = {}
        for s, pre in ((self.accel, "accelerometer"), (self.gyro, "gyroscope")):
            if s is None:
                continue
            out[f"{pre}_noise_density"] = s.worst("white").value
            rw = [a.random_walk for a in s.axes]
            out[f"{pre}_random_walk"] = max(p.value if p.detected else p.value + 2 * p.sigma for p in rw)
        return out

    def white_noise_floor(self) -> dict[str, list[float]]:
        """Per-axis white noise N (accel m/s^2/sqrt(Hz), gyro rad/s/sqrt(Hz)): the noise floor."""
        return {s.sensor: [a.white.value for a in s.axes] for s in self.sensors()}

    def to_dict(self, curves: bool = True) -> dict:
        d = {
            "version": self.version,
            "source": self.source,
            "duration_s": self.duration_s,
            "rate_hz": self.rate_hz,
            "n_samples": self.n_samples,
            "gaps": self.gaps,
            "temp_range_degC": self.temp_range_degC,
            "temp_segments": [t.to_dict() for t in self.temp_segments],
            "notes": self.notes,
            "kalibr": self.kalibr(),
        }
        for s in self.sensors():
            sd = s.to_dict()
            if not curves:
                for a in sd["axes"]:
                    a.pop("allan")
            d[s.sensor] = sd
        return d

    def to_json(self, indent: int | None = 1, curves: bool = True) -> str:
        import json

        return json.dumps(_finite(self.to_dict(curves)), indent=indent, allow_nan=False)


def _finite(x):
    """NaN/inf -> None, recursively (JSON has no NaN)."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    return x


# -- calibration-file section ----------------------------------------------------------------------------

_SECTION_UNITS = {
    "accel": {
        "white": "m/s^2/sqrt(Hz)",
        "bias_instability": "m/s^2",
        "random_walk": "m/s^3/sqrt(Hz)",
        "quantisation": "m/s",
    },
    "gyro": {
        "white": "rad/s/sqrt(Hz)",
        "bias_instability": "rad/s",
        "random_walk": "rad/s^2/sqrt(Hz)",
        "quantisation": "rad",
    },
}


def _term(p: Param) -> NoiseTerm:
    return NoiseTerm(value=p.value, sigma=p.sigma)


def calibration_section(m: NoiseModel) -> NoiseSection:
    """The 'noise' section of a calibration file: per sensor and axis each term as value and 1-sigma
    (SI units), plus the Kalibr values (what exporters read)."""
    sensors: dict[str, Any] = {  # NoiseSection's fields per sensor: accel, gyro
        s.sensor: SensorNoiseTerms(
            units=dict(_SECTION_UNITS[s.sensor]),
            axes={
                a.axis: AxisNoiseTerms(
                    white=_term(a.white),
                    bias_instability=_term(a.bias_instability),
                    random_walk=_term(a.random_walk),
                    quantisation=_term(a.quantisation),
                )
                for a in s.axes
            },
        )
        for s in m.sensors()
    }
    return NoiseSection(
        version=NOISE_SECTION_VERSION,
        source=m.source,
        duration_s=m.duration_s,
        rate_hz=m.rate_hz,
        convention="Allan/IEEE-952: ADEV(tau) = N / sqrt(tau); one-sided PSD density = sqrt(2) N",
        kalibr=m.kalibr(),
        kalibr_random_walk_is_bound=any(not a.random_walk.detected for s in m.sensors() for a in s.axes),
        **sensors,
    )


def white_floor_from_section(section: NoiseSection | None, sensor: str = "accel") -> np.ndarray | None:
    """(3,) white noise N per axis from a 'noise' section (m/s^2/sqrt(Hz) or rad/s/sqrt(Hz)), or None."""
    return None if section is None else section.white_noise(sensor)


def sem_with_noise_floor(section: NoiseSection, sem_mps2: np.ndarray, duration_s: float) -> np.ndarray:
    """The standard error of a T-second mean of the accelerometer (m/s^2, per axis), floored at the white
    noise of a calibration's 'noise' section: N / sqrt(T) (AVAR(T) = N^2 / T is the variance of that mean)."""
    n = white_floor_from_section(section, "accel")
    if n is None or not duration_s > 0:
        return sem_mps2
    return np.maximum(sem_mps2, n / math.sqrt(duration_s))


def floor_obs_sigma(obs, section: NoiseSection, rate_hz: float | None = None):
    """A copy of an ObsTable whose window sigma_g is at least the white noise of a 'noise' section:
    sigma_g >= N / g0 / sqrt(n_samples / rate_hz) (g), the standard error of a mean over the window's
    duration (`diagnose --noise-from`). rate_hz: the session's sample rate (default the section's)."""
    import dataclasses

    n = white_floor_from_section(section, "accel")
    rate = float(rate_hz or section.rate_hz or 0.0)
    if n is None or rate <= 0:
        return obs
    floor_g = n[None, :] / STANDARD_GRAVITY_MPS2 / np.sqrt(np.asarray(obs.n_samples, float)[:, None] / rate)
    return dataclasses.replace(obs, sigma_g=np.maximum(obs.sigma_g, floor_g))


def floor_noise(obs, helds, cal_path, rate_hz: float | None = None):
    """(obs, helds) with every window's sigma floored by the white noise (Allan) of the 'noise'
    section of the calibration file cal_path, at rate_hz (floor_obs_sigma; `diagnose --noise-from`);
    InputError (one line) when the file has no noise section."""
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.core.errors import InputError

    section = load_calibration(cal_path).noise
    if not section:
        raise InputError(
            "no noise section: add one with `accellog noise STILL.mcap --cal C -o C2`", where=str(cal_path)
        )
    return floor_obs_sigma(obs, section, rate_hz), [floor_obs_sigma(h, section, rate_hz) for h in helds]
