"""AK8963 magnetometer calibration: hard iron h and soft iron A from a session that rotates the sensor.

Measurement model (AK8963 axes, uT): m = W b + h + n, b the local field in the sensor frame (|b| = F for
every orientation), W the soft-iron distortion, h the hard-iron offset. The calibration

    b_hat = A (m - h),    |b_hat| = F for every sample,

is an ellipsoid fit: (m - h)^T M (m - h) = 1 with M = A^T A / F^2. Forms (as MATLAB ``magcal``): 'eye'
(A = I: a sphere, 4 parameters), 'diag' (A diagonal: axis-aligned ellipsoid, 6), 'sym' (A symmetric: any
ellipsoid, 9). A is normalised to det(A) = 1 (volume preserving), so F = det(M)^(-1/6) is the field
strength the data show; an overall sensitivity error of the sensor is indistinguishable from a different
field, which is why F is compared with the expected local field.

Fit: algebraic least squares for the start, then Levenberg-Marquardt (core.numeric.least_squares: scipy's;
not converged is a ModelError) on the geometric
residual r_k = F (sqrt((m_k - h)^T M (m_k - h)) - 1) (uT); covariance s^2 (J^T J)^-1 with s^2 the residual
variance, propagated to h, A and F by the delta method. The residual is compared with the noise from second
differences (1.4826 MAD(d2) / sqrt(6)), and regressed on each driver x (time, die temperature, rotation
rate, a motor current ...) as r = c0 + s x + (u . d) x: s, a field strength changing with x, and d, a hard
iron moving with x (u the unit corrected field), flagged when their chi2 (4 dof) exceeds TREND_CHI2_FLAG.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from accellog.core.errors import InputError, ModelError
from accellog.core.numeric import least_squares

FORMS = ("eye", "diag", "sym")
MAG_SECTION_VERSION = 1
TREND_CHI2_FLAG = 30.0
"""chi2 (4 dof) of a driver's terms above which the residual is said to depend on it (p ~ 5e-6)."""


@dataclass
class DriverTrend:
    """What the residual does with one driver x (centred): r = c0 + s x + (u . d) x, u = b_hat / |b_hat|.

    s (uT per unit): the field strength changes with x; d (3, uT per unit, corrected axes): the hard iron
    moves with x (e.g. a motor current). chi2 of (s, d) against 0 with their covariance (4 dof)."""

    driver: str
    unit: str
    slope: float
    slope_sigma: float
    shift: np.ndarray
    shift_sigma: np.ndarray
    chi2: float
    flagged: bool

    def to_dict(self) -> dict:
        return {
            "driver": self.driver,
            "unit": self.unit,
            "slope": self.slope,
            "slope_sigma": self.slope_sigma,
            "shift": self.shift.tolist(),
            "shift_sigma": self.shift_sigma.tolist(),
            "chi2": self.chi2,
            "flagged": self.flagged,
        }

    @classmethod
    def from_dict(cls, d: dict) -> DriverTrend:
        """Inverse of to_dict (null -> NaN)."""

        def num(v: float | None) -> float:
            return math.nan if v is None else float(v)

        return cls(
            driver=str(d["driver"]),
            unit=str(d.get("unit", "")),
            slope=num(d.get("slope")),
            slope_sigma=num(d.get("slope_sigma")),
            shift=np.array([num(v) for v in d.get("shift") or [None] * 3]),
            shift_sigma=np.array([num(v) for v in d.get("shift_sigma") or [None] * 3]),
            chi2=num(d.get("chi2")),
            flagged=bool(d.get("flagged", False)),
        )


@dataclass
class MagCalibration:
    """Fitted hard and soft iron (AK8963 axes) with 1-sigma, field strength, residual vs noise, diagnosis."""

    form: str
    hard_iron_uT: np.ndarray
    hard_iron_sigma_uT: np.ndarray
    soft_iron: np.ndarray
    soft_iron_sigma: np.ndarray
    field_uT: float
    field_sigma_uT: float
    residual_rms_uT: float
    noise_uT: float
    n_samples: int
    expected_field_uT: float | None = None
    trends: list[DriverTrend] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    version: int = MAG_SECTION_VERSION

    def correct(self, mag_uT: np.ndarray) -> np.ndarray:
        """b_hat = A (m - h) (n,3, uT, AK8963 axes)."""
        return (np.asarray(mag_uT, float) - self.hard_iron_uT) @ self.soft_iron.T

    def to_dict(self) -> dict:
        return {
            "version": self.version,
            "axes": "AK8963 (x_m = y_s, y_m = x_s, z_m = -z_s)",
            "equation": "b = A (m - h), det(A) = 1, |b| = field_uT",
            "form": self.form,
            "hard_iron_uT": self.hard_iron_uT.tolist(),
            "hard_iron_sigma_uT": self.hard_iron_sigma_uT.tolist(),
            "soft_iron": self.soft_iron.tolist(),
            "soft_iron_sigma": self.soft_iron_sigma.tolist(),
            "field_uT": self.field_uT,
            "field_sigma_uT": self.field_sigma_uT,
            "expected_field_uT": self.expected_field_uT,
            "residual_rms_uT": self.residual_rms_uT,
            "noise_uT": self.noise_uT,
            "n_samples": self.n_samples,
            "trends": [t.to_dict() for t in self.trends],
            "notes": list(self.notes),
        }

    def to_json(self, indent: int | None = 1) -> str:
        """Strict JSON (NaN -> null)."""
        from accellog.core.jsonio import dumps

        return dumps(self.to_dict(), indent=indent)

    @classmethod
    def from_dict(cls, d: dict, where: str | None = None) -> MagCalibration:
        d = check_section(d, where)
        return cls(
            form=str(d["form"]),
            hard_iron_uT=np.asarray(d["hard_iron_uT"], float),
            hard_iron_sigma_uT=np.asarray(d.get("hard_iron_sigma_uT", [np.nan] * 3), float),
            soft_iron=np.asarray(d["soft_iron"], float),
            soft_iron_sigma=np.asarray(d.get("soft_iron_sigma", np.full((3, 3), np.nan)), float),
            field_uT=float(d["field_uT"]),
            field_sigma_uT=float(d.get("field_sigma_uT") or math.nan),
            residual_rms_uT=float(d.get("residual_rms_uT") or math.nan),
            noise_uT=float(d.get("noise_uT") or math.nan),
            n_samples=int(d.get("n_samples", 0)),
            expected_field_uT=d.get("expected_field_uT"),
            trends=_trends(d.get("trends"), where),
            notes=list(d.get("notes", [])),
            version=int(d["version"]),
        )


def _trends(v, where: str | None) -> list[DriverTrend]:
    """The stored residual trends (none in files of older versions); InputError when malformed."""
    try:
        return [DriverTrend.from_dict(t) for t in v or []]
    except (KeyError, TypeError, ValueError, AttributeError):
        raise InputError("calibration 'magnetometer' has a malformed trends entry", where=where) from None


def check_section(d, where: str | None = None) -> dict:
    """Validate a 'magnetometer' section of a calibration file (one-line InputError)."""
    if not isinstance(d, dict) or not isinstance(d.get("version"), int):
        raise InputError("calibration 'magnetometer' section has no integer version", where=where)
    if d["version"] > MAG_SECTION_VERSION:
        raise InputError(
            f"calibration 'magnetometer' section version {d['version']} is newer than this accellog",
            where=where,
        )
    try:
        h = np.asarray(d["hard_iron_uT"], float)
        A = np.asarray(d["soft_iron"], float)
        float(d["field_uT"])
    except (KeyError, TypeError, ValueError):
        raise InputError(
            "calibration 'magnetometer' lacks hard_iron_uT, soft_iron or field_uT", where=where
        ) from None
    if h.shape != (3,) or A.shape != (3, 3) or not (np.isfinite(h).all() and np.isfinite(A).all()):
        raise InputError(
            "calibration 'magnetometer': hard_iron_uT must be 3 and soft_iron 3x3 finite numbers", where=where
        )
    return d


# -- fit ------------------------------------------------------------------------------------------------


def _M(form: str, q: np.ndarray) -> np.ndarray:
    if form == "eye":
        return np.eye(3) * q[0]
    if form == "diag":
        return np.diag(q)
    a, b, c, d, e, f = q
    return np.array([[a, d, e], [d, b, f], [e, f, c]])


def _algebraic(m: np.ndarray, form: str) -> np.ndarray:
    """Start values p = (h, q) from linear least squares of the quadric through the points."""
    x, y, z = m.T
    if form == "eye":  # |m|^2 = 2 h.m + (R^2 - |h|^2)
        D = np.column_stack([2 * x, 2 * y, 2 * z, np.ones_like(x)])
        sol = np.linalg.lstsq(D, x * x + y * y + z * z, rcond=None)[0]
        h = sol[:3]
        r2 = sol[3] + h @ h
        return np.concatenate([h, [1.0 / r2]])
    quad = [x * x, y * y, z * z] + ([] if form == "diag" else [2 * x * y, 2 * x * z, 2 * y * z])
    D = np.column_stack([*quad, 2 * x, 2 * y, 2 * z])
    v = np.linalg.lstsq(D, np.ones_like(x), rcond=None)[0]
    nq = len(quad)
    M0 = _M(form, v[:nq])
    h = -np.linalg.solve(M0, v[nq:])
    k = 1.0 + h @ M0 @ h
    return np.concatenate([h, v[:nq] / k])


def _derived(form: str, p: np.ndarray) -> np.ndarray:
    """(h (3), A (9), F) from p = (h, q): F = det(M)^(-1/6), A = F sqrtm(M) (det A = 1)."""
    M = _M(form, p[3:])
    w, V = np.linalg.eigh(M)
    if np.any(w <= 0):
        raise ModelError(
            "the magnetometer samples do not lie on an ellipsoid (rotate the sensor in all directions)"
        )
    F = float(np.prod(w) ** (-1.0 / 6.0))
    A = F * (V * np.sqrt(w)) @ V.T
    return np.concatenate([p[:3], A.ravel(), [F]])


def noise_from_second_differences(m: np.ndarray) -> float:
    """Per-sample noise (uT) of slowly varying readings: 1.4826 MAD(second differences) / sqrt(6), median axis."""
    if m.shape[0] < 5:
        return math.nan
    d2 = np.diff(m, 2, axis=0)
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return float(np.median(1.4826 * mad / math.sqrt(6.0)))


def fit_magnetometer(
    mag_uT: np.ndarray,
    form: str = "sym",
    *,
    expected_field_uT: float | None = None,
    drivers: dict[str, tuple[np.ndarray, str]] | None = None,
) -> MagCalibration:
    """Ellipsoid fit of the readings (n,3, uT); drivers: {name: (values (n,), unit)} for the diagnosis."""
    if form not in FORMS:
        raise InputError(f"magnetometer fit form {form!r}: use one of {', '.join(FORMS)}")
    m = np.asarray(mag_uT, float)
    m = m[np.isfinite(m).all(axis=1)]
    npar = 3 + {"eye": 1, "diag": 3, "sym": 6}[form]
    if m.shape[0] < 3 * npar:
        raise InputError(f"{m.shape[0]} magnetometer samples: need >= {3 * npar} for the '{form}' fit")
    spread = np.linalg.svd(m - m.mean(axis=0), compute_uv=False)
    if spread[-1] < 0.05 * spread[0]:
        raise ModelError(
            "the magnetometer samples span a plane or a line: rotate the sensor about all three axes"
        )
    p0 = _algebraic(m, form)

    def resid(p: np.ndarray) -> np.ndarray:
        d = m - p[:3]
        M = _M(form, p[3:])
        val = np.einsum("ij,jk,ik->i", d, M, d)
        return np.sqrt(np.maximum(val, 0.0)) - 1.0

    sol = least_squares(resid, p0, what=f"magnetometer '{form}' ellipsoid fit", x_scale="jac")
    p = sol.x
    F = _derived(form, p)[-1]
    r = sol.fun * F  # uT
    dof = max(m.shape[0] - npar, 1)
    s2 = float(r @ r / dof) / F**2
    try:
        cov_p = np.linalg.inv(sol.jac.T @ sol.jac) * s2
    except np.linalg.LinAlgError as exc:
        raise ModelError(
            f"magnetometer fit is singular ({exc}): rotate the sensor through more orientations"
        ) from None
    G = _jacobian(lambda q: _derived(form, q), p)
    cov = G @ cov_p @ G.T
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    out = _derived(form, p)
    noise = noise_from_second_differences(m)
    cal = MagCalibration(
        form=form,
        hard_iron_uT=out[:3],
        hard_iron_sigma_uT=sig[:3],
        soft_iron=out[3:12].reshape(3, 3),
        soft_iron_sigma=sig[3:12].reshape(3, 3),
        field_uT=float(out[12]),
        field_sigma_uT=float(sig[12]),
        residual_rms_uT=float(np.sqrt(np.mean(r * r))),
        noise_uT=noise,
        n_samples=int(m.shape[0]),
        expected_field_uT=expected_field_uT,
    )
    cal.trends = residual_trends(r, cal.correct(m), drivers or {})
    cal.notes = _notes(cal)
    return cal


def _jacobian(f, p: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian of f at p."""
    f0 = f(p)
    J = np.empty((f0.size, p.size))
    for i in range(p.size):
        h = 1e-6 * max(abs(p[i]), 1e-12)
        e = np.zeros_like(p)
        e[i] = h
        J[:, i] = (f(p + e) - f(p - e)) / (2 * h)
    return J


def residual_trends(
    r_uT: np.ndarray, b_hat: np.ndarray, drivers: dict[str, tuple[np.ndarray, str]]
) -> list[DriverTrend]:
    """Per driver x: least squares r = c0 + s x + (u . d) x (u the unit corrected field), sigma from the scatter."""
    u = b_hat / np.linalg.norm(b_hat, axis=1, keepdims=True)
    out = []
    for name, (x, unit) in drivers.items():
        x = np.asarray(x, float)
        ok = np.isfinite(x) & np.isfinite(r_uT)
        if ok.sum() < 20 or np.ptp(x[ok]) == 0:
            continue
        xc = x[ok] - x[ok].mean()
        X = np.column_stack([np.ones(ok.sum()), xc, xc[:, None] * u[ok]])
        coef, *_ = np.linalg.lstsq(X, r_uT[ok], rcond=None)
        e = r_uT[ok] - X @ coef
        s2 = e @ e / max(ok.sum() - X.shape[1], 1)
        cov = np.linalg.pinv(X.T @ X) * s2
        t = coef[1:]
        chi2 = float(t @ np.linalg.pinv(cov[1:, 1:]) @ t)
        sig = np.sqrt(np.diag(cov))
        out.append(
            DriverTrend(
                name,
                f"uT per {unit}",
                float(t[0]),
                float(sig[1]),
                t[1:],
                sig[2:],
                chi2,
                bool(chi2 > TREND_CHI2_FLAG),
            )
        )
    return out


def _notes(c: MagCalibration) -> list[str]:
    notes = []
    if c.expected_field_uT:
        dev = c.field_uT - c.expected_field_uT
        notes.append(
            f"field {c.field_uT:.2f} ± {c.field_sigma_uT:.2f} uT vs expected {c.expected_field_uT:.2f} uT "
            f"({100 * dev / c.expected_field_uT:+.1f} %): a difference is an overall sensitivity error or local disturbance"
        )
    elif not 20.0 <= c.field_uT <= 70.0:
        notes.append(
            f"field {c.field_uT:.1f} uT is outside the Earth's 20-70 uT: magnetic disturbance nearby?"
        )
    if c.noise_uT == c.noise_uT and c.residual_rms_uT > 2.0 * c.noise_uT:
        notes.append(
            f"residual {c.residual_rms_uT:.2f} uT is {c.residual_rms_uT / c.noise_uT:.1f}x the noise "
            f"{c.noise_uT:.2f} uT: the '{c.form}' model misses something"
            + ("" if c.form == "sym" else " (try --form sym)")
        )
    for t in c.trends:
        if t.flagged:
            shift = ", ".join(f"{v:+.3g}" for v in t.shift)
            notes.append(
                f"residual changes with {t.driver} (chi2 {t.chi2:.0f}): field strength {t.slope:+.3g} ± "
                f"{t.slope_sigma:.2g} {t.unit}, hard iron ({shift}) {t.unit}"
            )
    return notes
