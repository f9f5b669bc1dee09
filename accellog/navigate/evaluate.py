"""Evaluate calibrations on a session (the seed's Tables 4 and 5): one entry, ``evaluate_source``,
over a ``store.source.Source``; the variant follows from what the session holds:

- several pose labels: hold by hold, window by window (``PoseEvaluation``: per pose, pass, window);
- one pose label, or none and the reading is one static hold: against gravity in one pass over the
  blocks (``Evaluation``; ``evaluate_blocks``);
- no pose labels and the reading is not one static hold (it moves, or |mean| is not ~1 g): hand-held,
  the gravity-norm residual |f| - g on the detected static intervals (``HandheldEvaluation``).

The one-hold pass: the source arrives chunk by chunk (a finished MCAP) or as one block in memory; a
second, cheaper pass first only when the orientation must be inferred from the mean reading. Each
block is cut (until_s, max_samples), checked (finite reading, increasing stamps), calibrated
(``evaluation.block_residual``, per calibration) and folded into ``stream_sums.ResidualSums``; the
motion check runs on the 0.5 s windows of the raw reading (``calibrate.observe.motion.MotionCheck``). Memory is
one block plus a few window tables; a session in memory also keeps its series (t, r, d) for plots. A
calibration that reads dT/dt (a centred 5 s slope) is applied to the whole session in memory
(``session_drivers.needs_whole_series``). Formulas: navigate.evaluation (one hold) and
navigate.window_evaluation (window by window).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.model.fit import obs_drivers
from accellog.calibrate.model.session_drivers import needs_whole_series
from accellog.calibrate.observe.detect import static_sweep, with_labels
from accellog.calibrate.observe.motion import MotionCheck
from accellog.calibrate.observe.segment import observations
from accellog.core.errors import InputError
from accellog.core.session import ObsTable, Session
from accellog.navigate.blocks import checked_blocks, first_mean
from accellog.navigate.evaluation import (
    AXES,
    EvalContext,
    Evaluation,
    block_residual,
    driver_sums,
    eval_context,
    finish_evaluation,
    infer_up,
    norm_refusal,
)
from accellog.navigate.integrate import DEFAULT_TIMES_S
from accellog.navigate.stream_sums import ResidualSums
from accellog.navigate.window_evaluation import (
    HandheldEvaluation,
    PoseEvaluation,
    flag_lines,
    passes,
    trends,
)
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
    evs, refusal = _one_hold(src, tgts, **opts)
    if refusal is not None:
        raise refusal
    return evs


def _one_hold(src: Source, tgts: Sequence[Target], **opts) -> tuple[list[Evaluation], InputError | None]:
    """evaluate_blocks' pass over the source (whole when a calibration reads dT/dt): the evaluations,
    or none and the refusal when the reading is not one static hold (|mean| not ~1 g, or it moves)."""
    whole = needs_whole_series({d for t in tgts if t.cal is not None for d in t.cal.model.required_drivers})
    return src.run(lambda s: _evaluate(s, tgts, **opts), whole=whole)


def _evaluate(
    src: Source, tgts, *, up_sensor, times_s, until_s, max_samples, window_s, check_moving, on_block, sums_out,
    mean_g: np.ndarray | None = None,
) -> tuple[list[Evaluation], InputError | None]:  # fmt: skip
    """_one_hold's pass (the refusal checked in the seed's order: samples, |mean|, motion). An
    unlabelled session is evaluated with the face of its first block's mean reading (mean_g: of the
    whole session, known) and again, a second pass, only when the pass's own mean has another face."""
    where, meta = src.where, src.meta
    notes: list[str] = []
    guessed = up_sensor is None and not src.poses and mean_g is None
    up = _up(src, up_sensor, notes, lambda: first_mean(src) if mean_g is None else mean_g)
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
    if guessed and not np.array_equal(infer_up(read_sum / n, []), up):
        opts = dict(up_sensor=None, times_s=times_s, until_s=until_s, max_samples=max_samples, window_s=window_s,
                    check_moving=check_moving, on_block=on_block, sums_out=sums_out, mean_g=read_sum / n)  # fmt: skip
        return _evaluate(src, tgts, **opts)
    refusal = norm_refusal(read_sum / n, where)
    if motion is not None:  # the spill is closed either way
        moving = motion.refusal(1.0 / meta.accel_lsb_per_g if meta.accel_lsb_per_g else 0.0, where)
        refusal = moving if refusal is None else refusal
    if refusal is not None:
        return [], refusal
    stats = [acc.finish() for acc in sums]
    if sums_out is not None:
        sums_out.extend(zip(sums, stats, strict=True))
    return [
        finish_evaluation(x, st, read_sum / n, {k: v / n for k, v in dv.items()}, times_s)
        for x, st, dv in zip(ctxs, stats, drv, strict=True)
    ], None


def _up(src: Source, up_sensor, notes: list[str], mean_of: Callable[[], np.ndarray]) -> np.ndarray:
    """The given up vector, the single pose label's, or the one inferred from the mean reading mean_of()."""
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
    return infer_up(mean_of(), notes)


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


def evaluate_poses(
    session: Session,
    cal: Calibration | None,
    *,
    window_s: float = 2.0,
    trim_s: float = 0.5,
    at_s: float = 60.0,
    local_gravity_mps2: float | None = None,
) -> PoseEvaluation:
    """Residual corrected - truth_g * up per window of every labelled hold; chi2 against sigma_g.

    cal=None: the raw reading against up (truth 1, unit g_local: the seed's "No calibration")."""
    obs = observations(session, window_s=window_s, trim_s=trim_s)
    g = float(local_gravity_mps2 or session.meta.local_gravity_mps2)
    return _pose_windows(obs, cal, at_s=at_s, raw_gravity_mps2=g, session=session.path or session.meta.source)


def _pose_windows(
    obs: ObsTable, cal: Calibration | None, *, at_s: float, raw_gravity_mps2: float, session: str
) -> PoseEvaluation:
    """The PoseEvaluation of cal (None: the raw reading) from the session's observation table."""
    if cal is None:
        r = np.asarray(obs.meas_g, float) - np.asarray(obs.up_sensor, float)
        unit = float(raw_gravity_mps2)
    else:
        model = cal.model
        drv = {k: v for k, v in obs_drivers(obs).items() if k in model.required_drivers}
        f = model.correct(cal.theta, obs.meas_g, drv)
        truth = model.truth_g(cal.theta, obs.up_sensor, obs.q_sensor_to_world, cal.truth_g)
        r = f - truth
        unit = cal.mps2_per_unit
    k = len(obs.pose_names)
    mean = np.zeros((k, 3))
    sem = np.zeros((k, 3))
    for i in range(k):  # poses, not samples
        m = obs.pose_id == i
        w = 1.0 / obs.sigma_g[m] ** 2
        mean[i] = np.sum(r[m] * w, axis=0) / np.sum(w, axis=0)
        sem[i] = 1.0 / np.sqrt(np.sum(w, axis=0))
    label = cal.model_spec.get("name", "calibrated") if cal is not None else "no calibration"
    rows, trend_rows = passes(obs, r), trends(obs, r)
    return PoseEvaluation(
        label=label,
        session=session,
        pose_names=list(obs.pose_names),
        mean_resid_g=mean,
        sem_g=sem,
        rms_g=float(np.sqrt(np.mean(r**2))),
        chi2=float(np.sum((r / obs.sigma_g) ** 2)),
        dof=int(r.size),
        mps2_per_unit=float(unit),
        mean_resid_all_g=r.mean(axis=0),
        at_s=float(at_s),
        passes=rows,
        trends=trend_rows,
        flags=flag_lines(rows, trend_rows, label) if cal is not None else [],  # raw: a baseline
        window_resid_g=r,
    )


def _detected_windows(session: Session, *, window_s: float = 1.0) -> tuple[ObsTable, list[dict]] | None:
    """Static intervals of an unlabelled session (imu_tk's detector, threshold by the most distinct
    orientations) cut into 2 s windows: (observations, interval dicts), or None when fewer than 2
    distinct orientations are found (or the session is shorter than the detector's window)."""
    rate = (session.n - 1) / max(float(session.t_s[-1] - session.t_s[0]), 1e-12)
    window_samples = max(3, round(window_s * rate) | 1)
    if session.n < window_samples:
        return None
    labels, _ = static_sweep(session, window_samples=window_samples, min_poses=2)
    if labels is None:
        return None
    obs = observations(with_labels(session, labels), window_s=2.0, trim_s=0.0)
    ivs = [
        {"start_s": p.start_s, "end_s": p.end_s, "up_sensor": [float(x) for x in p.up_sensor]} for p in labels
    ]
    return obs, ivs


def _norm_windows(
    obs: ObsTable, intervals: list[dict], cal: Calibration | None, *, session: str, raw_gravity_mps2: float
) -> HandheldEvaluation:
    """The gravity-norm residual of cal (None: the raw reading against 1 g) on the detected windows."""
    meas = np.asarray(obs.meas_g, float)
    if cal is None:
        f, g, unit, label = meas, 1.0, float(raw_gravity_mps2), "no calibration"
    else:
        drv = {k: v for k, v in obs_drivers(obs).items() if k in cal.model.required_drivers}
        f = cal.model.correct(cal.theta, meas, drv)
        g, unit, label = cal.truth_g, cal.mps2_per_unit, cal.model_spec.get("name", "calibrated")
    norm = np.linalg.norm(f, axis=1)
    sigma = np.sqrt(np.sum((f / norm[:, None] * np.asarray(obs.sigma_g, float)) ** 2, axis=1))
    return HandheldEvaluation(
        label, session, intervals, norm - g, sigma, np.asarray(obs.pose_id), float(unit)
    )


@dataclass
class SessionEvaluation:
    """evaluate_source's result: the raw reading first, then each calibration, in the one list of
    the variant the session called for (module doc); obs: the windows judged window by window."""

    single: list[Evaluation] = field(default_factory=list)
    poses: list[PoseEvaluation] = field(default_factory=list)
    handheld: list[HandheldEvaluation] = field(default_factory=list)
    obs: ObsTable | None = None

    @property
    def kind(self) -> str:
        return "poses" if self.poses else "handheld" if self.handheld else "single"


def evaluate_source(
    src: Source,
    cals: Sequence[Calibration],
    labels: Sequence[str] | None = None,
    *,
    until_s: float | None = None,
    max_samples: int | None = None,
    at_s: float = 60.0,
) -> SessionEvaluation:
    """The raw reading and each calibration on the session, the variant chosen from what it holds
    (module doc; gravity of the raw reading: the first calibration's). labels name the calibrations
    of the one-hold and hand-held rows. until_s / max_samples cut a single hold (refused with
    several labelled holds). The one-hold refusal is raised when a labelled session is not one
    static hold, or an unlabelled one shows fewer than 2 distinct static orientations."""
    if len(src.poses) > 1:
        if until_s is not None or max_samples is not None:
            raise InputError(
                f"--until-s/--max-samples cut a single static hold; this session has {len(src.poses)} "
                "labelled holds",
                where=src.where,
            )
        obs = observations(src)
        g = cals[0].local_gravity_mps2 if cals else src.meta.local_gravity_mps2
        evs = [_pose_windows(obs, c, at_s=at_s, raw_gravity_mps2=g, session=src.where) for c in [None, *cals]]
        return SessionEvaluation(poses=evs, obs=obs)
    single, refusal = _one_hold(
        src, targets(cals, labels), up_sensor=None, times_s=DEFAULT_TIMES_S, until_s=until_s,
        max_samples=max_samples, window_s=2.0, check_moving=True, on_block=None, sums_out=None,
    )  # fmt: skip
    if refusal is None:
        return SessionEvaluation(single=single)
    if src.poses:
        raise refusal
    data = src.whole()
    found = _detected_windows(data)
    if found is None:
        raise refusal
    obs, intervals = found
    g = cals[0].local_gravity_mps2 if cals else data.meta.local_gravity_mps2
    name = data.path or data.meta.source
    hh = [_norm_windows(obs, intervals, c, session=name, raw_gravity_mps2=g) for c in [None, *cals]]
    for h, lab in zip(hh[1:], labels or [], strict=False):
        h.label = lab
    return SessionEvaluation(handheld=hh, obs=obs)


__all__ = [
    "AXES",
    "Evaluation",
    "HandheldEvaluation",
    "PoseEvaluation",
    "SessionEvaluation",
    "Target",
    "evaluate",
    "evaluate_blocks",
    "evaluate_poses",
    "evaluate_source",
    "targets",
]
