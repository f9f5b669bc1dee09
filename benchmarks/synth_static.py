"""Long static 1 kHz sessions (one '+z' hold, as `evaluate` / `integrate` / `drift` take them), written
hour by hour so a 4 h or 24 h file needs the memory of one hour. Accel = S up + b + noise (the
synth_long chip), gyro = bias + noise, temperature ramps 30 -> 35 degC per hour; counts in int16
ranges, read back through the real decoder. Used by bench_scale's evaluate / integrate modes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from synth_long import ACC_LSB, B_TRUE, BG_TRUE, GYR_LSB, RATE_HZ, S_TRUE

from accellog.core.session import PoseLabel, SessionMeta


def write_static(path: str | Path, duration_s: float, seed: int = 0) -> Path:
    """A labelled '+z' static session of duration_s at 1 kHz (module doc)."""
    from accellog.store.writer import SessionWriter

    path = Path(path)
    meta = SessionMeta(source="emulator", accel_lsb_per_g=ACC_LSB, accel_range_g=2.0, sample_rate_hz=RATE_HZ,
                       gyro_lsb_per_dps=GYR_LSB, gyro_range_dps=250)  # fmt: skip
    n_all = round(duration_s * RATE_HZ)
    rng = np.random.default_rng(seed)
    acc0 = S_TRUE @ np.array([0.0, 0.0, 1.0]) + B_TRUE
    with SessionWriter(path, meta, flush_interval_s=np.inf, chunk_size=1 << 20) as w:
        for i0 in range(0, n_all, round(3600 * RATE_HZ)):
            n = min(round(3600 * RATE_HZ), n_all - i0)
            t = (i0 + np.arange(n)) / RATE_HZ
            acc = acc0 + rng.normal(0, 0.003, (n, 3))
            gyr = BG_TRUE + rng.normal(0, 0.05, (n, 3))
            temp = 30.0 + 5.0 * (t % 3600.0) / 3600.0
            acc_c = np.round(acc * ACC_LSB).astype(np.int32)
            gyr_c = np.round(gyr * GYR_LSB).astype(np.int32)
            tmp_c = np.round((temp - 21.0) * 333.87).astype(np.int32)
            t_ns = np.round(t * 1e9).astype(np.int64)
            for a in range(0, n, 1000):
                b = min(a + 1000, n)
                w.write_imu(i0 + a, t_ns[a:b], accel_counts=acc_c[a:b], gyro_counts=gyr_c[a:b],
                            temp_counts=tmp_c[a:b])  # fmt: skip
        w.write_pose(PoseLabel("+z", 0.0, n_all / RATE_HZ, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0), 0))
    return path
