"""`drift` of a static MCAP session chunk by chunk: the drift model of ``navigate.drift`` in memory
bounded independently of the session length, equal to the whole-session fit up to rounding.

Three passes over the file's blocks (``stream_evaluate.checked_blocks``, the same cut and checks),
after the time-stamp check of ``open_streamed``:

1. residual r (m/s^2) per block (``evaluate.block_residual``) into ``stream_sums.ResidualSums``
   (n, std, autocorrelation time tau, v and d by the carried trapezoid rule); d(t) into
   ``drift.DriftSums`` (normal equations of d = q0 + q1 t + 1/2 q2 t^2 on a scaled time) and the
   sample intervals into ``drift.IntervalCount`` (their exact median);
2. the same d again into ``drift.DriftRefine`` (one step of iterative refinement on a centred
   basis, which needs the span of pass 1: q to least-squares accuracy, and the residual RMS), and
   the times of the decimated covariance grid (``drift.grid_index``, which needs n);
3. ``stream_evaluate`` of the calibration + drift model: the fit session after the model, which
   ``run_drift`` reports.

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

from accellog.calibrate.calibration import Calibration
from accellog.calibrate.drift_model import DriftModel
from accellog.core.errors import InputError
from accellog.core.session import PoseLabel, SessionMeta
from accellog.navigate.drift import DriftRefine, DriftSums, IntervalCount, _noise_cov_q, grid_index
from accellog.navigate.evaluate import Evaluation, block_residual, eval_context
from accellog.navigate.stream_evaluate import _up, can_stream_cals, checked_blocks, stream_evaluate
from accellog.navigate.stream_sums import Integrator, ResidualSums


def _residual_blocks(path, meta, poses, cal, up, until_s, max_samples) -> Iterator[tuple]:
    """(t_s, resid_mps2) of every block after the checks of stream_evaluate (finite, increasing)."""
    where = str(path)
    ctx = eval_context(where, meta, cal, up, [], apply_drift=False)
    n = 0
    for b, block in checked_blocks(path, meta, poses, until_s, max_samples):
        n += b.n
        yield b.t_s, block_residual(ctx, block)
    if n < 10:
        raise InputError(f"static session has {n} samples (need >= 10)", where=where)


def _first_pass(blocks: Iterator[tuple]) -> tuple[dict, DriftSums, IntervalCount]:
    """Residual statistics, normal equations and intervals (module doc, pass 1)."""
    sums, fit, dt = ResidualSums((), 2.0), DriftSums(), IntervalCount()
    for t, r in blocks:
        _v, d = sums.add(t, r)
        fit.add(t, d)
        dt.add(t)
    return sums.finish(), fit, dt


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
    notes: list[str] = []
    up = _up(path, poses, up_sensor, notes)
    args = (path, meta, poses, cal, up, until_s, max_samples)
    st, fit, dt = _first_pass(_residual_blocks(*args))
    refine = DriftRefine(fit.solve(), st["t_first"], st["t_last"])
    tg = _second_pass(_residual_blocks(*args), refine, grid_index(st["n"]))
    q, rms = refine.solve()
    var_density = st["std"] ** 2 * st["tau"] * dt.median()  # (m/s^2)^2 s
    dm = DriftModel(
        q=q.T.copy(),
        cov=_noise_cov_q(tg, var_density, n_grid=None),
        fit_duration_s=float(st["t_last"] - st["t_first"]),
        up_sensor=tuple(float(v) for v in up),
        source=str(path),
        rms_residual_m=rms,
    )
    cal_d = dataclasses.replace(cal, drift=dm, path=None)
    ev = stream_evaluate(path, meta, poses, [cal_d], include_raw=False, up_sensor=up, until_s=until_s,
                         max_samples=max_samples)[0]  # fmt: skip
    ev.notes[:0] = notes  # the inferred orientation, as the whole-session evaluate notes it
    return cal_d, dm, ev
