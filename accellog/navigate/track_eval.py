"""Tracks against the truth (simulations) or against themselves (loop closure), and the per-session
pipeline behind ``accellog track``: one track per calibration, optionally ZUPT-smoothed.

Errors (m), with e(t) = p_track(t) - p_true(t) (truth linearly interpolated to the track times):
    final = |e(t_end)|,  rms = sqrt(mean_k |e(t_k)|^2),  max = max_k |e(t_k)|,
    growth: |e| at n_growth evenly spaced times (how the error grows with time).
Without truth, for a path that returns to its start: loop closure = |p(t_end) - p(t_0)|, and
relative to the distance travelled sum_k |p_{k+1} - p_k|.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field

import numpy as np

from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.model.session_drivers import session_drivers
from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.navigate.strapdown import Track, initial_orientation, strapdown, yaw_of
from accellog.navigate.zupt import ZuptResult, apply_zupt, detect_stationary


@dataclass
class TrackError(JsonResult):
    """How far one track is off. reference: 'truth' or 'loop_closure' (then rms/max are NaN)."""

    name: str
    reference: str
    duration_s: float
    final_error_m: float
    final_error_vec_m: list[float]
    rms_error_m: float
    max_error_m: float
    path_length_m: float
    growth_t_s: list[float] = field(default_factory=list)
    growth_error_m: list[float] = field(default_factory=list)
    zupt_stops: int = 0
    """Number of stationary intervals used by ZUPT (0 = not applied)."""

    @property
    def final_error_pct_of_path(self) -> float:
        return 100.0 * self.final_error_m / self.path_length_m if self.path_length_m > 0 else float("nan")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["final_error_pct_of_path"] = self.final_error_pct_of_path
        return d


def _path_length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def evaluate_track(
    track: Track, truth_t_s: np.ndarray, truth_position_m: np.ndarray, *, n_growth: int = 10
) -> TrackError:
    """Compare a track with a true position history (K,) s, (K,3) m (world frame)."""
    tt = np.asarray(truth_t_s, float)
    tp = np.asarray(truth_position_m, float)
    if tt.size < 2 or tp.shape != (tt.size, 3):
        raise InputError("truth needs at least 2 samples of (t, position xyz)")
    ref = np.stack([np.interp(track.t_s, tt, tp[:, c]) for c in range(3)], axis=1)
    e = track.position_m - ref
    en = np.linalg.norm(e, axis=1)
    tg = np.linspace(track.t_s[0], track.t_s[-1], n_growth + 1)[1:]
    return TrackError(
        name=track.name,
        reference="truth",
        duration_s=float(track.t_s[-1] - track.t_s[0]),
        final_error_m=float(en[-1]),
        final_error_vec_m=[float(x) for x in e[-1]],
        rms_error_m=float(np.sqrt(np.mean(en**2))),
        max_error_m=float(en.max()),
        path_length_m=_path_length(ref),
        growth_t_s=[float(x) for x in tg],
        growth_error_m=[float(x) for x in np.interp(tg, track.t_s, en)],
    )


def loop_closure(track: Track) -> TrackError:
    """Closure error of a track whose path returns to its start (no truth needed)."""
    e = track.position_m[-1] - track.position_m[0]
    return TrackError(
        name=track.name,
        reference="loop_closure",
        duration_s=float(track.t_s[-1] - track.t_s[0]),
        final_error_m=float(np.linalg.norm(e)),
        final_error_vec_m=[float(x) for x in e],
        rms_error_m=float("nan"),
        max_error_m=float("nan"),
        path_length_m=_path_length(track.position_m),
    )


# ---------------------------------------------------------------- per-session pipeline


@dataclass
class TrackRun:
    """One calibration's track through a session: raw strapdown, optional ZUPT, and its errors."""

    name: str
    track: Track
    error: TrackError
    zupt: ZuptResult | None = None
    error_without_zupt: TrackError | None = None


def accel_corrector(cal, session=None) -> Callable[[np.ndarray], np.ndarray]:
    """A calibration as accel_g (N,3) -> corrected accel_g (N,3), in g0 units (what strapdown wants).

    accellog.calibrate.calfile.calibration.Calibration: correct_mps2(a, drivers) / g0, with the temperature/time
    drivers its model needs taken from the session; any other object: its ``correct(a)`` method;
    a plain callable: used as is.
    """
    if hasattr(cal, "correct_mps2"):
        drivers = None
        if session is not None:
            needed = list(getattr(cal.model, "required_drivers", []) or [])
            drivers = session_drivers(session, needed)
        return lambda a: np.asarray(cal.correct_mps2(a, drivers), float) / STANDARD_GRAVITY_MPS2
    fn = getattr(cal, "correct", cal)
    if not callable(fn):
        raise InputError(f"calibration {cal!r} has no correct() method")
    return fn


def gyro_corrector(cal, session=None) -> Callable[[np.ndarray], np.ndarray] | None:
    """The gyro part of a calibration (its ``gyro`` attribute, a GyroCalibration), or None."""

    g: GyroCalibration | None = getattr(cal, "gyro", None)
    if g is None:
        return None
    temp = None if session is None else session.temp_degC
    return lambda w: g.correct(w, temp_degC=temp)


def run_tracks(
    t_s: np.ndarray,
    accel_g: np.ndarray,
    gyro_dps: np.ndarray,
    corrections: Mapping[str, Callable[[np.ndarray], np.ndarray] | None],
    *,
    local_gravity_mps2: float,
    truth_t_s: np.ndarray | None = None,
    truth_position_m: np.ndarray | None = None,
    truth_q0: np.ndarray | None = None,
    use_zupt: bool = True,
    correct_gyro: Callable[[np.ndarray], np.ndarray] | None = None,
    static_window_s: float = 1.0,
    detect_kw: Mapping | None = None,
    gyro_corrections: Mapping[str, Callable[[np.ndarray], np.ndarray] | None] | None = None,
) -> list[TrackRun]:
    """One track per named accel correction (None = raw).

    Gyro: a track named in gyro_corrections uses its own gyro correction (its calibration's gyro
    part); the others use correct_gyro if given, else the bias is the mean rate over the first
    static_window_s (the run must start standing still). Initial orientation: roll/pitch from each corrected
    accel over the first static window; yaw from truth_q0 if given, else 0. Start position: truth
    at t0 if given, else 0. Errors vs truth when truth is given, else loop closure. With use_zupt,
    stops are detected once (on the raw accel and the corrected gyro) and applied to every track;
    no stop found -> InputError.
    """
    t = np.asarray(t_s, float)
    w = np.asarray(gyro_dps, float)
    if correct_gyro is not None:
        w = np.asarray(correct_gyro(w), float)
    else:
        sel = t <= t[0] + static_window_s
        w = w - w[sel].mean(axis=0)
    yaw = yaw_of(truth_q0) if truth_q0 is not None else 0.0
    p0 = np.zeros(3)
    if truth_position_m is not None and truth_t_s is not None:
        p0 = np.array([np.interp(t[0], truth_t_s, np.asarray(truth_position_m)[:, c]) for c in range(3)])
    intervals = None
    if use_zupt:
        intervals = detect_stationary(t, accel_g, w, **dict(detect_kw or {}))
        if intervals.shape[0] == 0:
            raise InputError(
                "no stops (stationary intervals) found in the session: cannot apply "
                "zero-velocity updates; run with --no-zupt"
            )
    runs: list[TrackRun] = []
    own_gyro = dict(gyro_corrections or {})
    for name, corr in corrections.items():
        a = np.asarray(corr(accel_g) if corr is not None else accel_g, float)
        gyro_corr = own_gyro.get(name)
        wk = np.asarray(gyro_corr(gyro_dps), float) if gyro_corr is not None else w
        q0 = initial_orientation(t, a, window_s=static_window_s, yaw_rad=yaw)
        tr = strapdown(t, a, wk, q0=q0, local_gravity_mps2=local_gravity_mps2, p0=p0, name=name)

        def _eval(track: Track) -> TrackError:
            if truth_position_m is not None and truth_t_s is not None:
                return evaluate_track(track, truth_t_s, truth_position_m)
            return loop_closure(track)

        if intervals is not None:
            z = apply_zupt(tr, intervals)
            err = _eval(z.track)
            err.zupt_stops = z.n_stops
            runs.append(TrackRun(name, z.track, err, zupt=z, error_without_zupt=_eval(tr)))
        else:
            runs.append(TrackRun(name, tr, _eval(tr)))
    return runs


def run_session_tracks(
    session, calibrations: Mapping[str, object] | None = None, *, use_zupt: bool = True, **kw
) -> list[TrackRun]:
    """run_tracks on an accellog Session: 'raw' plus one track per calibration object.

    A calibration is an accellog Calibration, any object with ``correct(accel_g)``, or a callable
    (see accel_corrector). Each calibration's track uses its own gyro part (see gyro_corrector)
    when it has one; 'raw' and calibrations without one take the gyro bias from the first static
    window. Raises InputError when the session has no gyro data (orientation cannot be tracked).
    """
    where = session.path or "session"
    if session.gyro_dps is None:
        raise InputError(
            "session has no gyro data: orientation, and so a track, cannot be computed", where=where
        )
    if session.n < 3:
        raise InputError("session has fewer than 3 samples: no track", where=where)
    corrections: dict[str, Callable | None] = {"raw": None}
    gyro_corrections: dict[str, Callable | None] = {}
    for name, cal in (calibrations or {}).items():
        corrections[name] = accel_corrector(cal, session)
        gyro_corrections[name] = gyro_corrector(cal, session)
    truth = session.truth
    try:
        return run_tracks(
            session.t_s,
            session.accel_g,
            session.gyro_dps,
            corrections,
            local_gravity_mps2=session.meta.local_gravity_mps2,
            truth_t_s=None if truth is None else truth.t_s,
            truth_position_m=None if truth is None else truth.position_m,
            truth_q0=None if truth is None else truth.q_sensor_to_world[0],
            use_zupt=use_zupt,
            gyro_corrections=gyro_corrections,
            **kw,
        )
    except InputError as exc:
        if exc.where is None:
            raise InputError(str(exc), where=where) from None
        raise


__all__ = [
    "TrackError",
    "TrackRun",
    "accel_corrector",
    "evaluate_track",
    "gyro_corrector",
    "loop_closure",
    "run_session_tracks",
    "run_tracks",
]
