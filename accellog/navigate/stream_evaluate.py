"""`evaluate` and `integrate` of a static MCAP session chunk by chunk (memory bounded by one chunk group
plus a few window tables, whatever the session length).

The samples stream past once (``store.stream.iter_imu``; a second, cheaper pass first only when the
orientation must be inferred from the mean reading), the file's time-stamp check riding along when
asked (``check_times``: ``checked_pass`` reads the blocks a cut left, raises its error before the
pass's own, and returns None for damaged chunks); each block is cut (until_s, max_samples),
checked (finite), calibrated (``evaluate.block_residual``, per calibration) and folded into
``stream_sums.ResidualSums``, the same running sums the whole-session ``evaluate`` feeds with one
block, so both give the same Evaluation up to rounding (tests: JSON within 1e-9 relative). The
motion check runs on the 0.5 s windows of the raw reading (``stream_motion.MotionCheck``: the
windows spilled to a temporary file, the same verdict as ``check_static``). Not streamed: models that read dT/dt (a 5 s centred slope needs
samples on both sides of a block boundary): ``stream_evaluate`` returns None and the caller reads
the whole session.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.observe.stream_segment import TimestampCheck
from accellog.core.errors import DataIntegrityWarning, InputError
from accellog.core.session import PoseLabel, Session, SessionMeta
from accellog.navigate.evaluate import (
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
from accellog.store.stream import ImuBlock, iter_imu

STREAM_BLIND_DRIVERS = ("dtemp_degC_per_s",)
"""Drivers computed over a centred span of samples: models reading them take the whole-session path."""

T = TypeVar("T")
BlockSink = Callable[[int, np.ndarray, np.ndarray, np.ndarray], None]
"""on_block(evaluation index, t_s, v_mps (n,3), d_m (n,3)) receives every block's integration."""


def can_stream_cals(cals: Sequence[Calibration]) -> bool:
    """False when a calibration's model needs a driver that is not pointwise (STREAM_BLIND_DRIVERS)."""
    return not any(d in c.model.required_drivers for c in cals for d in STREAM_BLIND_DRIVERS)


def _cut_blocks(
    path: str | Path, until_s: float | None, max_samples: int | None, source: _Source | None = None
) -> Iterator[ImuBlock]:
    """The file's blocks (from source when given) with t <= until_s and at most max_samples samples
    (evaluate's _slice)."""
    n = 0
    own = source is None
    with contextlib.closing(iter_imu(path)) if own else contextlib.nullcontext(source) as blocks:
        for b in blocks:
            k = b.n
            if until_s is not None:
                k = min(k, int(np.searchsorted(b.t_s, until_s, side="right")))
            if max_samples is not None:
                k = min(k, int(max_samples) - n)
            if k > 0:
                n += k
                yield b if k == b.n else ImuBlock(
                    b.meta, b.t_s[:k], b.sample_index[:k], b.accel_g[:k],
                    None if b.gyro_dps is None else b.gyro_dps[:k],
                    None if b.temp_degC is None else b.temp_degC[:k],
                )  # fmt: skip
            if k < b.n:
                return


class _Source:
    """The file's blocks read once, each block's stamps fed to a TimestampCheck on the way; drain()
    feeds the blocks a pass did not need (after a cut or an error)."""

    def __init__(self, path: str | Path, check: TimestampCheck) -> None:
        self.blocks = iter_imu(path)
        self.check = check
        self.failed: Exception | None = None  # the reader's own refusal of the file

    def __iter__(self) -> Iterator[ImuBlock]:
        while True:
            try:
                b = next(self.blocks)
            except StopIteration:
                return
            except Exception as e:
                self.failed = e
                raise
            self.check.add(b.t_s)
            yield b

    def drain(self) -> None:
        for _ in self:
            pass
        self.blocks.close()


def checked_pass(path: str | Path, run: Callable[[_Source], T]) -> T | None:
    """run(source) with the file's time-stamp check (stream_segment.stream_check_timestamps) made in
    the same pass: the reader's own refusal first, then the check's error, as when it ran before,
    then run's InputError; None for a file with damaged chunks (DataIntegrityWarning: the
    whole-session reader says what it skips)."""
    check = TimestampCheck()
    src = _Source(path, check)
    out, err = None, None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            out = run(src)
        except InputError as e:
            err = e
        if src.failed is not None:  # the reader refused the file: its error, as the check pass raised it
            raise src.failed
        src.drain()
    if any(issubclass(w.category, DataIntegrityWarning) for w in caught):
        return None
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    check.finish(path)
    if err is not None:
        raise err
    return out


def _mean_reading(path: str | Path, source: _Source | None = None) -> np.ndarray:
    """nanmean of every accel sample of the file (g): the first pass when the orientation is inferred."""
    s = np.zeros(3)
    c = np.zeros(3)
    for b in iter_imu(path) if source is None else source:
        ok = np.isfinite(b.accel_g)
        s += np.where(ok, b.accel_g, 0.0).sum(axis=0)
        c += ok.sum(axis=0)
    return s / np.maximum(c, 1)


def _up(
    path, poses: list[PoseLabel], up_sensor, notes: list[str], source: _Source | None = None
) -> np.ndarray:
    if up_sensor is not None:
        return np.asarray(up_sensor, float)
    if len(poses) == 1:
        return np.asarray(poses[0].up_sensor, float)
    if len(poses) > 1:
        raise InputError(
            f"evaluate needs a static session in one orientation; this one has {len(poses)} pose "
            "labels (use evaluate_poses / the pipeline's evaluate_poses stage)",
            where=str(path),
        )
    return infer_up(_mean_reading(path, source), notes)


def stream_evaluate(
    path: str | Path,
    meta: SessionMeta,
    poses: list[PoseLabel],
    cals: Sequence[Calibration],
    *,
    labels: Sequence[str] | None = None,
    include_raw: bool = True,
    up_sensor: Sequence[float] | None = None,
    times_s: Sequence[float] = DEFAULT_TIMES_S,
    until_s: float | None = None,
    max_samples: int | None = None,
    window_s: float = 2.0,
    check_moving: bool = True,
    on_block: BlockSink | None = None,
    sums_out: list[tuple[ResidualSums, dict]] | None = None,
    check_times: bool = False,
) -> list[Evaluation] | None:
    """run_evaluate(read_session(path), cals, ...) in one pass over the file's chunks (module doc):
    the raw reading first when include_raw (gravity of the first calibration), then each
    calibration. None when a model reads a driver that does not stream (STREAM_BLIND_DRIVERS).
    sums_out receives each evaluation's (ResidualSums, its finish() statistics). check_times: the
    file's time-stamp check runs in the same pass (checked_pass: its error first; None also for a
    file with damaged chunks) instead of in a pass of its own before (open_streamed's)."""
    if not can_stream_cals(cals):
        return None
    opts = dict(labels=labels, include_raw=include_raw, up_sensor=up_sensor, times_s=times_s,
                until_s=until_s, max_samples=max_samples, window_s=window_s,
                check_moving=check_moving, on_block=on_block, sums_out=sums_out)  # fmt: skip
    if not check_times:
        return _evaluate(path, meta, poses, cals, None, **opts)
    return checked_pass(path, lambda src: _evaluate(path, meta, poses, cals, src, **opts))


def _evaluate(
    path, meta, poses, cals, source: _Source | None, *, labels, include_raw, up_sensor, times_s, until_s,
    max_samples, window_s, check_moving, on_block, sums_out,
) -> list[Evaluation]:  # fmt: skip
    """stream_evaluate's pass (over source when given; an inferred orientation reads it first)."""
    where = str(path)
    notes: list[str] = []
    up = _up(path, poses, up_sensor, notes, source)
    if up_sensor is None and not poses:
        source = None  # the orientation pass read the file (and fed the check): the sums read it again
    ctxs: list[EvalContext] = []
    if include_raw:
        g = cals[0].local_gravity_mps2 if cals else None
        ctxs.append(eval_context(where, meta, None, up, list(notes), local_gravity_mps2=g))
    for i, c in enumerate(cals):
        ctxs.append(eval_context(where, meta, c, up, list(notes), label=labels[i] if labels else None))
    sums = [ResidualSums(times_s, window_s, drift=x.drift) for x in ctxs]
    drv: list[dict[str, float]] = [{} for _ in ctxs]
    motion = MotionCheck() if check_moving else None
    n, read_sum = 0, np.zeros(3)
    for b, block in checked_blocks(path, meta, poses, until_s, max_samples, source):
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


def checked_blocks(
    path, meta, poses, until_s: float | None, max_samples: int | None, source: _Source | None = None
) -> Iterator[tuple]:
    """(ImuBlock, the block as a Session) of every cut block whose accel is finite and whose
    stamps are finite and strictly increasing across blocks (else one InputError line)."""
    where = str(path)
    n, t_prev = 0, np.nan
    for b in _cut_blocks(path, until_s, max_samples, source):
        if not np.isfinite(b.accel_g).all():
            i = int(np.argmax(~np.isfinite(b.accel_g).all(axis=1)))
            raise InputError(f"accel is NaN/inf at t = {b.t_s[i]:.3f} s", where=where)
        _check_step(b, n, t_prev, where)
        t_prev = float(b.t_s[-1])
        n += b.n
        yield b, Session(meta=meta, t_s=b.t_s, sample_index=b.sample_index, accel_g=b.accel_g,
                         temp_degC=b.temp_degC, poses=poses, path=where)  # fmt: skip


def _check_step(b: ImuBlock, n_before: int, t_prev: float, where: str) -> None:
    """integrate.check_time across blocks: finite, strictly increasing stamps (same message)."""
    t = b.t_s
    if not np.all(np.isfinite(t)):
        raise InputError("timestamps contain NaN or infinite values", where=where)
    tt = t if n_before == 0 else np.concatenate([[t_prev], t])
    bad = np.diff(tt) <= 0
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(
            f"timestamps not strictly increasing at sample {n_before - (n_before > 0) + i + 1} "
            f"(t = {tt[i + 1]:.6f} s): they must increase",
            where=where,
        )
