"""MCAP read-back speed: read_session of a 1 kHz session vs the same arrays from raw .npy files.

Usage: python benchmarks/bench_readback.py [--minutes 60] [--repeat 3]

Simulated static recording (seeded): accel/gyro/temp counts with noise, per-FIFO host times. Layouts:
- write_session: 500-sample messages, 1 MiB zstd chunks (imports, simulations);
- recorder: 36-sample messages (one FIFO read each), 64 KiB chunks flushed every 0.5 s (SessionWriter
  defaults, crash-safe).
Baselines: np.load of t_ns, accel/gyro/temp counts, host time (.npy, uncompressed), alone and followed
by the same conversions read_session does (counts -> g, deg/s, degC; ns -> s). Ratios are measured
side by side in one run, best of --repeat (warm page cache).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from accellog.mcap_io import SessionWriter, read_session, write_session
from accellog.session import Session, SessionMeta
from accellog.units import temp_counts_to_degC

NS = 1_000_000_000


def simulate(n: int, seed: int = 0) -> Session:
    rng = np.random.default_rng(seed)
    t_ns = np.arange(n, dtype=np.int64) * 1_000_000
    up = np.array([0.02, -0.01, 1.0])
    ac = np.round((up + rng.normal(0, 0.004, (n, 3))) * 16384).astype(np.int32)
    gc = np.round(rng.normal(0, 0.05, (n, 3)) * 131 + [30, -12, 5]).astype(np.int32)
    tc = np.round((30 + 5 * (1 - np.exp(-np.arange(n) / 6e5)) - 21) * 333.87 + rng.normal(0, 3, n)).astype(
        np.int32
    )
    host_ns = (np.arange(n) // 36 + 1) * 36_000_000 + 250_000
    meta = SessionMeta(
        source="emulator", accel_lsb_per_g=16384.0, gyro_lsb_per_dps=131.0, sample_rate_hz=1000.0
    )
    return Session(
        meta=meta,
        t_s=t_ns / NS,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=ac / 16384.0,
        accel_counts=ac,
        gyro_dps=gc / 131.0,
        gyro_counts=gc,
        temp_degC=temp_counts_to_degC(tc.astype(np.float64)),
        temp_counts=tc,
        host_time_s=host_ns / NS,
    )


def write_recorder_layout(path: Path, s: Session) -> None:
    t_ns = np.round(s.t_s * NS).astype(np.int64)
    host = np.round(s.host_time_s * NS).astype(np.int64)
    with SessionWriter(path, s.meta) as w:
        for i in range(0, s.n, 36):
            j = min(i + 36, s.n)
            w.write_imu(
                i, t_ns[i:j], s.accel_counts[i:j], s.gyro_counts[i:j], s.temp_counts[i:j], int(host[j - 1])
            )


def best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    n = int(args.minutes * 60 * 1000)
    s = simulate(n)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        names = ("t_ns", "accel_counts", "gyro_counts", "temp_counts", "host_ns")
        arrays = (
            np.round(s.t_s * NS).astype(np.int64),
            s.accel_counts,
            s.gyro_counts,
            s.temp_counts,
            np.round(s.host_time_s * NS).astype(np.int64),
        )
        for name, a in zip(names, arrays, strict=True):
            np.save(d / f"{name}.npy", a)
        npy_bytes = sum((d / f"{nm}.npy").stat().st_size for nm in names)

        t0 = time.perf_counter()
        write_session(d / "ws.mcap", s)
        t_write_ws = time.perf_counter() - t0
        t0 = time.perf_counter()
        write_recorder_layout(d / "rec.mcap", s)
        t_write_rec = time.perf_counter() - t0

        def raw_load():
            return [np.load(d / f"{nm}.npy") for nm in names]

        def raw_convert():
            t, ac, gc, tc, h = raw_load()
            return t / NS, ac / 16384.0, gc / 131.0, temp_counts_to_degC(tc.astype(np.float64)), h / NS

        r = read_session(d / "ws.mcap")
        assert np.array_equal(r.accel_counts, s.accel_counts) and np.array_equal(r.host_time_s, s.host_time_s)
        r = read_session(d / "rec.mcap")
        assert np.array_equal(r.accel_counts, s.accel_counts) and np.array_equal(r.host_time_s, s.host_time_s)
        del r

        t_raw = best(raw_load, args.repeat)
        t_rawc = best(raw_convert, args.repeat)
        t_ws = best(lambda: read_session(d / "ws.mcap"), args.repeat)
        t_rec = best(lambda: read_session(d / "rec.mcap"), args.repeat)
        size_ws = (d / "ws.mcap").stat().st_size
        size_rec = (d / "rec.mcap").stat().st_size

    mb = 1e6
    print(
        f"read-back of {args.minutes:g} min at 1 kHz = {n:,} samples (accel+gyro+temp counts, t_ns, host time)"
    )
    print(f"{'variant':<42} {'read s':>8} {'vs npy':>8} {'vs npy+conv':>12} {'size MB':>9} {'write s':>8}")
    rows = [
        ("raw .npy (np.load only)", t_raw, npy_bytes, float("nan")),
        ("raw .npy + same conversions", t_rawc, npy_bytes, float("nan")),
        ("MCAP write_session (500/msg, 1 MiB zstd)", t_ws, size_ws, t_write_ws),
        ("MCAP recorder (36/msg, 64 KiB, 0.5 s flush)", t_rec, size_rec, t_write_rec),
    ]
    for name, t, size, tw in rows:
        print(f"{name:<42} {t:8.3f} {t / t_raw:8.2f} {t / t_rawc:12.2f} {size / mb:9.1f} {tw:8.2f}")


if __name__ == "__main__":
    main()
