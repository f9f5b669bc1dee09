"""Evaluate calibrations on a static session in one pass over its blocks (the seed's Tables 4 and 5;
the formulas: navigate.evaluation).

The session arrives as a ``store.source.Source`` (an MCAP file chunk by chunk, anything else as one
block in memory); a second, cheaper pass first only when the orientation must be inferred from the mean
reading. Each block is cut (until_s, max_samples), checked (finite reading, increasing stamps),
calibrated (``evaluation.block_residual``, per calibration) and folded into
``stream_sums.ResidualSums``; the motion check runs on the 0.5 s windows of the raw reading
(``stream_motion.MotionCheck``: check_static's verdict in bounded memory). Memory is one block plus
a few window tables, whatever the session length; a session in memory also keeps its series (t, r,
d) for plots. A calibration that reads dT/dt (a centred 5 s slope) is applied to the whole session
in memory (``session_drivers.needs_whole_series``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.model.session_drivers import needs_whole_series
from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.navigate.blocks import checked_blocks, mean_reading
from accellog.navigate.evaluation import (
    AXES,
    EvalContext,
    Evaluation,
    block_residual,
    check_norm,
    driver_sums,
    eval_context,
    finish_evaluation,
    infer_up,
)
from accellog.navigate.integrate import DEFAULT_TIMES_S
from accellog.navigate.stream_motion import MotionCheck
from accellog.navigate.stream_sums import ResidualSums
from accellog.store.source import Source, open_source

BlockSink = Callable[[int, np.ndarray, np.ndarray, np.ndarray], None]
"""on_block(evaluation index, t_s, v_mps (n,3), d_m (n,3)) receives every block's integration."""


@dataclass(frozen=True)
class Target:
    """One evaluation of a session: a calibration (None: the raw reading) and how it is reported."""

    cal: Calibration | None = None
    label: str | None = None
    local_gravity_mps2: float | None = None
    """m/s^2; None: the calibration's (the session's for the raw reading)."""
    raw_truth_g: float = 1.0
    apply_drift: bool = True


def targets(
    cals: Sequence[Calibration], labels: Sequence[str] | None = None, include_raw: bool = True
) -> list[Target]:
    """The raw reading first when include_raw (gravity of the first calibration), then each calibration."""
    raw = (
        [Target(None, local_gravity_mps2=cals[0].local_gravity_mps2 if cals else None)] if include_raw else []
    )
    return raw + [Target(c, labels[i] if labels else None) for i, c in enumerate(cals)]


def evaluate_blocks(
    src: Source,
    tgts: Sequence[Target],
    *,
    up_sensor: Sequence[float] | None = None,
    times_s: Sequence[float] = DEFAULT_TIMES_S,
    until_s: float | None = None,
    max_samples: int | None = None,
    window_s: float = 2.0,
    check_moving: bool = True,
    on_block: BlockSink | None = None,
    sums_out: list[tuple[ResidualSums, dict]] | None = None,
) -> list[Evaluation]:
    """One Evaluation per target (module doc); sums_out receives each evaluation's (ResidualSums,
    its finish() statistics). on_block and sums_out see a pass again when the source reads a
    damaged file whole (store.source.Source.run): they must start afresh at its first block."""
    opts = dict(up_sensor=up_sensor, times_s=times_s, until_s=until_s, max_samples=max_samples,
                window_s=window_s, check_moving=check_moving, on_block=on_block, sums_out=sums_out)  # fmt: skip
    whole = needs_whole_series({d for t in tgts if t.cal is not None for d in t.cal.model.required_drivers})
    return src.run(lambda s: _evaluate(s, tgts, **opts), whole=whole)


def _evaluate(
    src: Source, tgts, *, up_sensor, times_s, until_s, max_samples, window_s, check_moving, on_block, sums_out
) -> list[Evaluation]:
    """evaluate_blocks' pass."""
    where, meta = src.where, src.meta
    notes: list[str] = []
    up = _up(src, up_sensor, notes)
    ctxs: list[EvalContext] = [
        eval_context(where, meta, x.cal, up, list(notes), label=x.label, local_gravity_mps2=x.local_gravity_mps2,
                     raw_truth_g=x.raw_truth_g, apply_drift=x.apply_drift)
        for x in tgts
    ]  # fmt: skip
    sums = [ResidualSums(times_s, window_s, drift=x.drift, keep_series=src.in_memory) for x in ctxs]
    drv: list[dict[str, float]] = [{} for _ in ctxs]
    motion = MotionCheck() if check_moving else None
    n, read_sum = 0, np.zeros(3)
    for b, block in checked_blocks(src, until_s, max_samples):
        n += b.n
        read_sum += b.accel_g.sum(axis=0)
        if motion is not None:
            motion.add(b.t_s, b.accel_g)
        for k, (x, acc) in enumerate(zip(ctxs, sums, strict=True)):
            v, d = acc.add(b.t_s, block_residual(x, block))
            for name, val in driver_sums(x.cal, block).items():
                drv[k][name] = drv[k].get(name, 0.0) + val
            if on_block is not None:
                on_block(k, b.t_s, v, d)
    if n < 10:
        raise InputError(f"static session has {n} samples (need >= 10)", where=where)
    check_norm(read_sum / n, where)
    if motion is not None:
        motion.check(1.0 / meta.accel_lsb_per_g if meta.accel_lsb_per_g else 0.0, where)
    stats = [acc.finish() for acc in sums]
    if sums_out is not None:
        sums_out.extend(zip(sums, stats, strict=True))
    return [
        finish_evaluation(x, st, read_sum / n, {k: v / n for k, v in dv.items()}, times_s)
        for x, st, dv in zip(ctxs, stats, drv, strict=True)
    ]


def _up(src: Source, up_sensor, notes: list[str]) -> np.ndarray:
    """The given up vector, the single pose label's, or the one inferred from the mean reading."""
    if up_sensor is not None:
        return np.asarray(up_sensor, float)
    if len(src.poses) == 1:
        return np.asarray(src.poses[0].up_sensor, float)
    if len(src.poses) > 1:
        raise InputError(
            f"evaluate needs a static session in one orientation; this one has {len(src.poses)} pose "
            "labels (use evaluate_poses / the pipeline's evaluate_poses stage)",
            where=src.where,
        )
    return infer_up(mean_reading(src), notes)


def evaluate(
    session: Session,
    cal: Calibration | None,
    *,
    label: str | None = None,
    up_sensor: Sequence[float] | None = None,
    local_gravity_mps2: float | None = None,
    raw_truth_g: float = 1.0,
    times_s: Sequence[float] = DEFAULT_TIMES_S,
    until_s: float | None = None,
    max_samples: int | None = None,
    window_s: float = 2.0,
    apply_drift: bool = True,
    check_moving: bool = True,
) -> Evaluation:
    """Evaluate `cal` (None: raw reading) on a static session in memory (evaluate_blocks on it as one
    block). until_s / max_samples cut the session first (the seed used the first 10,800 samples of
    its 300 s final test). A drift model is applied only when its orientation matches up_sensor."""
    tgt = Target(cal, label, local_gravity_mps2, raw_truth_g, apply_drift)
    evs = evaluate_blocks(open_source(session), [tgt], up_sensor=up_sensor, times_s=times_s, until_s=until_s,
                          max_samples=max_samples, window_s=window_s, check_moving=check_moving)  # fmt: skip
    return evs[0]


# multi-pose sessions: accellog.navigate.pose_evaluate (re-exported here for existing callers)
from accellog.navigate.pose_evaluate import PoseEvaluation, evaluate_pose_obs, evaluate_poses  # noqa: E402

__all__ = [
    "AXES",
    "Evaluation",
    "PoseEvaluation",
    "Target",
    "evaluate",
    "evaluate_blocks",
    "evaluate_pose_obs",
    "evaluate_poses",
    "targets",
]
