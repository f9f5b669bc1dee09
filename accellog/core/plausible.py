"""What an IMU recording can plausibly hold, and which unit mistake explains values that it cannot.

Used at the door (``accellog import csv`` refuses with the likely fix) and by ``accellog doctor``
(reports a defect in a file already written):

- sample rate 1 / median(dt) within RATE_MIN_HZ .. RATE_MAX_HZ (1 Hz .. 100 kHz); outside, the time
  unit u in {s, ms, us, ns} whose rate 1 / (step * u) lies in that range, closest to
  TYPICAL_RATE_HZ on a log scale, is the likely one;
- median |a| at rest ~ 1 g (0.5 .. 2 g): ~9.8 means m/s^2, >= 500 means raw counts at the nearest
  MPU-9250 sensitivity (16384 / 8192 / 4096 / 2048 LSB/g), ~1 g times a power of 2 a full-scale
  mismatch (``accel_scale_guess``: a +-8 g log converted as +-2 g reads 0.25 g);
- gyro: a median |w| above 2000 deg/s (35 rad/s) is beyond any MEMS range; whole numbers with a
  median |w| above GYRO_INT_DPS (or beside accelerometer counts) are raw counts read as deg/s; in
  motion, a gyro that integrates to ~57x less than the turns of gravity the accelerometer sees is
  rad/s read as deg/s (``GravityTurns``: at rest the magnitude alone cannot tell);
- time stamps must fit int64 nanoseconds: |t| < MAX_TIME_S (about 292 years);
- every sample finite, |a| <= MAX_ACCEL_G and |w| <= MAX_GYRO_DPS (no MEMS part measures beyond).
"""

from __future__ import annotations

import math

import numpy as np

from accellog.core.units import ACCEL_LSB_PER_G, STANDARD_GRAVITY_MPS2

RATE_MIN_HZ = 1.0
RATE_MAX_HZ = 1e5
TYPICAL_RATE_HZ = 200.0
"""Centre (log scale) of the rates IMU loggers use; picks between two plausible time units."""
TIME_UNIT_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
TIME_UNIT_NAME = {"s": "seconds", "ms": "milliseconds", "us": "microseconds", "ns": "nanoseconds"}
MAX_TIME_S = 9.2e9
"""Largest |t| (s) that int64 nanoseconds hold (2**63 ns = 9.22e9 s), with a margin for rounding."""
MAX_ACCEL_G = 1000.0
"""Largest |a| (g) of one sample on any axis: high-g MEMS parts reach 400 g; 1e300 is a corrupt value."""
MAX_GYRO_DPS = 1e5
"""Largest |w| (deg/s) of one sample on any axis (MEMS gyros reach 4000 deg/s)."""
GYRO_MAX_DPS = 2000.0
GYRO_INT_DPS = 20.0
"""Median |w| (deg/s) above which whole-number gyro values are taken for raw counts."""
GYRO_LSB_HINT = "LSB is 131, 65.5, 32.8 or 16.4 per deg/s for +-250, 500, 1000 or 2000 deg/s"


def rate_ok(rate_hz: float) -> bool:
    """True for a sample rate an IMU can have (RATE_MIN_HZ .. RATE_MAX_HZ)."""
    return RATE_MIN_HZ <= rate_hz <= RATE_MAX_HZ


def likely_time_unit(step: float, declared: str = "s", keep_declared: bool = True) -> str | None:
    """The time unit that makes a median step of ``step`` (in the declared unit) a plausible rate
    (the one closest to TYPICAL_RATE_HZ), None when no unit does; ``declared`` itself if it does
    (unless keep_declared=False: then the best other unit)."""
    if not (step > 0 and math.isfinite(step)):
        return None
    rates = {u: 1.0 / (step * f) for u, f in TIME_UNIT_S.items()}
    if keep_declared and rate_ok(rates[declared]):
        return declared
    ok = [u for u, r in rates.items() if rate_ok(r) and (keep_declared or u != declared)]
    return min(ok, key=lambda u: abs(math.log(rates[u] / TYPICAL_RATE_HZ))) if ok else None


def accel_unit_guess(median_norm: float) -> tuple[str, float | None] | None:
    """('g', None), ('m/s^2', None) or ('counts', LSB/g) for a median |a| at rest given as a bare
    number; None when no unit makes it ~1 g."""
    m = median_norm
    if 0.5 <= m <= 2.0:
        return "g", None
    if 0.5 * STANDARD_GRAVITY_MPS2 <= m <= 2.0 * STANDARD_GRAVITY_MPS2:
        return "m/s^2", None
    if m >= 500:
        return "counts", nearest_accel_lsb(m)
    return None


ACCEL_SCALES = (2.0, 4.0, 8.0, 16.0, 0.5, 0.25, 0.125, 0.0625)
"""Full-scale mismatches: counts of a +-A g range converted with the sensitivity of a +-B g one read
B/A times the truth (a +-8 g log printed with +-2 g's 16384 LSB/g reads 1/4 g at rest)."""


def accel_scale_guess(median_g: float) -> float | None:
    """The factor k in ACCEL_SCALES that makes a median |a| of ``median_g`` (g) read 0.9 .. 1.1 g at
    rest (k * median_g), None when none does."""
    ok = [k for k in ACCEL_SCALES if 0.9 <= k * median_g <= 1.1]
    return min(ok, key=lambda k: abs(math.log(k * median_g))) if ok else None


def nearest_accel_lsb(counts_per_g: float) -> float:
    """The MPU-9250 accelerometer sensitivity (LSB/g) nearest on a log scale to a median |a| in counts."""
    m = max(float(counts_per_g), 1e-9)
    return min(ACCEL_LSB_PER_G.values(), key=lambda v: abs(math.log(m / v)))


def gyro_counts_evidence(w: np.ndarray, accel_counts: bool, to_dps: float = 1.0) -> str | None:
    """Why gyro values (n, 3) taken for deg/s (``to_dps`` = 180/pi for rad/s) look like raw counts, or
    None: a median |w| beyond GYRO_MAX_DPS, or whole numbers only with a median |w| above GYRO_INT_DPS
    (or beside accelerometer counts, not all equal)."""
    w = np.asarray(w, dtype=np.float64)
    w = w[np.all(np.isfinite(w), axis=1)]
    if w.shape[0] < 2:
        return None
    med = float(np.median(np.abs(w))) * to_dps
    if med > GYRO_MAX_DPS:
        return f"have a median magnitude of {med:.4g} deg/s, beyond any MEMS range"
    whole = bool(np.all(w == np.round(w)))
    if whole and (med > GYRO_INT_DPS or (accel_counts and np.ptp(w) > 0)):
        beside = " beside accelerometer counts" if accel_counts else ""
        return f"are whole numbers only (median magnitude {med:.4g} deg/s){beside}"
    return None


GYRO_WINDOW_S = 0.1
"""Accelerometer and gyro samples are averaged over windows of this length (s) to compare turns."""
STILL_STD_G = 0.02
"""A window is still when each accelerometer axis varies by less than this (std, g) within it."""
STILL_STEP_DEG = 1.0
"""... and its mean direction differs from the window before by less than this (deg)."""
STILL_MIN_WINDOWS = 5
"""A rest: at least this many consecutive still windows (0.5 s)."""
GYRO_MOVE_MIN_DEG = 20.0
"""A move between rests counts when gravity's direction differs by more (deg): a linear acceleration
that tilts it this far (0.36 g, held steady) is no rest."""
GYRO_TURN_MIN_DEG = 60.0
"""Gravity must turn by this much in all (deg) before the gyro's unit is judged from the motion."""
RAD_AS_DEG_RATIO = (20.0, 200.0)
"""turn / gyro integral of rad/s read as deg/s: 180 / pi = 57.3, within the slack of the bound."""


def _windows(t_s: np.ndarray, a: np.ndarray, speed: np.ndarray, n: int):
    """Per window of n rows (len(t_s) a multiple of n): last time (s), mean a (g), largest axis std
    of a (g), mean speed (deg/s)."""
    at = np.arange(0, t_s.shape[0], n)
    mean = np.add.reduceat(a, at, axis=0) / n
    var = np.add.reduceat(a * a, at, axis=0) / n - mean * mean
    return t_s[n - 1 :: n], mean, np.sqrt(np.maximum(var.max(axis=1), 0.0)), np.add.reduceat(speed, at) / n


def _angle_deg(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(float(u @ v), -1.0, 1.0))))


class GravityTurns:
    """How far gravity turns between rests vs how far the gyro integrates meanwhile, fed block by block.

    Windows of ``n`` samples: mean acceleration a_k (g), mean speed s_k = mean |w| (deg/s), duration
    d_k (s). A rest is a run of >= STILL_MIN_WINDOWS still windows (each axis' std < STILL_STD_G,
    |a_k| within 0.9 .. 1.1 g, direction within STILL_STEP_DEG of the window before), its direction
    u_j the mean of its windows' a_k / |a_k|. Between rests j and j+1 whose directions differ by
    theta_j = acos(u_j . u_j+1) > GYRO_MOVE_MIN_DEG, the sensor turned by at least theta_j, so a gyro
    in the declared unit integrates to g_j = sum s_k d_k (the windows between) >= theta_j.
    ``turn_deg`` = sum theta_j, ``gyro_deg`` = sum g_j; ``ratio()`` after ``finish()``.
    """

    def __init__(self, n: int) -> None:
        self.n = max(int(n), 1)
        self.turn_deg = 0.0
        self.gyro_deg = 0.0
        self._rest: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._rest_dir: np.ndarray | None = None  # direction of the last rest
        self._gap_deg = 0.0  # gyro integral since the last rest ended (deg)
        self._run: list = [0, np.zeros(3), 0.0]  # still windows in a row: count, sum of directions, gyro
        self._prev_u: np.ndarray | None = None  # last window's direction, and whether it was still
        self._prev_still = False
        self._prev_t: float | None = None

    def feed(self, t_s: np.ndarray, accel_g: np.ndarray, gyro_dps: np.ndarray) -> None:
        """Add consecutive samples: t_s (n,) s, accel_g (n, 3) g, gyro_dps (n, 3) deg/s."""
        speed = np.sqrt(np.einsum("ij,ij->i", gyro_dps, gyro_dps))
        parts = []
        if self._rest is not None:  # the window begun in the block before, completed with this one's rows
            k = self.n - self._rest[0].shape[0]
            t0, a0, s0 = self._rest
            self._rest = None
            if t_s.shape[0] < k:
                self._rest = (np.r_[t0, t_s], np.vstack([a0, accel_g]), np.r_[s0, speed])
                return
            parts.append(
                _windows(np.r_[t0, t_s[:k]], np.vstack([a0, accel_g[:k]]), np.r_[s0, speed[:k]], self.n)
            )
            t_s, accel_g, speed = t_s[k:], accel_g[k:], speed[k:]
        m = (t_s.shape[0] // self.n) * self.n
        if m < t_s.shape[0]:
            self._rest = (t_s[m:].copy(), accel_g[m:].copy(), speed[m:].copy())
        if m:
            parts.append(_windows(t_s[:m], accel_g[:m], speed[:m], self.n))
        if not parts:
            return
        ends, aw, sd, sw = (np.concatenate(x) for x in zip(*parts, strict=True))
        norm = np.linalg.norm(aw, axis=1)
        u = aw / np.where(norm > 0, norm, 1.0)[:, None]
        still = (sd < STILL_STD_G) & (np.abs(norm - 1.0) < 0.1)
        gyro = sw * np.diff(ends, prepend=self._prev_t if self._prev_t is not None else ends[0])
        before = np.vstack([self._prev_u if self._prev_u is not None else np.zeros(3), u[:-1]])
        steady = np.sum(u * before, axis=1) > np.cos(np.radians(STILL_STEP_DEG))
        # windows by run: a still window continues the run of a still, steady window before it, or
        # starts one; id r numbers the runs begun in this block (0: the one carried in), and the
        # windows of id r are run r's still ones, then the moving ones after it (the gap)
        starts = still & ~(np.r_[self._prev_still, still[:-1]] & steady)
        ids = np.cumsum(starts)
        w = int(ids[-1]) + 1
        cnt = np.bincount(ids[still], minlength=w)
        dirs = np.stack([np.bincount(ids[still], u[still, j], minlength=w) for j in range(3)], 1)
        run_gyro = np.bincount(ids[still], gyro[still], minlength=w)
        gap_n = np.bincount(ids[~still], minlength=w)
        gap_gyro = np.bincount(ids[~still], gyro[~still], minlength=w)
        for r in range(w):
            if r > 0:
                self._close_run()
            self._run = [
                self._run[0] + int(cnt[r]),
                self._run[1] + dirs[r],
                self._run[2] + float(run_gyro[r]),
            ]
            if gap_n[r]:
                self._close_run()
                self._gap_deg += float(gap_gyro[r])
        self._prev_u, self._prev_still, self._prev_t = u[-1], bool(still[-1]), float(ends[-1])

    def _close_run(self) -> None:
        count, total, gyro = self._run
        self._run = [0, np.zeros(3), 0.0]
        if count < STILL_MIN_WINDOWS:
            self._gap_deg += gyro
            return
        d = total / np.linalg.norm(total)
        if self._rest_dir is not None:
            theta = _angle_deg(d, self._rest_dir)
            if theta > GYRO_MOVE_MIN_DEG:
                self.turn_deg += theta
                self.gyro_deg += self._gap_deg
        self._rest_dir, self._gap_deg = d, 0.0

    def finish(self) -> None:
        """After the last samples: the rest the file ends in counts too."""
        self._close_run()

    def ratio(self) -> float | None:
        """turn_deg / gyro_deg (inf for a gyro that did not move), None before gravity has turned by
        GYRO_TURN_MIN_DEG between rests: then the motion cannot judge the gyro's unit."""
        if self.turn_deg < GYRO_TURN_MIN_DEG:
            return None
        return self.turn_deg / self.gyro_deg if self.gyro_deg > 0 else math.inf

    def looks_like_rad_s(self) -> bool:
        """True when the gyro integrates RAD_AS_DEG_RATIO times less than gravity turns."""
        r = self.ratio()
        return r is not None and RAD_AS_DEG_RATIO[0] <= r <= RAD_AS_DEG_RATIO[1]
