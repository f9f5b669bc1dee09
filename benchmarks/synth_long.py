"""Long 1 kHz sessions with accel, gyro and temperature, synthesised in numpy (seconds, not hours).

Twelve labelled holds (the six faces twice, 24-position style if asked) with smooth rotations
between them about a fixed body axis (smootherstep angle profile, 3 s per move), as a user
records them. Accel = S f + b + noise, f = the world up vector seen in the sensor frame; gyro =
M w + b_g + b_T (T - 25) + noise; temperature ramps 30 -> 35 degC. Written with
accellog.store.writer.write_session in counts (int16 ranges), so read-back goes through the real
decoder. Used by bench_fit_speed / bench_diagnose / bench_scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accellog.core.protocol import six_position, twenty_four_position
from accellog.core.rotations import quat_conjugate, quat_from_rotvec, quat_multiply, rotate_inverse
from accellog.core.session import PoseLabel, Session, SessionMeta

RATE_HZ = 1000.0
ACC_LSB = 16384.0
GYR_LSB = 131.0
S_TRUE = np.array([[1.01, 0.004, -0.006], [0.003, 0.985, 0.008], [-0.005, 0.002, 1.02]])
B_TRUE = np.array([0.03, -0.02, 0.05])
M_TRUE = np.array([[1.02, 0.008, -0.012], [-0.006, 0.985, 0.01], [0.015, -0.007, 1.03]])
BG_TRUE = np.array([0.8, -1.2, 0.4])
BT_TRUE = np.array([0.02, -0.015, 0.03])
MOVE_S = 3.0


def _rotvec(q: np.ndarray) -> np.ndarray:
    q = q * (1.0 if q[0] >= 0 else -1.0)
    s = np.linalg.norm(q[1:])
    return q[1:] * (2 * np.arctan2(s, q[0]) / s if s > 1e-12 else 2.0)


def synth_session(
    duration_s: float, seed: int = 0, protocol: str = "six", rate_hz: float = RATE_HZ
) -> Session:
    """A labelled calibration session of duration_s at rate_hz (see module doc)."""
    specs = six_position() * 2 if protocol == "six" else twenty_four_position()
    k = len(specs)
    hold_s = duration_s / k - MOVE_S
    n = round(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    qs = np.array([p.q_sensor_to_world for p in specs], float)
    seg = np.minimum((t // (hold_s + MOVE_S)).astype(int), k - 1)
    u = np.clip((t - seg * (hold_s + MOVE_S) - hold_s) / MOVE_S, 0.0, 1.0)
    u[seg == k - 1] = 0.0
    nxt = np.minimum(seg + 1, k - 1)
    rv = np.array([_rotvec(quat_multiply(quat_conjugate(qs[i]), qs[min(i + 1, k - 1)])) for i in range(k)])
    s = u**3 * (10 - 15 * u + 6 * u**2)
    ds = 30 * u**2 * (1 - u) ** 2 / MOVE_S
    q = quat_multiply(qs[seg], quat_from_rotvec(s[:, None] * rv[seg]))
    del nxt
    f = rotate_inverse(q, np.array([0.0, 0.0, 1.0]))
    w_true = np.rad2deg(ds[:, None] * rv[seg])
    rng = np.random.default_rng(seed)
    temp = 30.0 + 5.0 * t / max(t[-1], 1.0)
    acc = f @ S_TRUE.T + B_TRUE + rng.normal(0, 0.003, (n, 3))
    gyr = w_true @ M_TRUE.T + BG_TRUE + np.multiply.outer(temp - 25.0, BT_TRUE) + rng.normal(0, 0.05, (n, 3))
    acc_c = np.clip(np.round(acc * ACC_LSB), -32768, 32767).astype(np.int32)
    gyr_c = np.clip(np.round(gyr * GYR_LSB), -32768, 32767).astype(np.int32)
    tmp_c = np.round((temp - 21.0) * 333.87).astype(np.int32)
    step = hold_s + MOVE_S
    poses = [PoseLabel(p.name, i * step, i * step + hold_s, p.up_sensor, p.q_sensor_to_world, i)
             for i, p in enumerate(specs)]  # fmt: skip
    meta = SessionMeta(source="emulator", accel_lsb_per_g=ACC_LSB, accel_range_g=2.0, sample_rate_hz=rate_hz,
                       gyro_lsb_per_dps=GYR_LSB, gyro_range_dps=250)  # fmt: skip
    return Session(meta=meta, t_s=t, sample_index=np.arange(n, dtype=np.int64), accel_g=acc_c / ACC_LSB,
                   accel_counts=acc_c, gyro_dps=gyr_c / GYR_LSB, gyro_counts=gyr_c, temp_counts=tmp_c,
                   temp_degC=tmp_c / 333.87 + 21.0, poses=poses)  # fmt: skip


def write_long(path: str | Path, duration_s: float, seed: int = 0, protocol: str = "six") -> Path:
    """synth_session written to path (MCAP); sessions over 1 h are written hour by hour (each hour
    its own 12 holds, seed + k), so generating a 4 h or 24 h file needs the memory of one hour."""
    from accellog.store.writer import SessionWriter, write_session

    path = Path(path)
    if duration_s <= 3600.0:
        return write_session(path, synth_session(duration_s, seed, protocol))
    pieces = int(np.ceil(duration_s / 3600.0))
    first = synth_session(1.0, seed, protocol)
    with SessionWriter(path, first.meta, flush_interval_s=np.inf, chunk_size=1 << 20) as w:
        for k in range(pieces):
            s = synth_session(min(3600.0, duration_s - 3600.0 * k), seed + k, protocol)
            t0, i0 = 3600.0 * k, round(3600.0 * k * s.meta.sample_rate_hz)
            t_ns = np.round((s.t_s + t0) * 1e9).astype(np.int64)
            for a in range(0, s.n, 1000):
                b = min(a + 1000, s.n)
                w.write_imu(i0 + a, t_ns[a:b], accel_counts=s.accel_counts[a:b],
                            gyro_counts=s.gyro_counts[a:b], temp_counts=s.temp_counts[a:b])  # fmt: skip
            for p in s.poses:
                w.write_pose(PoseLabel(p.name, p.start_s + t0, p.end_s + t0, p.up_sensor,
                                       p.q_sensor_to_world, p.hold_index + 12 * k))  # fmt: skip
            del s
    return path
