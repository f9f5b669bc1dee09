"""Emulated static sessions with known noise terms (white, bias instability, random walk) for noise tests.

Samples come from the emulator's physical model (``SensorModel.sample``: DLPF-shaped white noise,
flicker and random-walk bias, quantisation to counts); ``write_static_mcap`` stores them through the real
``SessionWriter`` in FIFO-sized batches, as the recorder does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
from accellog.core.protocol import parse_protocol
from accellog.core.session import SessionMeta
from accellog.store.writer import SessionWriter

ACCEL_LSB, GYRO_LSB = 16384.0, 131.0
BW_HZ = 41.0  # DLPF -3 dB bandwidth of accel and gyro (emulated)


def static_model(
    duration_s: float,
    seed: int,
    *,
    accel_density_g=300e-6,
    accel_bi_g=0.0,
    accel_rw=0.0,
    gyro_density_dps=0.01,
    gyro_bi_dps=0.0,
    gyro_rw=0.0,
) -> SensorModel:
    motion = PoseSequenceMotion(parse_protocol("+z", duration_s + 10.0), move_s=1.0, start_delay_s=0.0)
    accel = AccelErrors(
        noise_density_g_per_rtHz=accel_density_g,
        bias_instability_g=accel_bi_g,
        random_walk_g_per_s_rtHz=accel_rw,
    )
    gyro = GyroErrors(
        noise_density_dps_per_rtHz=gyro_density_dps,
        bias_instability_dps=gyro_bi_dps,
        random_walk_dps_per_s_rtHz=gyro_rw,
    )
    return SensorModel(motion, accel=accel, gyro=gyro, seed=seed)


def static_samples(model: SensorModel, rate_hz: float, i0: int, i1: int):
    """(t_s, accel_counts, gyro_counts, temp_counts) of samples i0..i1 at rate_hz."""
    idx = np.arange(i0, i1, dtype=np.int64)
    t = idx / rate_hz
    blk = model.sample(
        t,
        accel_lsb_per_g=ACCEL_LSB,
        gyro_lsb_per_dps=GYRO_LSB,
        odr_hz=rate_hz,
        accel_bandwidth_hz=BW_HZ,
        gyro_bandwidth_hz=BW_HZ,
        index=idx,
    )
    return t, blk.accel_counts, blk.gyro_counts, blk.temp_counts


def write_static_mcap(
    path: Path, model: SensorModel, duration_s: float, rate_hz: float, batch: int = 200
) -> Path:
    """A static session of duration_s at rate_hz written in FIFO batches of ``batch`` samples."""
    meta = SessionMeta(
        source="emulator",
        accel_range_g=2,
        gyro_range_dps=250,
        accel_lsb_per_g=ACCEL_LSB,
        gyro_lsb_per_dps=GYRO_LSB,
        sample_rate_hz=rate_hz,
        protocol="+z",
    )
    n = round(duration_s * rate_hz)
    step = 1 << 16
    with SessionWriter(path, meta) as w:
        for i0 in range(0, n, step):
            t, ac, gc, tc = static_samples(model, rate_hz, i0, min(n, i0 + step))
            t_ns = np.round(t * 1e9).astype(np.int64)
            for j in range(0, t.shape[0], batch):
                sl = slice(j, j + batch)
                w.write_imu(i0 + j, t_ns[sl], accel_counts=ac[sl], gyro_counts=gc[sl], temp_counts=tc[sl])
    return path
