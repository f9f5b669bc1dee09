"""`drift` of a static MCAP session chunk by chunk: the drift model of ``navigate.drift`` in memory
bounded independently of the session length, equal to the whole-session fit up to rounding.

Two passes over the file's blocks (``stream_evaluate.checked_blocks``, the same cut and checks):

1. ``stream_evaluate`` of the calibration (without a drift model), which also makes the file's
   time-stamp check (``check_times``: the pass of its own ``open_streamed`` made before #11, its
   error first) and infers the orientation when not given: residual r per block into
   ``stream_sums.ResidualSums`` (n, std, autocorrelation time tau, v and d by the carried
   trapezoid rule, the samples around each reported time) and everything else `evaluate`
   reports; its d(t) into ``drift.DriftSums`` (normal equations of d = q0 + q1 t + 1/2 q2 t^2 on
   a scaled time) and the sample intervals into ``drift.IntervalCount`` (their exact median);
2. the same d again into ``drift.DriftRefine`` (one step of iterative refinement on a centred
   basis, which needs the span of pass 1: q to least-squares accuracy, and the residual RMS), and
   the times of the decimated covariance grid (``drift.grid_index``, which needs n).

The evaluation of the calibration + drift model, which ``run_drift`` reports, is pass 1's: the
residual does not depend on the drift model, and the drifted displacement at the reported times
is the model applied to the two samples around each (``Integrator.series_at``), the same
interpolation an evaluation of cal + drift makes (a third pass until #11 merged it).

The whole-session ``fit_drift`` runs the same sums on one block, so both agree to rounding.

The median interval is exact: IntervalCount keeps every distinct float value of dt = t_{i+1} - t_i
with its count (np.unique per block, merged), so the median is read from the same multiset
np.median(np.diff(t)) sorts. Its memory is the number of distinct intervals, which the clock
bounds (timestamps are integer nanoseconds: a few values per nanosecond step and binade of t), not
the number of samples.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.calfile.drift_model import DriftModel
from accellog.core.session import PoseLabel, SessionMeta
from accellog.navigate.drift import DriftRefine, DriftSums, IntervalCount, grid_index, noise_cov_q
from accellog.navigate.evaluate import Evaluation, block_residual, drift_result, eval_context
from accellog.navigate.stream_evaluate import can_stream_cals, checked_blocks, stream_evaluate
from accellog.navigate.stream_sums import Integrator


def _residual_blocks(path, meta, poses, cal, up, until_s, max_samples) -> Iterator[tuple]:
    """(t_s, resid_mps2) of every block after the checks of stream_evaluate (finite, increasing)."""
    ctx = eval_context(str(path), meta, cal, up, [], apply_drift=False)
    for b, block in checked_blocks(path, meta, poses, until_s, max_samples):
        yield b.t_s, block_residual(ctx, block)


def _second_pass(blocks: Iterator[tuple], refine: DriftRefine, grid: np.ndarray) -> np.ndarray:
    """Refinement sums of the same d (stream_sums.Integrator) and the times at the grid indices."""
    integ = Integrator(())
    n, tg = 0, []
    for t, r in blocks:
        _v, d, _ = integ.add(t, r)
        refine.add(t, d)
        tg.append(t[grid[(grid >= n) & (grid < n + t.size)] - n])
        n += t.size
    return np.concatenate(tg)


def stream_drift(
    path: str | Path,
    meta: SessionMeta,
    poses: list[PoseLabel],
    cal: Calibration,
    *,
    up_sensor: Sequence[float] | None = None,
    until_s: float | None = None,
    max_samples: int | None = None,
) -> tuple[Calibration, DriftModel, Evaluation] | None:
    """(cal + drift, drift, evaluation of cal + drift on the session) of an MCAP session chunk by chunk
    (module doc): drift_from_session then evaluate, without the whole session in memory. None when
    the calibration's model reads a driver that does not stream (stream_evaluate.STREAM_BLIND_DRIVERS)."""
    if not can_stream_cals([cal]):
        return None
    cal0 = dataclasses.replace(cal, drift=None)  # pass 1 evaluates the calibration alone
    fit, dt = DriftSums(), IntervalCount()

    def first_pass(_k: int, t: np.ndarray, _v: np.ndarray, d: np.ndarray) -> None:
        fit.add(t, d)
        dt.add(t)

    sums: list = []
    evs = stream_evaluate(path, meta, poses, [cal0], include_raw=False, up_sensor=up_sensor, until_s=until_s,
                          max_samples=max_samples, on_block=first_pass, sums_out=sums, check_times=True)  # fmt: skip
    if evs is None:  # damaged chunks: the whole-session path
        return None
    ev, (acc, st) = evs[0], sums[0]
    up = ev.up_sensor  # inferred in pass 1 when not given (its note is in ev.notes)
    refine = DriftRefine(fit.solve(), st["t_first"], st["t_last"])
    tg = _second_pass(_residual_blocks(path, meta, poses, cal, up, until_s, max_samples), refine,
                      grid_index(st["n"]))  # fmt: skip
    q, rms = refine.solve()
    var_density = st["std"] ** 2 * st["tau"] * dt.median()  # (m/s^2)^2 s
    dm = DriftModel(
        q=q.T.copy(),
        cov=noise_cov_q(tg, var_density, n_grid=None),
        fit_duration_s=float(st["t_last"] - st["t_first"]),
        up_sensor=tuple(float(v) for v in up),
        source=str(path),
        rms_residual_m=rms,
    )
    at, end = acc.integ.series_at(dm.apply)
    drift_result(ev, dm, {"disp_drift_at": at, "disp_drift_end": end}, {})
    return dataclasses.replace(cal, drift=dm, path=None), dm, ev
