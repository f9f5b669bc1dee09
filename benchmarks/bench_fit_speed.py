"""Fit speed: a one-hour 1 kHz six-pose session end to end vs the same work on arrays in memory.

End to end = read the MCAP (3.6 M samples) + segment (checks, windows, autocorrelation) + fit
model1/2/3 + evaluate Model 3 on a 10-minute 1 kHz static test read from MCAP (displacement).
In memory = the same stages on the Session objects already loaded. Goals: end to end < 5 s, and
within 3x of the in-memory work. Both are measured side by side in one run (best of --repeat).

    python benchmarks/bench_fit_speed.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.signal import lfilter

from accellog.calibrate.calibration import Calibration
from accellog.calibrate.fit import fit_model
from accellog.calibrate.model import build_model
from accellog.calibrate.segment import observations
from accellog.core.protocol import six_position
from accellog.core.session import PoseLabel, Session, SessionMeta
from accellog.navigate.evaluate import evaluate
from accellog.store.reader import read_session
from accellog.store.writer import write_session

RATE_HZ = 1000.0
LSB = 16384.0
S_TRUE = np.array([[1.01, 0.004, -0.006], [0.003, 0.985, 0.008], [-0.005, 0.002, 1.02]])
B_TRUE = np.array([0.03, -0.02, 0.05])


def synth(duration_s: float, faces: list, seed: int) -> Session:
    """Counts of S f + b + AR(1) noise (1 kHz); equal holds per face with 10 s moves between."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    per = duration_s / len(faces)
    k = np.minimum((t // per).astype(int), len(faces) - 1)
    ups = np.array([f.up_sensor for f in faces])
    f = ups[k]
    in_move = ((t - k * per) > per - 10.0) & (len(faces) > 1)
    nxt = ups[np.minimum(k + 1, len(faces) - 1)]
    w = np.clip((t - k * per - (per - 10.0)) / 10.0, 0, 1)[:, None] * in_move[:, None]
    f = (1 - w) * f + w * nxt + np.sin(np.pi * w) * np.array([0.6, 0.5, 0.4])  # never through 0
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    noise = lfilter([1.0], [1.0, -0.5], rng.normal(0, 0.003, (n, 3)), axis=0)
    counts = np.round((f @ S_TRUE.T + B_TRUE + noise) * LSB).astype(np.int32)
    poses = [
        PoseLabel(fc.name, i * per, (i + 1) * per - 10.0, fc.up_sensor, fc.q_sensor_to_world, 0)
        for i, fc in enumerate(faces)
    ]
    temp = 30.0 + 0.5 * (1 - np.exp(-t / 600.0))
    meta = SessionMeta(source="emulator", accel_lsb_per_g=LSB, accel_range_g=2, sample_rate_hz=RATE_HZ)
    return Session(meta=meta, t_s=t, sample_index=np.arange(n), accel_g=counts / LSB, accel_counts=counts,
                   temp_degC=temp, poses=poses if len(faces) > 1 else [])  # fmt: skip


def stages(cal_session: Session, test_session: Session) -> None:
    obs = observations(cal_session, window_s=2.0, trim_s=0.5)
    fits = [fit_model(obs, build_model(m), weighted=True) for m in ("model1", "model2", "model3")]
    ev = evaluate(test_session, Calibration.from_fit(fits[-1], obs=obs))
    assert np.isfinite(ev.disp_end_m).all()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        cal_p = write_session(Path(d) / "hour.mcap", synth(3600.0, six_position(), 1))
        test_p = write_session(Path(d) / "static.mcap", synth(600.0, six_position()[:1], 2))
        e2e, mem = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            cs, ts = read_session(cal_p), read_session(test_p)
            t1 = time.perf_counter()
            stages(cs, ts)
            t2 = time.perf_counter()
            stages(cs, ts)  # the same numpy work on arrays already in memory
            t3 = time.perf_counter()
            e2e.append(t2 - t0)
            mem.append(t3 - t2)
            read = t1 - t0
        tab = Table(
            title=f"fit speed: 1 h at 1 kHz ({cs.n:,} samples) + 10 min static test, best of {args.repeat}"
        )
        for c in ("measure", "time (s)", "ratio to in-memory", "goal"):
            tab.add_column(c, justify="right" if c != "measure" else "left")
        best_e2e, best_mem = min(e2e), min(mem)
        tab.add_row(
            "end to end (read MCAP + segment + 3 fits + evaluate)",
            f"{best_e2e:.2f}",
            f"{best_e2e / best_mem:.2f}",
            "< 5 s, < 3x",
        )
        tab.add_row("in memory (segment + 3 fits + evaluate)", f"{best_mem:.2f}", "1.00", "")
        tab.add_row("  of which read MCAP (last run)", f"{read:.2f}", f"{read / best_mem:.2f}", "")
        Console().print(tab)


if __name__ == "__main__":
    main()
