"""Gyro calibration fits: zero-rate bias (and its temperature slope) from the window means of static
holds; scale and misalignment from the rotations between labelled poses. These are the pure steps
on the sums that accellog.calibrate.gyro.stream reduces a session's blocks to (the one pass over
the samples; calibrate.calibrate_gyro feeds it whole arrays as one block).

Gyro measurement model (the accelerometer's effect library idea, on the rate; deg/s):

    w_meas = M w_true + b0 + b_T (T - T_ref) + noise,    M = I + scale/cross-axis terms
    correct:  w_true = M^-1 (w_meas - b0 - b_T (T - T_ref))

Effects: 'bias' (b0), 'temp_bias' (b_T, deg/s/degC, fitted only when the holds span at least
min_temp_span_degC), 'scale' (diag M), 'cross_axis' (off-diagonal M).

Bias: every static hold is cut into window_s windows; the window means obey mean = b0 + b_T dT,
fitted per axis by least squares; sigma = sqrt(s^2 (A^T A)^-1) with s^2 the residual variance of
the window means (so hold-to-hold scatter, e.g. from bias instability, widens the uncertainty).

Scale/misalignment: for consecutive holds a, b, integrate the corrected rate from the middle of a
to the middle of b (accellog.calibrate.gyro.rotation, as accellog.navigate.strapdown) and compare
what gravity can check: the up vector of a, carried through dq_int, must land on the up vector of
b (residual dq_int^-1 up_a - up_b, deg; yaw about the vertical is free, so a hand-held operator's
turns do no harm). With reference='orientation' (known headings: a fixture, a vehicle) the whole
nominal change dq_nom = q_a^-1 q_b is compared instead: residual = rotation vector of
dq_nom^-1 dq_int (deg). M is found by nonlinear least squares (core.numeric.least_squares: scipy's
Levenberg-Marquardt with the exact complex-step Jacobian; a fit that does not converge is a
ModelError); parameters the rotations do not excite (e.g. x/y scale when the robot only turns
about z) are held at the identity and reported as undetermined (sigma NaN).
Covariance = s^2 (J^T J)^-1, s^2 = max(RSS/dof, s_min^2).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from accellog.calibrate.gyro.model import PARAM_NAMES, GyroCalibration
from accellog.calibrate.gyro.rotation import relative_rotations
from accellog.core.errors import InputError, ModelError
from accellog.core.notices import note
from accellog.core.numeric import least_squares
from accellog.core.rotations import quat_conjugate, quat_multiply, quat_to_rotvec, rotate_inverse
from accellog.core.session import PoseLabel

DEG_PER_RAD = 180.0 / np.pi
BIAS_WINDOW_S = 1.0
"""The bias's window length (s): each hold's window means are its observations."""
BIAS_TRIM_S = 0.2
"""Cut from both ends of a hold before it is windowed (s)."""


def hold_intervals(holds: Sequence[PoseLabel] | np.ndarray) -> np.ndarray:
    """(K,2) start/end times (s) from PoseLabels or an array of intervals."""
    if len(holds) and isinstance(holds[0], PoseLabel):
        return np.array([[h.start_s, h.end_s] for h in holds], float)
    return np.asarray(holds, float).reshape(-1, 2)


def bias_window_times(iv: np.ndarray, window_s: float, trim_s: float) -> list[np.ndarray]:
    """Edge times (s) of the whole window_s windows of every trimmed hold (one array per hold)."""
    out = []
    for lo, hi in iv:
        lo, hi = lo + trim_s, hi - trim_s
        n_win = int((hi - lo) // window_s)
        if n_win >= 1:
            out.append(lo + window_s * np.arange(n_win + 1))
    return out


def bias_fit(
    means, temps, has_temp, n_holds, t_ref_degC, window_s, min_temp_span_degC, temp_order: int = 1
) -> GyroCalibration:
    """Least squares mean = b0 + b_T dT (+ b_T2 dT^2 with temp_order=2), dT = T - T_ref, over the
    window means (module doc); the temperature terms only when the windows span min_temp_span_degC."""
    if len(means) < 2:
        raise InputError(
            f"static holds give fewer than 2 windows of {window_s} s: gyro bias cannot be estimated"
        )
    y, tt = means, temps
    use_temp = has_temp and np.isfinite(tt).all() and np.ptp(tt) >= min_temp_span_degC
    order = temp_order if use_temp else 0
    cols = [np.ones(len(y))] + [(tt - t_ref_degC) ** k for k in range(1, order + 1)]
    A = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    dof = max(len(y) - A.shape[1], 1)
    s2 = ((y - A @ coef) ** 2).sum(axis=0) / dof
    cov_unit = np.linalg.inv(A.T @ A)
    sig = np.sqrt(np.outer(np.diag(cov_unit), s2))
    cal = GyroCalibration(bias_dps=coef[0], bias_sigma_dps=sig[0], t_ref_degC=t_ref_degC, n_holds=n_holds)
    if order >= 1:
        cal.temp_bias_dps_per_degC = coef[1]
        cal.temp_bias_sigma_dps_per_degC = sig[1]
        cal.effects = ["bias", "temp_bias"]
    if order >= 2:
        cal.temp_bias2_dps_per_degC2 = coef[2]
        cal.temp_bias2_sigma_dps_per_degC2 = sig[2]
        cal.effects.append("temp_bias2")
    return cal


def screened_bias_fit(means, temps, has_temp, n_holds, t_ref_degC, window_s, min_span, temp_order, still_ref):
    """fit.bias_fit; with still_ref (stops of a run, not a lab's holds) first the turns out
    (still_windows), then once more without the windows more than ROBUST_CLIP robust sigmas (1.4826
    MAD per axis) off the fitted curve: a stop that still creeps at its ends."""
    if still_ref is None:
        return bias_fit(means, temps, has_temp, n_holds, t_ref_degC, window_s, min_span, temp_order)
    means, temps = still_windows(means, temps, has_temp, still_ref)
    cal = bias_fit(means, temps, has_temp, n_holds, t_ref_degC, window_s, min_span, temp_order)
    res = means - cal.bias_at(temps if "temp_bias" in cal.effects else None)
    mad = 1.4826 * np.median(np.abs(res - np.median(res, axis=0)), axis=0)
    keep = np.all(np.abs(res) <= ROBUST_CLIP * np.maximum(mad, 1e-9), axis=1)
    if keep.all() or keep.sum() < 3:
        return cal
    note(f"gyro: {int((~keep).sum())} of {keep.size} stop windows more than {ROBUST_CLIP:g} robust sigma off "
         "the bias curve: left out")  # fmt: skip
    return bias_fit(means[keep], temps[keep], has_temp, n_holds, t_ref_degC, window_s, min_span, temp_order)


STILL_TOL_DPS = 2.0
"""A window whose mean rate is further than this from the reference's bias (deg/s, any axis) is a
turn: an accelerometer-still interval of a robot turning in place (a yaw rate leaves the specific
force unchanged) is not a gyro stop. MPU-9250 zero-rate offsets move by less than this over months
(the aging a field calibration allows, calibrate.model.prior)."""
DATASHEET_TEMP_DPS_PER_DEGC = 0.24
"""PS-MPU-9250A Table 1 zero-rate output variation over temperature (+-30 deg/s over -40..85 degC):
the tolerance grows by this per degC away from the reference's T_ref when it has no temperature curve."""
ROBUST_CLIP = 4.0
"""Stop windows further than this many robust sigmas from the fitted bias curve are left out (_screened_fit)."""


def still_windows(means, temps, has_temp: bool, ref: GyroCalibration | None):
    """(means, temps) of the windows at rest by the reference gyro calibration (STILL_TOL_DPS; all of
    them without one); how many were turns is said in a note."""
    if ref is None or not len(means):
        return means, temps
    known = has_temp and np.isfinite(temps).all()
    expect = ref.bias_at(temps if known else None)
    tol = np.full(len(means), STILL_TOL_DPS)
    if known and not np.any(ref.temp_poly_dps):  # no curve: allow the datasheet's tempco
        tol = tol + DATASHEET_TEMP_DPS_PER_DEGC * np.abs(temps - ref.t_ref_degC)
    keep = np.all(np.abs(means - expect) <= tol[:, None], axis=1)
    if not keep.all():
        note(f"gyro: {int((~keep).sum())} of {keep.size} still windows turn (further from the prior's bias than "
             f"{STILL_TOL_DPS:g} deg/s, + {DATASHEET_TEMP_DPS_PER_DEGC:g}/degC off its T_ref without its temperature "
             "curve): left out of the bias")  # fmt: skip
    return means[keep], temps[keep]


def pooled_bias(windows, n_holds: int, *, t_ref_degC: float = 25.0, window_s: float = BIAS_WINDOW_S,
                min_temp_span_degC: float = 2.0, temp_order: int = 1,
                still_ref: GyroCalibration | None = None) -> GyroCalibration:  # fmt: skip
    """fit.bias_fit over the windows (stream.bias_windows) of several sessions of one sensor together: one
    temperature curve from all their temperatures (a warm-up and a cool-down, several days);
    still_ref: as stream.calibrate_blocks."""
    means = np.concatenate([w[0] for w in windows])
    temps = np.concatenate([w[1] for w in windows])
    has_temp = all(w[2] for w in windows)
    return screened_bias_fit(
        means, temps, has_temp, n_holds, t_ref_degC, window_s, min_temp_span_degC, temp_order, still_ref
    )


CLIP_NEAR = 0.98
"""A rate at or above this fraction of the gyro full scale on any axis counts as clipped."""


def clipped_in_moves(t_s: np.ndarray, gyro_dps: np.ndarray, mid_t: np.ndarray, full_scale_dps) -> np.ndarray:
    """Clipped samples (|rate| >= CLIP_NEAR full scale on some axis) in each move k, the span
    [mid_t[k], mid_t[k+1]) the rotation from hold k to hold k+1 integrates: (K-1,) counts."""
    n_moves = max(len(mid_t) - 1, 0)
    if not full_scale_dps or not n_moves:
        return np.zeros(n_moves, np.int64)
    w, lim = np.asarray(gyro_dps), CLIP_NEAR * float(full_scale_dps)
    hit = np.zeros(w.shape[0], bool)
    for k in range(3):  # booleans only: no (N,3) temporary
        hit |= (w[:, k] >= lim) | (w[:, k] <= -lim)
    move = np.searchsorted(mid_t, np.asarray(t_s)[hit], side="right") - 1
    return np.bincount(move[(move >= 0) & (move < n_moves)], minlength=n_moves)


def known_poses(poses: Sequence[PoseLabel], model: str, reference: str) -> list[PoseLabel]:
    """The poses the matrix fit rotates between (checks model and reference)."""
    if model not in ("scale", "full"):
        raise InputError(f"unknown gyro model {model!r}: use 'scale' or 'full'")
    if reference not in ("gravity", "orientation"):
        raise InputError(f"unknown gyro reference {reference!r}: use 'gravity' or 'orientation'")
    known = [p for p in poses if reference == "gravity" or p.q_sensor_to_world is not None]
    if len(known) < 2:
        raise InputError("fewer than 2 labelled poses with known orientation: gyro scale cannot be fitted")
    return known


def pose_times(known: list[PoseLabel]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Middle, end and start time (s) of every hold."""
    return (
        np.array([0.5 * (p.start_s + p.end_s) for p in known]),
        np.array([p.end_s for p in known]),
        np.array([p.start_s for p in known]),
    )


def _residuals(phi, c, at, known: list[PoseLabel], reference: str, rows: np.ndarray):
    """forward(m): the residual rows `rows` (..., R) of the rotations between consecutive holds for
    gyro matrices m ((3,3) or (P,3,3)); three rows a move (module doc)."""
    if reference == "orientation":
        qn = np.array([p.q_sensor_to_world for p in known], float)
        dq_nom_c = quat_conjugate(quat_multiply(quat_conjugate(qn[:-1]), qn[1:]))
    else:
        up = np.array([p.up_sensor for p in known], float)
        up /= np.linalg.norm(up, axis=1, keepdims=True)

    def forward(m: np.ndarray) -> np.ndarray:
        dq_int = relative_rotations(phi, c, at, m)
        if reference == "orientation":
            return (quat_to_rotvec(quat_multiply(dq_nom_c, dq_int)) * DEG_PER_RAD).reshape(
                (*dq_int.shape[:-2], -1)
            )[..., rows]
        # up_a (world-fixed) seen from the sensor at hold b: v_b = dq_int^-1 v_a; the difference of
        # unit vectors is the tilt error in rad for small errors (and, unlike a cross product,
        # it does not vanish for a vector pointing the opposite way)
        pred = rotate_inverse(dq_int, up[:-1])
        return ((pred - up[1:]) * DEG_PER_RAD).reshape((*dq_int.shape[:-2], -1))[..., rows]

    return forward


def fit_matrix(
    phi, c, at, known, base: GyroCalibration, model: str, floor_deg: float, reference: str, clipped=None
):
    """The scale ('scale': diag M) or scale + cross-axis ('full': all of M) fit of the rotations
    between the consecutive holds known (module doc) from their coarse block increments phi, c and
    the block index at of each hold middle (stream.py), on top of base's bias; returns a copy of base
    with matrix, matrix_sigma, undetermined and rotation_rms_deg filled in. floor_deg: smallest
    residual scatter assumed (deg); clipped: (K-1,) moves left out."""
    diag_idx = [0, 4, 8]
    free_all = diag_idx if model == "scale" else list(range(9))
    clipped = np.zeros(len(known) - 1, bool) if clipped is None else np.asarray(clipped, bool)
    if clipped.any() and 3 * int((~clipped).sum()) < len(free_all):  # too few moves left: bias only
        return dataclasses.replace(
            base, undetermined=[PARAM_NAMES[f] for f in free_all], clipped_moves=int(clipped.sum())
        )
    forward = _residuals(phi, c, at, known, reference, np.flatnonzero(np.repeat(~clipped, 3)))

    def matrix(p: np.ndarray, free: list[int]) -> np.ndarray:
        m = np.eye(3).ravel()
        m[free] = p
        return m.reshape(3, 3)

    def jacobian(p: np.ndarray, free: list[int]) -> np.ndarray:
        """d residuals / d M_free, all columns in one vectorised complex-step pass (exact to
        rounding: Im f(M + i h E_j) / h with h = 1e-30, no subtractive cancellation)."""
        h = 1e-30
        m = np.broadcast_to(matrix(p, free).astype(complex), (len(free), 3, 3)).reshape(len(free), 9).copy()
        m[np.arange(len(free)), free] += 1j * h
        return (forward(m.reshape(-1, 3, 3)).imag / h).T

    # which entries of M do the rotations excite? (sensitivity at M = I)
    p_init = np.eye(3).ravel()[free_all]
    j_init = jacobian(p_init, free_all)
    sens = np.linalg.norm(j_init, axis=0)
    # a 1 % error in M_ij must move some rotation by > 10 floor_deg-ish to be determinable
    free = [f for f, s in zip(free_all, sens, strict=True) if s * 0.01 > floor_deg]
    undetermined = [PARAM_NAMES[f] for f in free_all if f not in free]
    if not free:
        raise ModelError("the rotations between labelled poses are too small to determine any gyro scale")
    if j_init.shape[0] < len(free):
        raise ModelError(
            f"gyro {model} model is not determined by these rotations ({j_init.shape[0]} residuals for "
            f"{len(free)} parameters)"
        )
    fun, jac = lambda p: forward(matrix(p, free)), lambda p: jacobian(p, free)
    sol = least_squares(fun, np.eye(3).ravel()[free], what=f"gyro {model} fit", jac=jac, x_scale=0.01)
    r = sol.fun
    dof = r.size - len(free)
    s2 = max(float(r @ r) / dof, floor_deg**2) if dof > 0 else floor_deg**2
    jtj = sol.jac.T @ sol.jac
    if np.linalg.cond(jtj) > 1e12:
        raise ModelError(f"gyro {model} model is not determined by these rotations (rank deficient)")
    cov = s2 * np.linalg.inv(jtj)
    m = np.eye(3).ravel()
    m[free] = sol.x
    msig = np.full(9, np.nan)
    msig[free] = np.sqrt(np.diag(cov))
    offdiag_free = [f for f in free if f not in diag_idx]
    effects = [e for e in base.effects if e not in ("scale", "cross_axis")] + ["scale"]
    if offdiag_free:
        effects.append("cross_axis")
    return dataclasses.replace(
        base,
        matrix=m.reshape(3, 3),
        matrix_sigma=msig.reshape(3, 3),
        effects=effects,
        undetermined=undetermined,
        rotation_rms_deg=float(np.sqrt(np.mean(r**2))),
        clipped_moves=int(clipped.sum()),
    )
