"""Replay of a one-hour 1 kHz session to an .rrd vs the pipeline's own work on the same session.

Goal (issues #4, #11): logging adds under 50 % to the same replay without logging (the right
baseline; `evaluate`, one batch, is shown for context only).

    baseline: read_session + model3 correct + double trapezoid (accellog.navigate.evaluate, one batch)
    replay:   accellog.flows.replay.replay(..., speed=max) without a recording (online, batch by batch)
    replay + .rrd: the same, logging raw + calibrated accel, temperature and tracks to a file

The session (3.6 M samples, int16 counts, seeded) is synthesised once with accellog.store.writer.write_session.
Run: python benchmarks/bench_replay.py [--minutes 60]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

from accellog.calibrate.calibration import load_calibration
from accellog.core.session import PoseLabel, Session, SessionMeta
from accellog.flows.replay import replay
from accellog.flows.stages import run_fit
from accellog.navigate.evaluate import evaluate
from accellog.present.rrd.recording import RunRecording
from accellog.store.reader import read_session
from accellog.store.writer import write_session

LSB = 16384.0


def _session(f_g: np.ndarray, rate: float, rng, poses=()) -> Session:
    S = np.array([[1.01, 0.004, -0.003], [0.002, 0.995, 0.006], [-0.005, 0.001, 1.02]])
    counts = np.round((f_g @ S.T + [0.03, -0.02, 0.05] + rng.normal(0, 0.002, f_g.shape)) * LSB).astype(
        np.int32
    )
    n = counts.shape[0]
    temp = np.round((30.0 + np.linspace(0, 2.0, n) - 21.0) * 333.87).astype(np.int32)
    meta = SessionMeta(source="emulator", accel_lsb_per_g=LSB, accel_range_g=2.0, sample_rate_hz=rate)
    return Session(
        meta=meta,
        t_s=np.arange(n) / rate,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=counts / LSB,
        accel_counts=counts,
        temp_counts=temp,
        temp_degC=temp / 333.87 + 21.0,
        poses=list(poses),
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        ups = [(0, 0, 1), (0, 0, -1), (0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0)]
        per = 2000
        f = np.concatenate([np.tile(np.array(u, float), (per, 1)) for u in ups])
        poses = [PoseLabel(str(k), k * 2 + 0.1, (k + 1) * 2 - 0.1, u, None, k) for k, u in enumerate(ups)]
        write_session(d / "cal.mcap", _session(f, 1000.0, rng, poses))
        run_fit(d / "cal.mcap", "model3", gravity="seed").cal.save(d / "model3.json")
        n = int(args.minutes * 60 * 1000)
        t0 = time.perf_counter()
        write_session(
            d / "hour.mcap", _session(np.tile([0.0, 0.0, 1.0], (n, 1)), 1000.0, rng), batch_size=1000
        )
        t_write = time.perf_counter() - t0
        size_mb = (d / "hour.mcap").stat().st_size / 1e6

        def baseline() -> None:
            s = read_session(d / "hour.mcap")
            evaluate(s, load_calibration(d / "model3.json"), up_sensor=(0, 0, 1), check_moving=False)

        def replay_only() -> None:
            replay(d / "hour.mcap", cals=[d / "model3.json"], speed=None, up_sensor="+z")

        def replay_rrd() -> None:
            rec = RunRecording(f"save:{d / 'hour.rrd'}")
            replay(d / "hour.mcap", cals=[d / "model3.json"], speed=None, up_sensor="+z", recording=rec)
            rec.close()

        rows = []
        for name, fn in (
            ("read+correct+integrate (evaluate)", baseline),
            ("replay, no logging", replay_only),
            ("replay -> .rrd", replay_rrd),
        ):
            best = min(_timed(fn) for _ in range(args.repeat))
            rows.append((name, best))
        rrd_mb = (d / "hour.rrd").stat().st_size / 1e6
    base = rows[1][1]  # the right baseline: the same replay without logging
    print(
        f"session: {n:,} samples ({args.minutes:g} min at 1 kHz), MCAP {size_mb:.1f} MB written in {t_write:.1f} s; .rrd {rrd_mb:.0f} MB"
    )
    print(f"load average {os.getloadavg()} (2 cores; a loaded machine inflates every figure)")
    print(f"{'variant':40s} {'best s':>8s} {'x replay':>9s}")
    for name, t in rows:
        print(f"{name:40s} {t:8.2f} {t / base:9.2f}")
    added = rows[2][1] / base - 1.0
    print(f"logging adds {100 * added:.0f} % to the same replay without logging (goal: under 50 %)")


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
