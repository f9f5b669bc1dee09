"""Gyro calibration of a session held in memory: its arrays fed as one block to the one
implementation (accellog.calibrate.gyro.stream.calibrate_blocks; the model and the fits:
accellog.calibrate.gyro.fit); the gyro calibration of one or several session Sources
(``calibrate_source``, ``calibrate_sources``: the fit stage's, the source itself is the pass
factory) and what the fit flow reads off a session for it (the gyro full scale, the first pass
fed along the observation pass, the warning for the moves left out).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from accellog.calibrate.gyro.fit import BIAS_TRIM_S, BIAS_WINDOW_S, CLIP_NEAR, pooled_bias
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.gyro.stream import (
    Blocks,
    FirstPass,
    RateBlock,
    bias_windows,
    calibrate_blocks,
    first_pass,
)
from accellog.core.errors import AccellogError, InputError, ModelError
from accellog.core.notices import note
from accellog.core.session import PoseLabel

if TYPE_CHECKING:
    from accellog.store.source import Source


def calibrate_gyro(
    t_s: np.ndarray,
    gyro_dps: np.ndarray,
    poses: Sequence[PoseLabel],
    temp_degC: np.ndarray | None = None,
    *,
    model: str = "full",
    reference: str = "gravity",
    full_scale_dps: float | None = None,
    **bias_kw,
) -> GyroCalibration:
    """The bias from the poses' holds (fit_gyro_bias), then the matrix (fit_gyro_matrix, see there
    for reference and full_scale_dps) when there are >= 2 holds to rotate between (with known
    orientations for reference='orientation'). t_s (N,) s, gyro_dps (N,3), temp_degC (N,) or None."""
    blocks = _one_block(t_s, gyro_dps, temp_degC)
    cal = calibrate_blocks(
        blocks, poses, model=model, reference=reference, full_scale_dps=full_scale_dps, **bias_kw
    )
    return _given(cal)


def fit_gyro_bias(
    t_s: np.ndarray,
    gyro_dps: np.ndarray,
    holds: Sequence[PoseLabel] | np.ndarray,
    temp_degC: np.ndarray | None = None,
    *,
    t_ref_degC: float = 25.0,
    window_s: float = BIAS_WINDOW_S,
    min_temp_span_degC: float = 2.0,
    trim_s: float = BIAS_TRIM_S,
) -> GyroCalibration:
    """Bias (and temp_bias when the holds span >= min_temp_span_degC) from static holds (gyro.fit
    module doc). holds: PoseLabels or (K,2) start/end times (s); trim_s is cut from both ends of
    each hold."""
    cal = calibrate_blocks(
        _one_block(t_s, gyro_dps, temp_degC),
        holds,
        t_ref_degC=t_ref_degC,
        window_s=window_s,
        min_temp_span_degC=min_temp_span_degC,
        trim_s=trim_s,
        rotations=False,
    )
    return _given(cal)


def fit_gyro_matrix(
    t_s: np.ndarray,
    gyro_dps: np.ndarray,
    poses: Sequence[PoseLabel],
    base: GyroCalibration,
    temp_degC: np.ndarray | None = None,
    *,
    model: str = "full",
    floor_deg: float = 0.05,
    reference: str = "gravity",
    full_scale_dps: float | None = None,
) -> GyroCalibration:
    """Scale ('scale': diag M) or scale + cross-axis ('full': all of M) from rotations between
    consecutive labelled poses (gyro.fit module doc), on top of base's bias. Returns a copy of base
    with matrix, matrix_sigma, undetermined and rotation_rms_deg filled in.

    reference: 'gravity' (default) compares only what gravity sees: the up vector of hold a,
    carried through the integrated rotation, must land on the up vector of hold b (residual
    dq_int^-1 up_a - up_b, deg; rotations about the vertical are not used, so an operator who
    turns the sensor freely between holds does no harm); 'orientation' compares the whole
    nominal rotation q_a^-1 q_b (for fixtures or vehicles whose heading is known).
    floor_deg: smallest residual scatter assumed (deg, nominal pose orientation error).
    full_scale_dps: the gyro full scale (gyro_full_scale_dps): moves whose rate clips are left out
    (GyroCalibration.clipped_moves); None: every move is used.
    """
    cal = calibrate_blocks(
        _one_block(t_s, gyro_dps, temp_degC),
        poses,
        model=model,
        floor_deg=floor_deg,
        reference=reference,
        full_scale_dps=full_scale_dps,
        base=base,
    )
    return _given(cal)


def _one_block(t_s, gyro_dps, temp_degC) -> Blocks:
    """The arrays as the one block of a session."""
    w = None if gyro_dps is None else np.asarray(gyro_dps, float)
    temp = None if temp_degC is None else np.asarray(temp_degC, float)
    blk = RateBlock(np.asarray(t_s, float), w, temp)
    return lambda: (blk,)


def _given(cal: GyroCalibration | None) -> GyroCalibration:
    """calibrate_blocks' result on arrays: None only when no rate was given."""
    if cal is None:
        raise InputError("no gyro rate: the gyro cannot be calibrated")
    return cal


def gyro_full_scale_dps(meta) -> float | None:
    """The configured gyro full scale (deg/s) of a SessionMeta: its range, else 32768 counts / LSB per
    deg/s; None when neither is recorded."""
    if meta.gyro_range_dps:
        return float(meta.gyro_range_dps)
    return 32768.0 / meta.gyro_lsb_per_dps if meta.gyro_lsb_per_dps else None


def temp_order_of(terms: Sequence[str]) -> int:
    """The gyro bias's order in temperature: the accelerometer model's (2 with temp_bias2, else 1)."""
    return 2 if "temp_bias2" in terms else 1


def first_pass_of(src: Source) -> FirstPass | None:
    """An unfed first pass of calibrate_source's calibrate_blocks (segment.observe_riding's rider),
    or None (fewer than 2 holds, or no pass to plan)."""
    if len(src.poses) < 2:
        return None
    try:
        return first_pass(src.poses, full_scale_dps=gyro_full_scale_dps(src.meta))
    except AccellogError:
        return None


def calibrate_source(
    src: Source,
    *,
    temp_order: int = 1,
    first: FirstPass | None = None,
    still_ref: GyroCalibration | None = None,
) -> GyroCalibration | None:
    """Gyro bias (and scale/misalignment where the holds' orientations are known) from a session's
    holds and the moves between them (one pass more; first: the first pass already fed), stored
    next to the accelerometer's; None when the session has no gyro or < 2 holds. Rotations that do
    not determine the matrix leave the bias alone (said). still_ref: the prior's gyro (turns among
    the stops left out: gyro.stream.still_windows)."""
    if len(src.poses) < 2:
        return None
    fs = gyro_full_scale_dps(src.meta)
    try:  # in Source.run: a session not read yet (observations given) has its stamps checked here
        return src.run(
            lambda s: calibrate_blocks(
                s, s.poses, full_scale_dps=fs, first=first, temp_order=temp_order, still_ref=still_ref
            )
        )
    except ModelError as exc:  # e.g. rotations that do not determine M: said, and the bias kept
        try:
            cal = src.run(
                lambda s: calibrate_blocks(
                    s, s.poses, rotations=False, temp_order=temp_order, still_ref=still_ref
                )
            )
        except AccellogError:
            cal = None
        note(f"gyro scale/misalignment not calibrated: {exc}" + ("; the bias is" if cal else ""))
        return cal
    except AccellogError:
        return None


def calibrate_sources(
    srcs: Sequence[Source], *, temp_order: int = 1, still_ref: GyroCalibration | None = None
) -> GyroCalibration | None:
    """The gyro calibration of several sessions of one sensor: the bias and its temperature curve
    from the holds (stops) of all of them (fit.pooled_bias), the matrix from the rotations of the
    session with the most holds; one session: calibrate_source."""
    if len(srcs) == 1:
        return calibrate_source(srcs[0], temp_order=temp_order, still_ref=still_ref)
    try:
        wins = [w for src in srcs if len(src.poses) and (w := src.run(lambda s: bias_windows(s, s.poses)))]
        if not wins:
            return None
        n = sum(len(s.poses) for s in srcs)
        base = pooled_bias(wins, n, temp_order=temp_order, still_ref=still_ref)
        best = max(srcs, key=lambda s: len(s.poses))
        if len(best.poses) < 2:
            return base
        fs = gyro_full_scale_dps(best.meta)
        note(f"gyro: bias from the holds of all {len(srcs)} sessions, scale/misalignment from {best.where}")
        return best.run(lambda s: calibrate_blocks(s, s.poses, full_scale_dps=fs, base=base))
    except ModelError as exc:
        note(f"gyro not calibrated: {exc}")
        return None
    except AccellogError:
        return None


def warn_clipped_moves(fit, cal) -> None:
    """When cal.gyro left moves out (clipped_moves), a warning of the fit `fit` (a FitResult: printed
    by `fit`) and of the calibration `cal` (its fit section: written into the file)."""
    g = cal.gyro
    if g is None or not g.clipped_moves:
        return
    msg = (
        f"gyro: {g.clipped_moves} of {max(g.n_holds - 1, g.clipped_moves)} moves between holds reach "
        f"{CLIP_NEAR:.0%} of the gyro full scale (clipped): left out of the gyro scale/misalignment fit"
    )
    fit.warnings.append(msg)
    cal.fit = dataclasses.replace(cal.fit, warnings=(*(cal.fit.warnings or ()), msg))
