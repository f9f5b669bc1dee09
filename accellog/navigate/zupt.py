"""Zero-velocity updates: find where the sensor stands still and take the velocity error out.

Detection (vectorised, centred moving windows of window_s seconds):
    stationary_k  <=>  std_window(|a|) < accel_std_g  and  | mean_window(w) - b_w | < gyro_dps_max
                       and | mean_window(|a|) - 1 | < accel_norm_tol_g
then runs shorter than min_duration_s are dropped. b_w (deg/s) is a residual gyro bias: the median
windowed rate where the accel is still and the rate steady, so a bias left by the calibration
(e.g. at another temperature) does not hide the stops, while a turn in place (no change in
acceleration, only the rate shows it) still counts as motion. Vehicles are told from standing
still by their vibration (a constant-speed cruise is otherwise invisible to an IMU).

Correction (standard ZUPT smoothing, velocity only): at stationary samples the true velocity is 0,
so the velocity error there is the integrated velocity itself; over each moving stretch between
two stops the error is taken to grow linearly in time from its value at the end of the previous
stop to its value at the start of the next one (and from 0 at t0 if the run starts moving):
    v_c = v - e(t),  e = v on stationary samples, linear interpolation in t between them;
    p_c = p0 + cumtrapz(v_c, t).
After the last stop the error is held constant (no later stop to anchor it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from accellog.core.errors import InputError
from accellog.core.timeseries import cumtrapz
from accellog.core.timeseries import runs as run_bounds
from accellog.navigate.strapdown import Track


@dataclass
class ZuptResult:
    """A ZUPT-corrected track and what was done to it.

    intervals_s: (K,2) start/end times (s) of the stationary intervals used;
    velocity_error_mps: (K,3) integrated velocity at the start of each stop (the error removed);
    final_shift_m: (3,) how far the correction moved the final position (m).
    """

    track: Track
    intervals_s: np.ndarray
    velocity_error_mps: np.ndarray
    final_shift_m: np.ndarray

    @property
    def n_stops(self) -> int:
        return int(self.intervals_s.shape[0])


def _moving_mean(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving mean over n samples (shrinking at the ends), via cumulative sums."""
    c = np.concatenate([[0.0], np.cumsum(x)])
    i = np.arange(x.size)
    lo = np.clip(i - n // 2, 0, x.size)
    hi = np.clip(i - n // 2 + n, 0, x.size)
    return (c[hi] - c[lo]) / (hi - lo)


def detect_stationary(
    t_s: np.ndarray,
    accel_g: np.ndarray,
    gyro_dps: np.ndarray,
    *,
    window_s: float = 0.2,
    accel_std_g: float = 0.02,
    gyro_dps_max: float = 2.0,
    accel_norm_tol_g: float = 0.2,
    min_duration_s: float = 0.5,
    trim_s: float = 0.1,
) -> np.ndarray:
    """Stationary intervals as (K,2) [start, end) sample indices (see module doc for the test).

    trim_s (s) is cut from both ends of each run (the window smears the edges of motion).
    """
    t = np.asarray(t_s, float)
    a = np.asarray(accel_g, float)
    w = np.asarray(gyro_dps, float)
    if t.size < 3:
        return np.zeros((0, 2), int)
    dt = float(np.median(np.diff(t)))
    n = max(3, round(window_s / dt))
    an = np.linalg.norm(a, axis=1)
    m1 = _moving_mean(an, n)
    var = np.maximum(_moving_mean(an * an, n) - m1 * m1, 0.0)
    still_a = (np.sqrt(var) < accel_std_g) & (np.abs(m1 - 1.0) < accel_norm_tol_g)
    # A gyro bias left by the calibration (e.g. at another temperature) must not hide the stops:
    # estimate it as the median rate over windows where the accel is still and the rate steady
    # (windowed std below gyro_dps_max / 2), then test the magnitude of the de-biased rate.
    w_mean = np.column_stack([_moving_mean(w[:, i], n) for i in range(3)])
    w_var = np.column_stack([_moving_mean(w[:, i] ** 2, n) for i in range(3)]) - w_mean**2
    steady = still_a & (np.sqrt(np.maximum(w_var, 0.0)).max(axis=1) < 0.5 * gyro_dps_max)
    bias = np.median(w_mean[steady], axis=0) if steady.any() else np.zeros(3)
    wn = np.linalg.norm(w_mean - bias, axis=1)
    mask = still_a & (wn < gyro_dps_max)
    runs = run_bounds(mask)
    if runs.size == 0:
        return runs
    t_lo = t[runs[:, 0]] + trim_s
    t_hi = t[runs[:, 1] - 1] - trim_s
    keep = (t_hi - t_lo) >= min_duration_s
    lo = np.searchsorted(t, t_lo[keep], side="left")
    hi = np.searchsorted(t, t_hi[keep], side="right")
    return np.stack([lo, hi], axis=1).astype(int)


def apply_zupt(track: Track, intervals: np.ndarray, *, v0=0.0) -> ZuptResult:
    """ZUPT-smooth a track with stationary index intervals (K,2) (see module doc).

    Raises InputError when there is no stationary interval: without a stop there is nothing to
    anchor the velocity, and returning the track unchanged would look like a correction.
    """
    iv = np.asarray(intervals, int).reshape(-1, 2)
    if iv.shape[0] == 0:
        raise InputError(
            "no stationary intervals found: zero-velocity updates cannot be applied (the "
            "run has no stops, or the thresholds are too tight)"
        )
    t = track.t_s
    v = track.velocity_mps
    mask = np.zeros(t.size, bool)
    for lo, hi in iv:
        mask[lo:hi] = True
    knots_t = t[mask]
    knots_e = v[mask]
    if not mask[0]:
        knots_t = np.concatenate([[t[0]], knots_t])
        knots_e = np.concatenate([(v[0] - np.asarray(v0, float) * np.ones(3))[None, :], knots_e])
    err = np.stack([np.interp(t, knots_t, knots_e[:, c]) for c in range(3)], axis=1)
    vc = v - err
    pc = track.position_m[0] + cumtrapz(t, vc)
    out = Track(t_s=t, q=track.q, velocity_mps=vc, position_m=pc, name=track.name)
    return ZuptResult(
        track=out,
        intervals_s=np.stack([t[iv[:, 0]], t[iv[:, 1] - 1]], axis=1),
        velocity_error_mps=v[iv[:, 0]],
        final_shift_m=pc[-1] - track.position_m[-1],
    )


def zupt(track: Track, accel_g: np.ndarray, gyro_dps: np.ndarray, *, v0=0.0, **detect_kw) -> ZuptResult:
    """Detect stops in the (corrected) readings that made the track, then apply_zupt."""
    iv = detect_stationary(track.t_s, accel_g, gyro_dps, **detect_kw)
    return apply_zupt(track, iv, v0=v0)
