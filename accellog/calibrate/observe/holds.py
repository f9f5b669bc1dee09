"""One labelled hold: its checks, its observation rows and its statistics (accelerations in g).

The stage 'segment' (``stream_segment.segment_blocks``) hands every trimmed hold's samples here:
``check_hold`` (unit up vector, enough samples, finite readings), ``units_error`` (|mean| near
1 g), ``hold_rows`` (the windows of about window_s: one observation each) and ``hold_stats``
(``PoseStats``). A window's observation is

    meas_g = window mean (g),   sigma_g = std_window * sqrt(tau_hold / n_window)   (g)

where tau_hold is the hold's integrated autocorrelation time (samples, ``hold_noise``), floored
at the quantum / sqrt(12 n). Several windows per hold keep slow effects (temperature, warm-up,
time drift) visible to the fit.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.observe.hold_noise import integrated_autocorr_time, sem_autocorr
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel, Session, SessionMeta

UNIT_NORM_RANGE_G = (0.5, 2.0)
"""A reading at rest must have |a| in this range (g); outside it the units are wrong."""
MIN_WINDOW_SAMPLES = 10
"""A window must hold this many samples (its mean and std mean nothing with fewer)."""


@dataclass
class PoseStats:
    """Statistics of one labelled hold after trimming (accelerations in g)."""

    name: str
    hold_index: int
    up_sensor: np.ndarray  # (3,) nominal up vector
    start_s: float  # first used sample time (s)
    end_s: float  # last used sample time (s)
    n: int  # samples used
    mean_g: np.ndarray  # (3,)
    std_g: np.ndarray  # (3,) sample standard deviation
    sem_g: np.ndarray  # (3,) autocorrelation-aware standard error of the mean
    tau_samples: np.ndarray  # (3,) integrated autocorrelation time
    temp_degC: float | None = None  # mean die temperature
    dtemp_degC_per_s: float | None = None  # temperature slope over the hold

    @property
    def n_eff(self) -> np.ndarray:
        """Effective sample size n / tau per axis."""
        return self.n / self.tau_samples

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "hold_index": self.hold_index,
            "up_sensor": self.up_sensor.tolist(),
            "start_s": self.start_s,
            "end_s": self.end_s,
            "n": self.n,
            "mean_g": self.mean_g.tolist(),
            "std_g": self.std_g.tolist(),
            "sem_g": self.sem_g.tolist(),
            "tau_samples": self.tau_samples.tolist(),
            "n_eff": self.n_eff.tolist(),
            "temp_degC": self.temp_degC,
            "dtemp_degC_per_s": self.dtemp_degC_per_s,
        }


def session_where(session: Session) -> str:
    return session.path or f"session ({session.meta.source})"


def quantum_g(session: Session) -> float:
    return meta_quantum_g(session.meta)


def meta_quantum_g(meta: SessionMeta) -> float:
    """One LSB (g) of the session's accelerometer; 0 when unknown."""
    lsb = meta.accel_lsb_per_g
    return 1.0 / lsb if lsb else 0.0


def check_window(window_s: float, rate_hz: float, where: str | None = None) -> None:
    """InputError unless window_s (s) holds >= MIN_WINDOW_SAMPLES samples at rate_hz (Hz; 0 or
    unknown: the chip's highest rate, 4 kHz)."""
    rate = rate_hz if np.isfinite(rate_hz) and rate_hz > 0 else 4000.0
    if not window_s * rate >= MIN_WINDOW_SAMPLES:
        raise InputError(
            f"window_s = {window_s:g} s holds {window_s * rate:.3g} samples at {rate:g} Hz; a window "
            f"needs >= {MIN_WINDOW_SAMPLES} (--window-s >= {MIN_WINDOW_SAMPLES / rate:g} s)",
            where=where,
        )


def checked_labels(poses: Sequence[PoseLabel], where: str, events: Sequence = ()) -> list[PoseLabel]:
    """The labels in time order after the label-level checks (none, twice, empty, overlapping);
    events: the session's (a 'recovered' one says that missing labels went with a truncated end)."""
    if not poses:
        cut = next((f"the file is truncated: they went with its end ({e.detail})" for e in events
                    if e.kind == "recovered"), "record it with a pose protocol")  # fmt: skip
        raise InputError(
            f"session has no pose labels: {cut}; or use the orientation-free fit (static intervals are then "
            "detected automatically)",
            where=where,
        )
    labels = sorted(poses, key=lambda p: p.start_s)
    seen: dict[tuple[str, int], PoseLabel] = {}
    for p in labels:
        key = (p.name, p.hold_index)
        if key in seen:
            q = seen[key]
            raise InputError(
                f"pose {p.name!r} (hold {p.hold_index}) is labelled twice: {q.start_s:.2f}-{q.end_s:.2f} s "
                f"and {p.start_s:.2f}-{p.end_s:.2f} s",
                where=where,
            )
        seen[key] = p
        if not p.end_s > p.start_s:
            raise InputError(f"pose {p.name!r} has end {p.end_s} s <= start {p.start_s} s", where=where)
    for a, b in itertools.pairwise(labels):
        if b.start_s < a.end_s - 1e-9:
            raise InputError(
                f"poses {a.name!r} ({a.start_s:.2f}-{a.end_s:.2f} s) and {b.name!r} "
                f"({b.start_s:.2f}-{b.end_s:.2f} s) overlap",
                where=where,
            )
    return labels


def check_hold(
    p: PoseLabel, t: np.ndarray, acc: np.ndarray, trim_s: float, min_samples: int, where: str
) -> None:
    """InputError for a hold whose label's up vector is not a unit 3-vector, that has fewer than
    min_samples samples t (s), acc (g) after trimming trim_s (s), or a non-finite reading."""
    up = np.asarray(p.up_sensor, float)
    if up.shape != (3,) or not np.isfinite(up).all() or abs(np.linalg.norm(up) - 1.0) > 1e-3:
        raise InputError(f"pose {p.name!r}: up vector {p.up_sensor} is not a unit 3-vector", where=where)
    n = t.shape[0]
    if n < min_samples:
        raise InputError(
            f"pose {p.name!r} ({p.start_s:.2f}-{p.end_s:.2f} s) has {n} samples after trimming "
            f"{trim_s} s at each end (need >= {min_samples}): hold longer or lower --trim",
            where=where,
        )
    if not np.isfinite(acc).all():  # one flat pass; the rows only when one is bad
        bad = ~np.isfinite(acc).all(axis=1)
        i = int(np.argmax(bad))
        raise InputError(
            f"pose {p.name!r}: accel is NaN/inf at t = {t[i]:.3f} s ({int(bad.sum())} bad samples)",
            where=where,
        )


def units_error(p: PoseLabel, mean: np.ndarray, where: str) -> InputError | None:
    """The refusal of a hold whose mean reading (g) is far from 1 g (wrong units), else None."""
    lo, hi = UNIT_NORM_RANGE_G
    norm = float(np.linalg.norm(mean))
    if lo <= norm <= hi:
        return None
    hint = " (are raw counts declared as g? check accel_lsb_per_g)" if norm > hi else ""
    return InputError(
        f"pose {p.name!r}: |accel| at rest is {norm:.4g} g, expected about 1 g{hint}", where=where
    )


def window_stats(x: np.ndarray, starts: np.ndarray, ref=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, std (ddof=1), n) of x (n,k) over windows at indices `starts` (sorted); ref: x's mean, if known."""
    ref = x.mean(axis=0) if ref is None else ref
    return centred_window_stats(x - ref, starts, ref)


def centred_window_stats(
    xc: np.ndarray, starts: np.ndarray, ref
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """window_stats of x from xc = x - ref (made once by a caller that needs it again)."""
    n = np.diff(np.append(starts, xc.shape[0]))
    s1 = np.add.reduceat(xc, starts, axis=0)
    s2 = np.add.reduceat(xc * xc, starts, axis=0)
    mean_c = s1 / n[:, None]
    var = np.maximum(s2 - n[:, None] * mean_c**2, 0.0) / np.maximum(n - 1, 1)[:, None]
    return mean_c + ref, np.sqrt(var), n


def temp_slope(t: np.ndarray, temp: np.ndarray) -> float:
    """Least-squares slope dT/dt (degC/s)."""
    tc = t - t.mean()
    den = float(tc @ tc)
    return float(tc @ (temp - temp.mean()) / den) if den > 0 else 0.0


def hold_rows(
    p: PoseLabel, t: np.ndarray, acc: np.ndarray, temp: np.ndarray | None, mean: np.ndarray, window_s: float,
    quantum: float,
) -> tuple[dict[str, np.ndarray], np.ndarray]:  # fmt: skip
    """(columns, tau): the observation rows of one trimmed hold (t s, acc g, temp degC or None, mean
    its mean g) as ObsTable columns (pose_id apart), and the hold's integrated autocorrelation time
    per axis (samples; hold_noise.integrated_autocorr_time, for hold_stats). Columns: meas_g = window mean, sigma_g = std_window sqrt(tau_hold /
    n_window) (floored at quantum / sqrt(12 n)), t_s = mean sample time of the window,
    t_in_pose_s = t_s - label start, temp_degC = window mean, dtemp_degC_per_s = slope of the window
    means within the hold (the in-window slope for a single-window hold), q = the label's nominal
    orientation (NaN if unknown)."""
    n_all = acc.shape[0]
    nwin = max(1, int(np.floor((t[-1] - t[0]) / window_s + 1e-9)))
    edges = t[0] + (t[-1] - t[0]) * np.arange(nwin) / nwin
    starts = np.unique(np.searchsorted(t, edges))
    starts = starts[starts < n_all]
    xc = acc - mean  # once, for the windows and the autocorrelation
    wmean, std, n = centred_window_stats(xc, starts, mean)
    tau = np.asarray(integrated_autocorr_time(xc, centred=True))  # (3,): xc is (n, 3)
    del xc
    sigma = np.maximum(std * np.sqrt(tau[None, :] / n[:, None]), quantum / np.sqrt(12.0 * n[:, None]))
    tmid = np.add.reduceat(t - t[0], starts) / n + t[0]
    k = len(starts)
    q = np.asarray(p.q_sensor_to_world, float) if p.q_sensor_to_world is not None else np.full(4, np.nan)
    cols = {
        "meas_g": wmean,
        "sigma_g": sigma,
        "up_sensor": np.tile(np.asarray(p.up_sensor, float), (k, 1)),
        "t_s": tmid,
        "t_in_pose_s": tmid - p.start_s,
        "n_samples": n,
        "std_g": std,
        "q_sensor_to_world": np.tile(q, (k, 1)),
    }
    if temp is not None:
        tw = np.add.reduceat(temp, starts) / n
        cols["temp_degC"] = tw
        cols["dtemp_degC_per_s"] = np.gradient(tw, tmid) if k >= 2 else np.array([temp_slope(t, temp)])
    return cols, tau


def hold_stats(
    p: PoseLabel,
    t: np.ndarray,
    acc: np.ndarray,
    temp: np.ndarray | None,
    mean: np.ndarray,
    quantum: float,
    tau: np.ndarray | None = None,
) -> PoseStats:
    """PoseStats of one trimmed hold (arguments as hold_rows; tau: the tau hold_rows returned for
    it, the same values: the autocorrelation is not computed again)."""
    sem, tau = sem_autocorr(acc, quantum=quantum, tau=tau)
    tmean = dtemp = None
    if temp is not None:
        tmean = float(temp.mean())
        dtemp = temp_slope(t, temp)
    return PoseStats(
        name=p.name,
        hold_index=p.hold_index,
        up_sensor=np.asarray(p.up_sensor, float),
        start_s=float(t[0]),
        end_s=float(t[-1]),
        n=int(acc.shape[0]),
        mean_g=mean,
        std_g=acc.std(axis=0, ddof=1),
        sem_g=sem,
        tau_samples=tau,
        temp_degC=tmean,
        dtemp_degC_per_s=dtemp,
    )
