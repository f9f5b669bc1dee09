"""Static holds -> statistics and observation tables for fitting (stage 'segment').

A labelled hold [start_s, end_s) is trimmed by trim_s at both ends (the hand that turned the cube
is still settling) and cut into windows of about window_s; each window gives one observation

    meas_g = window mean (g),   sigma_g = std_window * sqrt(tau_hold / n_window)   (g)

where tau_hold is the hold's integrated autocorrelation time (samples, accellog.calibrate.observe.hold_noise). Several
windows per hold keep slow effects (temperature, warm-up, time drift) visible to the fit.

Checks (each raises InputError naming the pose and time): no labels, overlapping or duplicated
labels, too few samples, NaN readings, a reading far from 1 g at rest (wrong units, e.g. counts
declared as g), and a hold labelled static that moves (window variance far above the noise, or a
window mean that wanders from the hold's median by more than a few degrees).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.observe.hold_noise import integrated_autocorr_time, sem_autocorr
from accellog.calibrate.observe.label_check import check_labels, check_timestamps
from accellog.core.errors import InputError, ModelError
from accellog.core.session import POSE_UP_VECTORS, ObsTable, PoseLabel, Session

UNIT_NORM_RANGE_G = (0.5, 2.0)
"""A reading at rest must have |a| in this range (g); outside it the units are wrong."""
MOVING_STD_FACTOR = 6.0
"""A check window whose std (norm over axes) exceeds this multiple of the session noise moves."""
MOVING_MEAN_SHIFT_G = 0.05
"""A check window whose mean leaves the hold's median by more than this (g, ~3 deg) moves."""


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
    lsb = session.meta.accel_lsb_per_g
    return 1.0 / lsb if lsb else 0.0


def pose_name_for_up(up: np.ndarray) -> str:
    """'+z' etc. for an up vector along an axis, else 'up(x,y,z)'."""
    for name, vec in POSE_UP_VECTORS.items():
        if np.allclose(up, vec, atol=1e-9):
            return name
    return "up(" + ",".join(f"{v:.3f}" for v in up) + ")"


def _hold_slices(session: Session, trim_s: float, min_samples: int) -> list[tuple[PoseLabel, slice]]:
    """Validated (label, sample slice) for every hold, in time order."""
    where = session_where(session)
    if session.n == 0 and session.poses:
        raise InputError("session has no samples", where=where)
    check_timestamps(session, where=where)
    labels = checked_labels(session.poses, where, session.events)
    out = []
    for p in labels:
        up = np.asarray(p.up_sensor, float)
        if up.shape != (3,) or not np.isfinite(up).all() or abs(np.linalg.norm(up) - 1.0) > 1e-3:
            raise InputError(f"pose {p.name!r}: up vector {p.up_sensor} is not a unit 3-vector", where=where)
        t0, t1 = p.start_s + trim_s, p.end_s - trim_s
        sl = session.slice_time(t0, t1) if t1 > t0 else slice(0, 0)
        n = sl.stop - sl.start
        if n < min_samples:
            raise InputError(
                f"pose {p.name!r} ({p.start_s:.2f}-{p.end_s:.2f} s) has {n} samples after trimming "
                f"{trim_s} s at each end (need >= {min_samples}): hold longer or lower --trim",
                where=where,
            )
        acc = session.accel_g[sl]
        if not np.isfinite(acc).all():  # one flat pass; the rows only when one is bad
            bad = ~np.isfinite(acc).all(axis=1)
            i = int(np.argmax(bad))
            raise InputError(
                f"pose {p.name!r}: accel is NaN/inf at t = {session.t_s[sl][i]:.3f} s "
                f"({int(bad.sum())} bad samples)",
                where=where,
            )
        out.append((p, sl))
    return out


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


def _check_units(session: Session, holds: list[tuple[PoseLabel, slice]], means: list[np.ndarray]) -> None:
    lo, hi = UNIT_NORM_RANGE_G
    for (p, _sl), mean in zip(holds, means, strict=True):
        norm = float(np.linalg.norm(mean))
        if not lo <= norm <= hi:
            hint = " (are raw counts declared as g? check accel_lsb_per_g)" if norm > hi else ""
            raise InputError(
                f"pose {p.name!r}: |accel| at rest is {norm:.4g} g, expected about 1 g{hint}",
                where=session_where(session),
            )


MIN_WINDOW_SAMPLES = 10
"""A window must hold this many samples (its mean and std mean nothing with fewer)."""


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


def window_stats(x: np.ndarray, starts: np.ndarray, ref=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean, std (ddof=1), n) of x (n,k) over windows at indices `starts` (sorted); ref: x's mean, if known."""
    ref = x.mean(axis=0) if ref is None else ref
    xc = x - ref
    n = np.diff(np.append(starts, x.shape[0]))
    s1 = np.add.reduceat(xc, starts, axis=0)
    s2 = np.add.reduceat(xc * xc, starts, axis=0)
    mean_c = s1 / n[:, None]
    var = np.maximum(s2 - n[:, None] * mean_c**2, 0.0) / np.maximum(n - 1, 1)[:, None]
    return mean_c + ref, np.sqrt(var), n


def check_static(
    session: Session,
    holds: list[tuple[PoseLabel, slice]] | None = None,
    *,
    trim_s: float = 0.5,
    window_s: float = 0.5,
    std_factor: float = MOVING_STD_FACTOR,
    mean_shift_g: float = MOVING_MEAN_SHIFT_G,
) -> None:
    """Raise InputError if a hold labelled static moves.

    Each hold is cut into window_s windows; the noise reference is the median window std per axis
    over the whole session (most windows are static). A window moves if its std norm exceeds
    std_factor * reference (and 4 quanta), or its mean leaves the hold's median by > mean_shift_g.
    """
    holds = holds if holds is not None else _hold_slices(session, trim_s, 2)
    per_hold = [(p, *static_windows(session.t_s[sl], session.accel_g[sl], window_s)) for p, sl in holds]
    moving_check(per_hold, quantum_g(session), session_where(session), std_factor, mean_shift_g)


def static_windows(t: np.ndarray, acc: np.ndarray, window_s: float = 0.5) -> tuple:
    """check_static's windows of one hold: (window start times, end times, mean, std, n)."""
    edges = np.arange(t[0], t[-1], window_s)
    starts = np.unique(np.searchsorted(t, edges))
    mean, std, n = window_stats(acc, starts)
    ends = np.append(starts[1:] - 1, t.shape[0] - 1)
    return t[starts], t[ends], mean, std, n


def moving_check(
    per_hold: list[tuple],
    quantum: float,
    where: str,
    std_factor: float = MOVING_STD_FACTOR,
    mean_shift_g: float = MOVING_MEAN_SHIFT_G,
) -> None:
    """check_static's verdict from every hold's static_windows (label first): the noise reference
    is the median window std over the whole session."""
    shifted = [(p, t0, t1, mean_shift(mean), std, n) for p, t0, t1, mean, std, n in per_hold]
    moving_verdict(shifted, quantum, where, std_factor, mean_shift_g)


def mean_shift(mean: np.ndarray) -> np.ndarray:
    """|window mean - the hold's median window mean| (g) per window of one hold."""
    return np.linalg.norm(mean - np.median(mean, axis=0), axis=1)


def moving_verdict(
    per_hold: list[tuple],
    quantum: float,
    where: str,
    std_factor: float = MOVING_STD_FACTOR,
    mean_shift_g: float = MOVING_MEAN_SHIFT_G,
    ref: float | None = None,
) -> None:
    """moving_check on (label, t_start, t_end, mean_shift, std, n) per hold (the shift taken when the
    hold passed: no window means kept); ref: the session noise reference (g, the norm of the median
    std per axis of the windows of n > 2) when the caller has it (then there is such a window)."""
    if ref is None:
        all_std = np.concatenate([h[4][h[5] > 2] for h in per_hold]) if per_hold else np.zeros((0, 3))
        if all_std.shape[0] == 0:
            return
        ref = float(np.linalg.norm(np.median(all_std, axis=0)))
    limit = max(std_factor * ref, 4.0 * quantum)
    for p, t_start, t_end, shift, std, n in per_hold:
        snorm = np.linalg.norm(std, axis=1)
        bad_std = (snorm > limit) & (n > 2)
        bad_mean = shift > mean_shift_g
        bad = bad_std | bad_mean
        if bad.any():
            j = int(np.argmax(bad))
            raise moving_error(
                p.name, t_start[j], t_end[j], snorm[j] if bad_std[j] else None, shift[j], ref, where
            )


def moving_error(
    name: str, t_start: float, t_end: float, std_g: float | None, shift_g: float, ref: float, where: str
) -> InputError:
    """The motion check's refusal of the window t_start..t_end (s) of hold ``name``: its std norm
    std_g (g) against the session noise ref (g), or (std_g None) its mean shift_g (g)."""
    why = (
        f"accel std {std_g:.4g} g is {std_g / max(ref, 1e-12):.0f}x the session noise {ref:.3g} g"
        if std_g is not None
        else f"mean moved {shift_g:.3g} g from the hold's median"
    )
    return InputError(
        f"pose {name!r} is labelled static but moves at t = {t_start:.2f}-{t_end:.2f} s: "
        f"{why}; relabel or trim the hold",
        where=where,
    )


def _checked_holds(
    session: Session, trim_s: float, min_samples: int, check_units: bool, check_moving: bool
) -> tuple[list[tuple[PoseLabel, slice]], list[np.ndarray]]:
    """Validated holds (see _hold_slices) and their mean readings (g), checked for units and motion if asked."""
    holds = _hold_slices(session, trim_s, min_samples)
    means = [session.accel_g[sl].mean(axis=0) for _p, sl in holds]  # once, for the checks and the caller
    if check_units:
        _check_units(session, holds, means)
        check_labels(session, holds, where=session_where(session), means=means)
    if check_moving:
        check_static(session, holds)
    return holds, means


def _temp_slope(t: np.ndarray, temp: np.ndarray) -> float:
    """Least-squares slope dT/dt (degC/s)."""
    tc = t - t.mean()
    den = float(tc @ tc)
    return float(tc @ (temp - temp.mean()) / den) if den > 0 else 0.0


def pose_stats(
    session: Session,
    *,
    trim_s: float = 0.5,
    min_samples: int = 20,
    check_units: bool = True,
    check_moving: bool = True,
) -> list[PoseStats]:
    """Per-hold statistics (mean, std, autocorrelation-aware sem, tau, temperature, times)."""
    holds, means = _checked_holds(session, trim_s, min_samples, check_units, check_moving)
    q = quantum_g(session)
    out = []
    for (p, sl), mean in zip(holds, means, strict=True):
        acc = session.accel_g[sl]
        t = session.t_s[sl]
        sem, tau = sem_autocorr(acc, quantum=q)
        temp = dtemp = None
        if session.temp_degC is not None:
            tt = session.temp_degC[sl]
            temp = float(tt.mean())
            dtemp = _temp_slope(t, tt)
        out.append(
            PoseStats(
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
                temp_degC=temp,
                dtemp_degC_per_s=dtemp,
            )
        )
    return out


def observations(
    session: Session,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    *,
    min_samples: int = 20,
    check_units: bool = True,
    check_moving: bool = True,
) -> ObsTable:
    """ObsTable with one row per window of about window_s in every trimmed hold.

    Rows: meas_g = window mean, sigma_g = std_window sqrt(tau_hold / n_window) (floored at the
    quantum / sqrt(12 n)), t_s = mean sample time of the window, t_in_pose_s = t_s - label start,
    temp_degC = window mean, dtemp_degC_per_s = slope of the window means within the hold (the
    in-window slope for a single-window hold), q = the label's nominal orientation (NaN if unknown).
    """
    check_window(window_s, session.meta.sample_rate_hz, session_where(session))
    holds, means = _checked_holds(session, trim_s, min_samples, check_units, check_moving)
    quantum = quantum_g(session)
    names: list[str] = []
    name_id: dict[str, int] = {}
    cols: dict[str, list[np.ndarray]] = {
        k: [] for k in ("meas", "sigma", "std", "up", "pid", "t", "tin", "n", "temp", "dtemp", "q")
    }
    has_temp = session.temp_degC is not None
    for (p, sl), hold_mean in zip(holds, means, strict=True):
        acc = session.accel_g[sl]
        t = session.t_s[sl]
        n_all = acc.shape[0]
        nwin = max(1, int(np.floor((t[-1] - t[0]) / window_s + 1e-9)))
        edges = t[0] + (t[-1] - t[0]) * np.arange(nwin) / nwin
        starts = np.unique(np.searchsorted(t, edges))
        starts = starts[starts < n_all]
        mean, std, n = window_stats(acc, starts, hold_mean)
        tau = integrated_autocorr_time(acc, mean=hold_mean)
        sigma = np.maximum(std * np.sqrt(tau[None, :] / n[:, None]), quantum / np.sqrt(12.0 * n[:, None]))
        tmid = np.add.reduceat(t - t[0], starts) / n + t[0]
        if p.name not in name_id:
            name_id[p.name] = len(names)
            names.append(p.name)
        k = len(starts)
        cols["meas"].append(mean)
        cols["sigma"].append(sigma)
        cols["std"].append(std)
        cols["up"].append(np.tile(np.asarray(p.up_sensor, float), (k, 1)))
        cols["pid"].append(np.full(k, name_id[p.name]))
        cols["t"].append(tmid)
        cols["tin"].append(tmid - p.start_s)
        cols["n"].append(n)
        q = np.asarray(p.q_sensor_to_world, float) if p.q_sensor_to_world is not None else np.full(4, np.nan)
        cols["q"].append(np.tile(q, (k, 1)))
        if has_temp:
            temp = session.temp_degC[sl]
            tw = np.add.reduceat(temp, starts) / n
            dtw = np.gradient(tw, tmid) if k >= 2 else np.array([_temp_slope(t, temp)])
            cols["temp"].append(tw)
            cols["dtemp"].append(dtw)
    return ObsTable(
        meas_g=np.concatenate(cols["meas"]),
        sigma_g=np.concatenate(cols["sigma"]),
        up_sensor=np.concatenate(cols["up"]),
        pose_id=np.concatenate(cols["pid"]).astype(int),
        pose_names=names,
        t_s=np.concatenate(cols["t"]),
        t_in_pose_s=np.concatenate(cols["tin"]),
        n_samples=np.concatenate(cols["n"]).astype(int),
        std_g=np.concatenate(cols["std"]),
        temp_degC=np.concatenate(cols["temp"]) if has_temp else None,
        dtemp_degC_per_s=np.concatenate(cols["dtemp"]) if has_temp else None,
        q_sensor_to_world=np.concatenate(cols["q"]),
        session=session.path or session.meta.source,
    )


def obs_from_pose_means(
    up: np.ndarray,
    mean_g: np.ndarray,
    std_g: np.ndarray,
    n: int | np.ndarray,
    *,
    names: Sequence[str] | None = None,
    session: str = "",
    where: str | None = None,
) -> ObsTable:
    """ObsTable with one row per pose from summary means (the seed's six_position_data CSVs).

    up: (k,3) true reading / 1 g (the seed's x_true, y_true, z_true columns), mean_g, std_g: (k,3);
    n: samples per pose (scalar or (k,)). sigma_g = std_g / sqrt(n): the summaries carry no
    autocorrelation information, so this naive standard error is too small (documented limit).
    """
    up = np.atleast_2d(np.asarray(up, float))
    mean_g = np.atleast_2d(np.asarray(mean_g, float))
    std_g = np.atleast_2d(np.asarray(std_g, float))
    k = up.shape[0]
    if up.shape != (k, 3) or mean_g.shape != (k, 3) or std_g.shape != (k, 3):
        raise InputError(
            f"pose table shapes differ: up {up.shape}, mean {mean_g.shape}, std {std_g.shape}", where=where
        )
    for arr, what in ((up, "truth"), (mean_g, "mean"), (std_g, "std")):
        if not np.isfinite(arr).all():
            row = int(np.argmax(~np.isfinite(arr).all(axis=1)))
            raise InputError(f"{what} of pose row {row + 1} is NaN", where=where)
    nn = np.broadcast_to(np.asarray(n, float), (k,)).astype(float)
    pose_names = list(names) if names is not None else [pose_name_for_up(u) for u in up]
    dup = {x for x in pose_names if pose_names.count(x) > 1}
    if dup:
        raise InputError(f"pose(s) {sorted(dup)} appear more than once in the pose table", where=where)
    return ObsTable(
        meas_g=mean_g.copy(),
        sigma_g=std_g / np.sqrt(nn)[:, None],
        up_sensor=up.copy(),
        pose_id=np.arange(k),
        pose_names=pose_names,
        t_s=np.zeros(k),
        t_in_pose_s=np.zeros(k),
        n_samples=nn.astype(int),
        std_g=std_g.copy(),
        q_sensor_to_world=np.full((k, 4), np.nan),
        session=session,
    )


def check_coverage(obs: ObsTable, needs_scale: bool = True, where: str | None = None) -> None:
    """Raise ModelError if the poses cannot determine the model.

    Bias-only needs one pose; a scale or 3x3 model needs up vectors that are affinely independent in
    3-D (rank [up 1] = 4), e.g. both sides of every axis. The message lists the missing faces.
    """
    if obs.n == 0:
        raise ModelError("no observations to fit", where=where or obs.session or None)
    if not needs_scale:
        return
    ups = np.unique(np.round(obs.up_sensor, 6), axis=0)
    A = np.c_[ups, np.ones(ups.shape[0])]
    # Per axis i, bias and scale separate only with two different up_i values.
    spread = np.ptp(ups, axis=0) if ups.shape[0] else np.zeros(3)
    if np.linalg.matrix_rank(A) < 4 or np.any(spread < 0.5):
        have = {pose_name_for_up(u) for u in ups}
        missing = [f for f in POSE_UP_VECTORS if f not in have]
        raise ModelError(
            f"poses {sorted(have)} cannot separate bias from scale: missing {', '.join(missing) or 'distinct poses'}",
            where=where or obs.session or None,
        )
