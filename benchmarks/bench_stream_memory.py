"""Peak memory of streamed passes over recorder-layout sessions of 1 h / 4 h / 24 h (#11).

    python benchmarks/bench_stream_memory.py [--hours 1 4 24] [--dir /tmp/streammem] [--baseline DIR]

The live recorder writes one message per FIFO read (30-42 samples here, seeded) into 0.5 s chunks:
~7,000 chunks per hour, ~170 k in a day, where ``write_session`` (the sessions of bench_scale.py)
writes ~120 per hour. Whatever the reader keeps per chunk therefore grows with the session here and
hides there. Each file is written once hour by hour (``SessionWriter`` with its defaults, as the
recorder: zstd; ~4 s per hour) and reused from --dir. Each figure is a fresh process (its own peak
RSS, VmHWM: ru_maxrss would count this process's memory when it spawned the child; wall and CPU
time) of what every streamed stage does first (``store.source.open_source``: "labels") and of ``iter_imu``
over every block, the pass it makes ("pass"); the load average is printed with it. --baseline DIR:
the same with PYTHONPATH=DIR, e.g. an export of an earlier commit (``git archive COMMIT accellog |
tar -x -C DIR``).
"""

from __future__ import annotations

import argparse
import itertools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_readback import NS, fifo_reads, simulate

from accellog.store.writer import SessionWriter

HOUR = 3_600_000  # samples at 1 kHz

_CHILD = """
import sys, time
from accellog.store.source import open_source
from accellog.store.stream import iter_imu
t0, c0, n = time.perf_counter(), time.process_time(), 0
if sys.argv[2] == "pass":
    for block in iter_imu(sys.argv[1]):
        n += block.n
else:  # what every streamed stage does first
    open_source(sys.argv[1])
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
peak_kb = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM"))
print(n, peak_kb / 1024, wall, cpu)
"""


def write_recorder_session(path: Path, hours: int) -> None:
    """hours of 1 kHz samples as the recorder stores them (one message per FIFO read of 30-42)."""
    meta = simulate(10).meta
    with SessionWriter(path, meta) as w:
        for h in range(hours):
            s = simulate(HOUR, seed=h)
            shift = h * HOUR * 1_000_000
            t_ns = np.round(s.t_s * NS).astype(np.int64) + shift
            host = np.round(s.host_time_s * NS).astype(np.int64) + shift
            for i, j in itertools.pairwise(fifo_reads(HOUR, True).tolist()):
                w.write_imu(h * HOUR + i, t_ns[i:j], s.accel_counts[i:j], s.gyro_counts[i:j],
                            s.temp_counts[i:j], int(host[j - 1]))  # fmt: skip


def measure(path: Path, pythonpath: str | None, what: str) -> tuple[int, float, float, float]:
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    out = subprocess.run(  # cwd /: "python -c" puts the cwd first on sys.path, before PYTHONPATH
        [sys.executable, "-c", _CHILD, str(path), what], capture_output=True, text=True, env=env, cwd="/"
    )
    if out.returncode:
        sys.exit(out.stderr)
    n, peak, wall, cpu = out.stdout.split()
    return int(n), float(peak), float(wall), float(cpu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=int, nargs="+", default=[1, 4, 24])
    ap.add_argument("--dir", type=Path, default=Path("/tmp/streammem"))
    ap.add_argument("--baseline", help="PYTHONPATH of the code to compare with (an export of a commit)")
    args = ap.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    runs = [("now", None)] + ([("baseline", args.baseline)] if args.baseline else [])
    print(f"{'session':>8} {'~chunks':>8} {'file MB':>8} {'step':>7} {'code':>9} {'wall s':>7} {'CPU s':>6} "
          f"{'peak MB':>8} {'vs first':>8}  load average")  # fmt: skip
    first: dict[tuple[str, str], float] = {}
    for hours in args.hours:
        path = args.dir / f"rec_{hours}h.mcap"
        if not path.exists():
            write_recorder_session(path, hours)
        for what in ("labels", "pass"):  # labels: open_source; pass: iter_imu
            for name, pp in runs:
                n, peak, wall, cpu = measure(path, pp, what)
                assert what == "labels" or n == hours * HOUR, (path, n)
                first.setdefault((what, name), peak)
                load = " ".join(f"{x:.1f}" for x in os.getloadavg())
                print(f"{hours:>6} h {hours * 7200:>8} {path.stat().st_size / 1e6:>8.0f} {what:>7} {name:>9} "
                      f"{wall:>7.2f} {cpu:>6.2f} {peak:>8.0f} {peak / first[what, name]:>7.2f}x  {load}",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
