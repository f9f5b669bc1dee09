"""Displacement-drift model of a calibrated sensor at rest (the seed's 'bonus' second stage).

Per axis, the displacement integrated from calibrated static data is modelled as

    d'(t) = d(t) + 1/2 q2 t^2 + q1 t + q0        (m; t in s since session start)

with q2 a residual acceleration bias (m/s^2), q1 a velocity offset (m/s), q0 an offset (m), fitted by
least squares on d(t) of one static session and subtracted from the displacement of another.

Uncertainties: the displacement residuals are a double integral of noise, so they are strongly
correlated and ordinary least-squares errors are far too small. The covariance reported here is
propagated from white acceleration noise of variance sigma_a^2 per sample (inflated by its
autocorrelation time tau): Cov(d(s), d(t)) = sigma_a^2 tau dt (m^2 M / 2 - m^3 / 6), m = min(s,t),
M = max(s,t), evaluated on a decimated time grid. Bias instability and flicker are not included.

The fit runs on the session's blocks (a ``store.source.Source``: a file chunk by chunk, anything else
as one block in memory) in two passes (drift_blocks), memory independent of the session length.

LIMITS (stated in every output): a residual-bias model for a sensor at rest in the orientation it
was fitted in; it is not a calibration of the sensor and is invalid once the sensor moves or turns,
and it extrapolates poorly beyond the fitted duration.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.calfile.drift_model import DriftModel
from accellog.calibrate.model.session_drivers import needs_whole_series
from accellog.core.errors import InputError
from accellog.core.session import Session, vec3
from accellog.core.timeseries import sorted_unique
from accellog.navigate.blocks import checked_blocks
from accellog.navigate.evaluate import Target, evaluate_blocks
from accellog.navigate.evaluation import Evaluation, block_residual, drift_result, eval_context
from accellog.navigate.stream_sums import Integrator, ResidualSums
from accellog.store.source import Source, open_source


def _design(t: np.ndarray) -> np.ndarray:
    return np.c_[np.ones_like(t), t, 0.5 * t**2]


def grid_index(n: int, n_grid: int = 400) -> np.ndarray:
    """Indices of the <= n_grid samples (of n) the covariance is evaluated on."""
    return sorted_unique(np.linspace(0, n - 1, min(n_grid, n)).astype(np.int64))


def noise_cov_q(t: np.ndarray, accel_noise_var: np.ndarray, n_grid: int | None = 400) -> np.ndarray:
    """(3,3,3) covariance of the OLS q per axis under white acceleration noise (see module doc);
    n_grid None: t is already the grid (the sample times at grid_index)."""
    tg_abs = t if n_grid is None else t[grid_index(t.size, n_grid)]
    tg = tg_abs - tg_abs[0]
    A = _design(tg_abs)
    m = np.minimum.outer(tg, tg)
    M = np.maximum.outer(tg, tg)
    K = m**2 * M / 2.0 - m**3 / 6.0  # s^3: Cov of a double integral of unit white noise density
    P = np.linalg.pinv(A)  # (3, g): OLS operator on the grid
    base = P @ K @ P.T
    return accel_noise_var[:, None, None] * base[None, :, :]


class DriftSums:
    """Normal equations of d(t) = q0 + q1 t + 1/2 q2 t^2 (per axis) fed block by block.

    With u = t - t0 (t0: the first sample) the sums S_k = sum u^k (k = 0..4) and B_k = sum u^k d
    (k = 0..2) accumulate; at the end the time is scaled, s = u / T (T = t_last - t0), so the 3x3
    Gram matrix S_{j+k} / T^{j+k} is well conditioned, c solves it on the basis (1, s, s^2), and c is
    mapped back to (q0, q1, q2) on the absolute t."""

    def __init__(self) -> None:
        self.t0: float | None = None
        self.t_last = np.nan
        self.s = np.zeros(5)
        self.b = np.zeros((3, 3))

    @staticmethod
    def design(t: np.ndarray) -> np.ndarray:
        """(n,3) columns 1, t, t^2/2 (the model's design on absolute t)."""
        return _design(np.asarray(t, float))

    def add(self, t: np.ndarray, d: np.ndarray) -> None:
        if t.shape[0] == 0:
            return
        if self.t0 is None:
            self.t0 = float(t[0])
        s, b = _moments(t - self.t0, d)
        self.s += s
        self.b += b
        self.t_last = float(t[-1])

    def solve(self) -> np.ndarray:
        """(3 params q0 m, q1 m/s, q2 m/s^2; 3 axes), as np.linalg.lstsq(design(t), d) to ~1e-8
        relative on the smallest coefficient (DriftRefine takes it to lstsq's accuracy)."""
        t0 = self.first_s()
        T = self.t_last - t0
        k = np.arange(3)
        G = self.s[k[:, None] + k[None, :]] / T ** (k[:, None] + k[None, :])
        return _to_q(np.linalg.solve(G, self.b / T ** k[:, None]), t0, T)

    def first_s(self) -> float:
        """The first sample's time (s); ValueError before any sample."""
        if self.t0 is None:
            raise ValueError("no samples to fit a drift polynomial to")
        return self.t0


def _moments(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sum x^k for k = 0..4, (3, m) sum x^k y for k = 0..2) by products (a float power is 10x slower)."""
    x2 = x * x
    s = np.array([x.size, x.sum(), x2.sum(), (x2 * x).sum(), (x2 * x2).sum()], float)
    return s, np.stack([y.sum(axis=0), x @ y, x2 @ y])


def _to_q(c: np.ndarray, t0: float, h: float) -> np.ndarray:
    """c0 + c1 s + c2 s^2 with s = (t - t0) / h as (q0, q1, q2) of q0 + q1 t + 1/2 q2 t^2."""
    a1, a2 = c[1] / h, c[2] / h**2  # c0 + a1 u + a2 u^2, u = t - t0
    return np.array([c[0] - a1 * t0 + a2 * t0 * t0, a1 - 2.0 * a2 * t0, 2.0 * a2])


class DriftRefine:
    """Second pass of the fit: one step of iterative refinement, and the residual RMS.

    The residual e = d - A q of DriftSums' q is fitted again on the centred, scaled basis
    (1, s, s^2), s = (t - c) / h (c, h: mid-point and half-span of the fitted times; Gram condition
    ~20 instead of ~500 on [0, 1]), so q + delta has the accuracy of a QR least squares; the RMS of
    e - A delta follows from sum e^2, A'e and the Gram matrix (delta is tiny: no cancellation)."""

    def __init__(self, q: np.ndarray, t_first: float, t_last: float) -> None:
        self.q = np.asarray(q, float)
        self.c, self.h = 0.5 * (t_first + t_last), max(0.5 * (t_last - t_first), 1e-300)
        self.n = 0
        self.s = np.zeros(5)
        self.b = np.zeros((3, 3))
        self.ee = np.zeros(3)

    def add(self, t: np.ndarray, d: np.ndarray) -> None:
        e = d - _design(t) @ self.q
        s, b = _moments((t - self.c) / self.h, e)
        self.s += s
        self.b += b
        self.ee += (e * e).sum(axis=0)
        self.n += t.shape[0]

    def solve(self) -> tuple[np.ndarray, np.ndarray]:
        """(q + delta (3 params, 3 axes), rms of the final residual per axis (3,) m)."""
        k = np.arange(3)
        G = self.s[k[:, None] + k[None, :]]
        delta = np.linalg.solve(G, self.b)
        sq = self.ee - 2.0 * np.sum(delta * self.b, axis=0) + np.einsum("ia,ij,ja->a", delta, G, delta)
        return self.q + _to_q(delta, self.c, self.h), np.sqrt(np.maximum(sq, 0.0) / self.n)


class IntervalCount:
    """Every distinct sample interval dt = t_{i+1} - t_i (float, s) with its count, fed block by block;
    median() equals np.median(np.diff(t)) exactly (the same multiset)."""

    def __init__(self) -> None:
        self.last: float | None = None
        self.values = np.zeros(0)
        self.counts = np.zeros(0, dtype=np.int64)

    def add(self, t: np.ndarray) -> None:
        if t.shape[0] == 0:
            return
        dt = np.diff(t if self.last is None else np.concatenate([[self.last], t]))
        self.last = float(t[-1])
        v, c = np.unique(dt, return_counts=True)
        allv, inv = np.unique(np.concatenate([self.values, v]), return_inverse=True)
        self.counts = np.bincount(inv, np.concatenate([self.counts, c]), minlength=allv.size).astype(np.int64)
        self.values = allv

    def median(self) -> float:
        """Median interval (s): the middle value, or the mean of the two middle ones."""
        m = int(self.counts.sum())
        if m == 0:
            return float("nan")
        cum = np.cumsum(self.counts)
        lo = self.values[np.searchsorted(cum, (m - 1) // 2, side="right")]
        hi = self.values[np.searchsorted(cum, m // 2, side="right")]
        return float(np.mean([lo, hi]))


class DriftFit:
    """The fit of q on d(t) fed in two passes of consecutive blocks (module doc of drift_blocks):
    pass 1 DriftSums and the sample intervals, pass 2 DriftRefine and the covariance grid's times."""

    def __init__(self) -> None:
        self.sums = DriftSums()
        self.dt = IntervalCount()
        self.refine: DriftRefine | None = None
        self.grid = np.zeros(0, dtype=int)
        self.n2 = 0
        self.grid_t: list[np.ndarray] = []

    def add(self, t: np.ndarray, d: np.ndarray) -> None:
        """Pass 1."""
        self.sums.add(t, d)
        self.dt.add(t)

    def second_pass(self, n: int) -> None:
        """After pass 1 over n samples: the refinement starts from pass 1's q."""
        self.refine = DriftRefine(self.sums.solve(), self.sums.first_s(), self.sums.t_last)
        self.grid = grid_index(n)

    def add_again(self, t: np.ndarray, d: np.ndarray) -> None:
        """Pass 2 (the same blocks, after second_pass)."""
        self._refined().add(t, d)
        g = self.grid
        self.grid_t.append(t[g[(g >= self.n2) & (g < self.n2 + t.size)] - self.n2])
        self.n2 += t.size

    def _refined(self) -> DriftRefine:
        if self.refine is None:
            raise RuntimeError("pass 2 before second_pass()")
        return self.refine

    def model(
        self, var_mps2: np.ndarray | None, tau: np.ndarray | None, up_sensor, source: str
    ) -> DriftModel:
        """The DriftModel after both passes; var_mps2 (3,) (m/s^2)^2 and tau (3,) samples of the
        residual acceleration (None: sigma NaN, no honest estimate)."""
        q, rms = self._refined().solve()
        if var_mps2 is None:
            cov = np.full((3, 3, 3), np.nan)
        else:
            var_density = var_mps2 * tau * self.dt.median()  # (m/s^2)^2 s
            cov = noise_cov_q(np.concatenate(self.grid_t), var_density, n_grid=None)
        return DriftModel(
            q=q.T.copy(),
            cov=cov,
            fit_duration_s=float(self.sums.t_last - self.sums.first_s()),
            up_sensor=None if up_sensor is None else vec3(up_sensor),
            source=source,
            rms_residual_m=rms,
        )


def fit_drift(
    t_s: np.ndarray,
    disp_m: np.ndarray,
    *,
    accel_resid_mps2: np.ndarray | None = None,
    up_sensor: tuple[float, float, float] | None = None,
    source: str = "",
) -> DriftModel:
    """Least-squares q per axis on d(t) = q0 + q1 t + 1/2 q2 t^2 (t_s s, disp_m (n,3) m): DriftFit
    fed with one block.

    accel_resid_mps2: the gravity-removed calibrated acceleration (n,3) the displacement came from;
    its variance and autocorrelation time give the uncertainty (white-noise propagation). Without
    it, sigma is NaN (no honest estimate).
    """
    t = np.asarray(t_s, float)
    d = np.asarray(disp_m, float)
    if t.ndim != 1 or t.size < 10 or d.shape != (t.size, 3):
        raise InputError(f"drift fit needs >= 10 samples of (n,3) displacement, got t {t.shape}, d {d.shape}")
    if not (np.isfinite(t).all() and np.isfinite(d).all()):
        raise InputError("drift fit: displacement or time contains NaN")
    fit = DriftFit()
    fit.add(t, d)
    fit.second_pass(t.size)
    fit.add_again(t, d)
    var = tau = None
    if accel_resid_mps2 is not None:
        acc = ResidualSums((), 2.0)
        acc.add(t, np.asarray(accel_resid_mps2, float))
        st = acc.finish()
        var, tau = st["std"] ** 2, st["tau"]
    return fit.model(var, tau, up_sensor, source)


def drift_blocks(
    src: Source,
    cal: Calibration,
    *,
    up_sensor: Sequence[float] | None = None,
    until_s: float | None = None,
    max_samples: int | None = None,
) -> tuple[Calibration, DriftModel, Evaluation]:
    """(cal + drift, drift, evaluation of cal + drift on the session) in two passes over the
    session's blocks (one Source.run: a damaged file read whole runs both again; a model reading
    dT/dt: the whole session in memory).

    1. evaluate_blocks of the calibration without its drift model (the checks, the file's
       time-stamp check, the orientation): its displacement d(t) into DriftFit (normal equations of
       d = q0 + q1 t + 1/2 q2 t^2 on a scaled time, the sample intervals' exact median) and the
       residual's std and autocorrelation time;
    2. the same d again (stream_sums.Integrator) into DriftFit (one step of iterative refinement on a
       centred basis: q to least-squares accuracy, the residual RMS; the decimated covariance grid).

    The evaluation of cal + drift is pass 1's: the residual does not depend on the drift model, and
    the drifted displacement at the reported times is the model applied to the two samples around
    each (Integrator.series_at), the interpolation an evaluation of cal + drift makes.

    The median interval is exact: IntervalCount keeps every distinct float dt with its count; its
    memory is the number of distinct intervals, which the clock bounds (integer nanosecond stamps),
    not the number of samples."""
    opts = dict(up_sensor=up_sensor, until_s=until_s, max_samples=max_samples)
    return src.run(lambda s: _drift(s, cal, **opts), whole=needs_whole_series(cal.model.required_drivers))


def _drift(src: Source, cal: Calibration, *, up_sensor, until_s, max_samples):
    """drift_blocks' two passes."""
    cal0 = dataclasses.replace(cal, drift=None)  # pass 1 evaluates the calibration alone
    fit = DriftFit()
    sums: list = []
    evs = evaluate_blocks(src, [Target(cal0)], up_sensor=up_sensor, until_s=until_s, max_samples=max_samples,
                          on_block=lambda _k, t, _v, d: fit.add(t, d), sums_out=sums)  # fmt: skip
    ev, (acc, st) = evs[0], sums[0]
    up = ev.up_sensor  # inferred in pass 1 when not given (its note is in ev.notes)
    ctx = eval_context(src.where, src.meta, cal, up, [], apply_drift=False)
    integ = Integrator(())
    fit.second_pass(st["n"])
    for b, block in checked_blocks(src, until_s, max_samples):
        _v, d, _ = integ.add(b.t_s, block_residual(ctx, block))
        fit.add_again(b.t_s, d)
    dm = fit.model(st["std"] ** 2, st["tau"], up, src.where)
    at, end = acc.integ.series_at(dm.apply)
    t_s, disp_m = ev.t_s, ev.disp_series_m  # the series kept for plots, if any
    series = {} if t_s is None or disp_m is None else {"dd": dm.apply(t_s, disp_m)}
    drift_result(ev, dm, {"disp_drift_at": at, "disp_drift_end": end}, series)
    return dataclasses.replace(cal, drift=dm, path=None), dm, ev


def drift_from_session(
    session: Session,
    cal: Calibration,
    *,
    up_sensor: tuple[float, float, float] | None = None,
    until_s: float | None = None,
    max_samples: int | None = None,
) -> tuple[Calibration, DriftModel]:
    """Fit the drift model on a static session in memory calibrated with `cal`; returns (cal + drift,
    drift): drift_blocks on the session as one block."""
    cal_d, dm, _ev = drift_blocks(
        open_source(session), cal, up_sensor=up_sensor, until_s=until_s, max_samples=max_samples
    )
    return cal_d, dm
