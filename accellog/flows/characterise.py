"""`accellog noise`: stream a long static session through the Allan accumulator and fit its noise terms.

MCAP sessions are read chunk by chunk (``store.stream``), so memory stays bounded whatever the length;
CSV / capstone / imucal files go through the importers (they are small). Accelerometer columns are
analysed in m/s^2 (g0 = 9.80665), gyro columns in rad/s. Besides the fit (``calibrate.noise_model``):

- the lowest fitted tau is 1 + ``TAU_MIN_FACTOR`` (tau_int - 1) samples, tau_int the integrated
  autocorrelation time of the first 8192 samples (1 for white samples): the DLPF correlates neighbouring
  samples, which bends the ADEV below the white-noise line by an amount ~ (tau_int - 1) / m (first-order
  DLPF at 1 kHz, tau_int = 7.8: 2.5 % low at m = 128, 1.7 % at 256, < 0.5 % beyond 700);
- quantisation is flagged (and Q fitted) where the sample sigma is below 2 LSB;
- temperature-driven stretches: 60 s windows whose die temperature changes faster than
  ``TEMP_RATE_FLAG_DEGC_PER_MIN`` (the long-tau ADEV there may be thermal, not random walk);
- gaps in the sample index and uneven timestamps (ADEV assumes a uniform rate) are noted.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from accellog.calibrate.noise.allan import AllanAccumulator
from accellog.calibrate.noise.noise_model import NoiseModel, SensorNoise, TempSegment, fit_axis
from accellog.calibrate.observe.hold_noise import integrated_autocorr_time
from accellog.core.errors import InputError
from accellog.core.session import Session, SessionMeta
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.importers.ros2 import is_ros2_bag
from accellog.store.stream import ImuBlock, closed_after, iter_imu, read_labels

TAU_MIN_FACTOR = 100.0
TEMP_WINDOW_S = 60.0
TEMP_RATE_FLAG_DEGC_PER_MIN = 0.05
QUANT_FLAG_LSB = 2.0
_AXES = ("x", "y", "z")


def _session_chunks(s: Session, size: int = 1 << 18) -> Iterator[ImuBlock]:
    for i in range(0, s.n, size):
        sl = slice(i, i + size)
        yield ImuBlock(
            s.meta,
            s.t_s[sl],
            s.sample_index[sl],
            s.accel_g[sl],
            None if s.gyro_dps is None else s.gyro_dps[sl],
            None if s.temp_degC is None else s.temp_degC[sl],
        )


def _open(path: Path) -> tuple[SessionMeta, Iterator[ImuBlock]]:
    if path.suffix.lower() == ".mcap" and not is_ros2_bag(path):
        return read_labels(path)[0], iter_imu(path)
    from accellog.flows.stages import load_input

    x = load_input(path)
    if not isinstance(x, Session):
        raise InputError(
            "noise needs a recorded session (samples), not a table of pose means", where=str(path)
        )
    return x.meta, _session_chunks(x)


class _Stream:
    """Everything accumulated over the chunks besides the Allan sums."""

    def __init__(self) -> None:
        self.n = 0
        self.t_first = self.t_last = math.nan
        self.last_index: int | None = None
        self.gaps = 0
        self.temp_sum: dict[int, float] = {}
        self.temp_n: dict[int, int] = {}

    def add(self, c: ImuBlock) -> None:
        if self.n == 0:
            self.t_first = float(c.t_s[0])
        self.t_last = float(c.t_s[-1])
        idx = c.sample_index
        self.gaps += int(np.count_nonzero(np.diff(idx) > 1))
        if self.last_index is not None and idx[0] - self.last_index > 1:
            self.gaps += 1
        self.last_index = int(idx[-1])
        self.n += c.t_s.shape[0]
        if c.temp_degC is not None:
            w = np.floor(c.t_s / TEMP_WINDOW_S).astype(np.int64)
            ws, inv = np.unique(w, return_inverse=True)
            sums, cnt = np.bincount(inv, c.temp_degC), np.bincount(inv)
            for k, s_, n_ in zip(ws.tolist(), sums.tolist(), cnt.tolist(), strict=True):
                self.temp_sum[k] = self.temp_sum.get(k, 0.0) + s_
                self.temp_n[k] = self.temp_n.get(k, 0) + n_

    def temp_segments(self) -> tuple[tuple[float, float] | None, list[TempSegment]]:
        if not self.temp_n:
            return None, []
        ks = np.array(sorted(self.temp_n))
        T = np.array([self.temp_sum[k] / self.temp_n[k] for k in ks.tolist()])
        rate = np.gradient(T, ks * TEMP_WINDOW_S) * 60.0 if T.size > 1 else np.zeros(1)
        hot = np.abs(rate) > TEMP_RATE_FLAG_DEGC_PER_MIN
        segs: list[TempSegment] = []
        i = 0
        while i < hot.size:
            if not hot[i]:
                i += 1
                continue
            j = i
            while j + 1 < hot.size and hot[j + 1]:
                j += 1
            r = float(rate[i : j + 1][np.argmax(np.abs(rate[i : j + 1]))])
            segs.append(TempSegment(float(ks[i] * TEMP_WINDOW_S), float((ks[j] + 1) * TEMP_WINDOW_S), r))
            i = j + 1
        return (float(T.min()), float(T.max())), segs


def _rate_hz(meta: SessionMeta, c: ImuBlock, notes: list[str]) -> float:
    dt = np.diff(c.t_s)
    if dt.size == 0:
        raise InputError("too few samples for an Allan deviation")
    med = float(np.median(dt))
    if med <= 0:
        raise InputError("timestamps do not increase")
    jitter = float(np.std(dt) / med)
    if jitter > 0.01:
        notes.append(
            f"uneven timestamps (dt sigma {100 * jitter:.0f} % of the median {1e3 * med:.2f} ms): the "
            "Allan deviation assumes a uniform rate; taus are sample counts times the median dt"
        )
    if meta.sample_rate_hz and meta.source in ("emulator", "hardware"):
        return float(meta.sample_rate_hz)
    return 1.0 / med


def characterise_noise(path: str | os.PathLike) -> NoiseModel:
    """Noise model of a static session file (.mcap streamed; .csv via the importers)."""
    path = Path(path)
    if not path.exists():
        raise InputError("no such file", where=str(path))
    meta, chunks = _open(path)
    notes: list[str] = []
    stream = _Stream()
    acc: AllanAccumulator | None = None
    first: ImuBlock | None = None
    has_gyro = False
    with closed_after(chunks):
        for c in chunks:
            if c.t_s.shape[0] == 0:
                continue
            if acc is None:
                first = c
                rate = _rate_hz(meta, c, notes)
                has_gyro = c.gyro_dps is not None
                acc = AllanAccumulator(rate, 6 if has_gyro else 3)
            stream.add(c)
            cols = [c.accel_g * STANDARD_GRAVITY_MPS2]
            if has_gyro:
                if c.gyro_dps is None:
                    raise InputError("gyro samples stop part-way through the session", where=str(path))
                cols.append(np.deg2rad(c.gyro_dps))
            acc.add(np.concatenate(cols, axis=1))
    if acc is None or first is None or stream.n < 64:
        raise InputError(f"too few samples ({stream.n}) for an Allan deviation (need >= 64)", where=str(path))
    curve = acc.curve()
    tau_min = _tau_min_s(first, acc.tau0)
    temp_range, segs = stream.temp_segments()
    if stream.gaps:
        notes.append(f"{stream.gaps} gaps in the sample index: analysed as if the samples were contiguous")
    if segs:
        notes.append(
            f"{len(segs)} temperature-driven stretch(es) (|dT/dt| > {TEMP_RATE_FLAG_DEGC_PER_MIN} degC/min): "
            "long-tau ADEV there may be thermal bias drift, not random walk"
        )
    sensors = []
    for name, col0, lsb, unit in (
        ("accel", 0, meta.accel_lsb_per_g, "m/s^2"),
        ("gyro", 3, meta.gyro_lsb_per_dps, "rad/s"),
    ):
        if name == "gyro" and not has_gyro:
            continue
        k = STANDARD_GRAVITY_MPS2 if name == "accel" else math.pi / 180.0
        quantum = k / lsb if lsb else None
        series = first.accel_g if name == "accel" else first.gyro_dps
        assert series is not None  # the gyro is skipped above when the session has none
        sigma0 = np.std((series * k)[:8192], axis=0)
        coarse = bool(quantum is not None and np.any(sigma0 < QUANT_FLAG_LSB * quantum))
        axes = [fit_axis(curve, col0 + i, _AXES[i], unit, tau_min, fit_quantisation=coarse) for i in range(3)]
        flag = coarse or any(a.quantisation.detected for a in axes)
        sensors.append(SensorNoise(name, axes, quantum, flag))
    return NoiseModel(
        source=str(path),
        duration_s=stream.t_last - stream.t_first,
        rate_hz=acc.rate_hz,
        n_samples=stream.n,
        accel=sensors[0],
        gyro=sensors[1] if len(sensors) > 1 else None,
        temp_range_degC=temp_range,
        temp_segments=segs,
        gaps=stream.gaps,
        notes=notes,
    )


def _tau_min_s(first: ImuBlock, tau0: float) -> float:
    """1 + TAU_MIN_FACTOR (tau_int - 1) samples, tau_int of the linearly detrended first 8192 samples."""
    cols = [first.accel_g[:8192]] + ([first.gyro_dps[:8192]] if first.gyro_dps is not None else [])
    x = np.concatenate(cols, axis=1)
    t = np.arange(x.shape[0], dtype=float)
    if x.shape[0] > 2:
        x = x - _linfit(t, x)
    tau_int = float(np.max(integrated_autocorr_time(x))) if x.shape[0] > 16 else 1.0
    return tau_min_samples(tau_int) * tau0


def tau_min_samples(tau_int: float) -> float:
    """Shortest averaging factor fitted for samples of integrated autocorrelation time tau_int."""
    return 1.0 + TAU_MIN_FACTOR * max(tau_int - 1.0, 0.0)


def _linfit(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    A = np.stack([np.ones_like(t), t], axis=1)
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)
    return A @ coef
