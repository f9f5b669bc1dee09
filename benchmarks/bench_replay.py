"""Replay to an .rrd against the same replay without logging, with peak memory, by session length.

Goal (issues #4, #11): logging adds under 50 % to the same replay without logging (the right
baseline, measured in the same run); replay memory bounded independently of session length.

    replay            flows.replay.replay(P, model3, speed=max): the file streamed block by block
    replay_rrd        the same, logging raw + calibrated accel and temperature (min/max display
                      envelopes), poses, events and the decimated tracks to an .rrd file
    replay_rrd_full   the same with every sample in the .rrd (--rrd-full): what logging cost before
    replay_whole      replay(read_session(P)): the whole session in memory first (before streaming)
    evaluate          read_session + model3 correct + double trapezoid in one batch (context only)

Sessions: a static z-up session at 1 kHz (accel + temperature counts, seeded), written hour by hour
with SessionWriter (1 MiB chunks, zstd). Every figure is one fresh process under /usr/bin/time
(peak RSS), imports done before the clock starts (wall and CPU = the work only; CPU = user + sys of
all threads), best of --repeat, the modes interleaved; the range of the load average during the
runs is printed with each row (a loaded 2-core machine inflates every wall time, CPU time less).

    python benchmarks/bench_replay.py [--minutes 60 240] [--modes replay replay_rrd ...] [--repeat 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

os.environ.setdefault("RERUN_ANALYTICS", "0")

LSB = 16384.0
S_TRUE = np.array([[1.01, 0.004, -0.003], [0.002, 0.995, 0.006], [-0.005, 0.001, 1.02]])
B_TRUE = np.array([0.03, -0.02, 0.05])

_PRELUDE = """
import json, os, time, resource
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
os.environ.setdefault("RERUN_ANALYTICS", "0")
from accellog.flows.replay import replay
from accellog.navigate.evaluate import evaluate
from accellog.calibrate.calfile.calibration import load_calibration
from accellog.present.rrd.recording import RunRecording
from accellog.store.reader import read_session
import rerun
"""
MODES = {
    "replay": "replay(P, cals=[C], speed=None, up_sensor='+z')",
    "replay_rrd": (
        "rec = RunRecording(f'save:{R}')\n"
        "replay(P, cals=[C], speed=None, up_sensor='+z', recording=rec)\nrec.close()"
    ),
    "replay_rrd_full": (
        "rec = RunRecording(f'save:{R}', full_rate=True)\n"
        "replay(P, cals=[C], speed=None, up_sensor='+z', recording=rec)\nrec.close()"
    ),
    "replay_whole": "replay(read_session(P), cals=[C], speed=None, up_sensor='+z')",
    "evaluate": ("evaluate(read_session(P), load_calibration(C), up_sensor=(0, 0, 1), check_moving=False)"),
}


def write_static(path: Path, minutes: float, seed: int = 0) -> Path:
    """A static z-up session of `minutes` at 1 kHz, generated and written ten minutes at a time."""
    from accellog.core.session import SessionMeta
    from accellog.store.writer import SessionWriter

    rng = np.random.default_rng(seed)
    n = round(minutes * 60_000)
    meta = SessionMeta(source="emulator", accel_lsb_per_g=LSB, accel_range_g=2.0, sample_rate_hz=1000.0)
    with SessionWriter(path, meta, flush_interval_s=np.inf, chunk_size=1 << 20) as w:
        for a0 in range(0, n, 600_000):
            m = min(600_000, n - a0)
            f = np.tile([0.0, 0.0, 1.0], (m, 1))
            counts = np.round((f @ S_TRUE.T + B_TRUE + rng.normal(0, 0.002, f.shape)) * LSB).astype(np.int32)
            i = np.arange(a0, a0 + m)
            temp = np.round((30.0 + 2.0 * i / n - 21.0) * 333.87).astype(np.int32)
            t_ns = i * 1_000_000
            for a in range(0, m, 1000):
                w.write_imu(a0 + a, t_ns[a : a + 1000], accel_counts=counts[a : a + 1000],
                            temp_counts=temp[a : a + 1000])  # fmt: skip
    return path


def write_calibration(d: Path) -> Path:
    """model3 fitted on a six-pose session of the same synthetic chip (2 s per pose)."""
    from accellog.core.session import PoseLabel, Session, SessionMeta
    from accellog.flows.stages import run_fit
    from accellog.store.writer import write_session

    rng = np.random.default_rng(1)
    ups = [(0, 0, 1), (0, 0, -1), (0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0)]
    f = np.concatenate([np.tile(np.array(u, float), (2000, 1)) for u in ups])
    counts = np.round((f @ S_TRUE.T + B_TRUE + rng.normal(0, 0.002, f.shape)) * LSB).astype(np.int32)
    poses = [PoseLabel(str(k), k * 2 + 0.1, (k + 1) * 2 - 0.1, u, None, k) for k, u in enumerate(ups)]
    meta = SessionMeta(source="emulator", accel_lsb_per_g=LSB, accel_range_g=2.0, sample_rate_hz=1000.0)
    n = counts.shape[0]
    s = Session(meta=meta, t_s=np.arange(n) / 1000.0, sample_index=np.arange(n), accel_g=counts / LSB,
                accel_counts=counts, poses=poses)  # fmt: skip
    write_session(d / "cal.mcap", s)
    run_fit(d / "cal.mcap", "model3", gravity="seed").cal.save(d / "model3.json")
    return d / "model3.json"


def run(mode: str, session: Path, cal: Path, rrd: Path) -> tuple[float, float, float]:
    """(wall s, CPU s (user + sys, all threads) of the work, peak RSS MB of the process) of one fresh
    process doing `mode`."""
    code = (
        f"{_PRELUDE}P, C, R = {str(session)!r}, {str(cal)!r}, {str(rrd)!r}\n"
        f"t0, c0 = time.perf_counter(), cpu()\n{MODES[mode]}\n"
        "print(json.dumps([time.perf_counter() - t0, cpu() - c0]))"
    )
    r = subprocess.run(
        ["/usr/bin/time", "-f", "%M", sys.executable, "-c", code], capture_output=True, text=True
    )
    if r.returncode:
        raise SystemExit(f"{mode}: {r.stderr[-2000:]}")
    wall, cpu = json.loads(r.stdout.strip().splitlines()[-1])
    return float(wall), float(cpu), int(r.stderr.strip().splitlines()[-1]) / 1024


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, nargs="+", default=[60.0])
    ap.add_argument("--modes", nargs="+", default=["replay", "replay_rrd", "replay_rrd_full", "evaluate"])
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        cal = write_calibration(d)
        for minutes in args.minutes:
            session = write_static(d / f"s{minutes:g}.mcap", minutes)
            print(f"\nsession: {minutes:g} min at 1 kHz ({minutes * 60_000:,.0f} samples), "
                  f"MCAP {session.stat().st_size / 1e6:.0f} MB")  # fmt: skip
            print(
                f"{'mode':16s} {'best s':>8s} {'x replay':>9s} {'CPU s':>7s} {'x replay':>9s} {'peak MB':>8s} "
                f"{'rrd MB':>7s}  load average (during the runs)"
            )
            runs: dict[str, list] = {m: [] for m in args.modes}
            sizes: dict[str, float] = {}
            loads = []
            for _ in range(args.repeat):  # interleaved: a change of load hits every mode alike
                for mode in args.modes:
                    rrd = d / f"{mode}.rrd"
                    runs[mode].append(run(mode, session, cal, rrd))
                    loads.append(os.getloadavg()[0])
                    if rrd.exists():
                        sizes[mode] = rrd.stat().st_size / 1e6
                    rrd.unlink(missing_ok=True)
            base = runs.get("replay")
            bw, bc = (min(r[0] for r in base), min(r[1] for r in base)) if base else (None, None)
            load = f"{min(loads):.1f}-{max(loads):.1f}"
            for mode, rs in runs.items():
                wall, cpu, peak = min(r[0] for r in rs), min(r[1] for r in rs), max(r[2] for r in rs)
                size = f"{sizes[mode]:7.1f}" if mode in sizes else f"{'-':>7s}"
                rw = f"{wall / bw:9.2f}" if bw else f"{'-':>9s}"
                rc = f"{cpu / bc:9.2f}" if bc else f"{'-':>9s}"
                print(f"{mode:16s} {wall:8.2f} {rw} {cpu:7.2f} {rc} {peak:8.0f} {size}  {load}", flush=True)
            session.unlink()
    print("\n2-core machine shared with other developers: compare ratios within one run, not across runs.")


if __name__ == "__main__":
    main()
