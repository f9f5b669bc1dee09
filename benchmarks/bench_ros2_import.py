"""ROS 2 bag import speed and memory: `accellog import ros2` vs rosbags' own read and decode floors.

Usage: python benchmarks/bench_ros2_import.py [--minutes 60] [--rate 1000]

Data: a seeded 1 kHz sensor_msgs/msg/Imu stream (+ a 10 Hz Temperature topic) written once as a
rosbag2 MCAP file by accellog.store.ros2_writer (rosbags' writer). Each variant runs in its own
Python process (peak RSS = its own ru_maxrss); the page cache is warmed first. Variants:
- read floor: rosbags AnyReader iterating the raw IMU messages (no decoding);
- decode floor: the same plus rosbags' CDR deserialization of every message (what any importer
  using the maintained decoder must pay);
- accellog: import_ros2_to_mcap, what `accellog import ros2 BAG -o OUT.mcap` runs (blocks of raw
  messages decoded with numpy, SI -> accellog units, stamps vs log time, temperature interpolation,
  written to an accellog MCAP as they are read).
Speed is reported as x real time (bag duration / wall, and / process CPU time, which a loaded shared
machine distorts less) and as a ratio to the decode floor; the load average is printed with every
figure (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def write_bag(path: Path, n: int, rate_hz: float, seed: int = 0, slice_n: int = 100_000) -> None:
    from accellog.store.ros2_writer import Ros2BagWriter

    rng = np.random.default_rng(seed)
    t0 = 1_700_000_000_000_000_000
    with Ros2BagWriter(path) as w:
        for s in range(0, n, slice_n):
            k = min(slice_n, n - s)
            stamp = t0 + np.round((s + np.arange(k)) * 1e9 / rate_hz).astype(np.int64)
            acc = np.array([0.2, -0.1, 9.81]) + rng.normal(0, 0.04, (k, 3))
            gyr = rng.normal(0, 0.002, (k, 3))
            cov = np.diag([1e-3] * 3)
            w.write_imu(stamp, acc, gyr, cov, cov * 1e-3, log_ns=stamp + 1_500_000)
            step = max(1, round(rate_hz / 10))
            w.write_temperature(stamp[::step], 30 + 0.001 * (s + np.arange(k)[::step]) / rate_hz)


_CHILD = r"""
import json, resource, sys, time
from pathlib import Path
variant, bag, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
t0 = time.perf_counter()
if variant in ("read_floor", "decode_floor"):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    n = 0
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
        conns = [c for c in r.connections if c.msgtype == "sensor_msgs/msg/Imu"]
        des = r.deserialize
        for c, _, raw in r.messages(connections=conns):
            if variant == "decode_floor":
                des(raw, c.msgtype)
            n += 1
else:
    from accellog.store.importers.ros2_stream import import_ros2_to_mcap
    n = import_ros2_to_mcap(bag, out, temperature_topic="/imu/temperature", overwrite=True)["samples"]
wall = time.perf_counter() - t0
ru, rc = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
cpu = ru.ru_utime + ru.ru_stime + rc.ru_utime + rc.ru_stime  # + the decoding worker processes
peak = (ru.ru_maxrss + rc.ru_maxrss) / 1024  # self + the largest worker: an upper bound
print(json.dumps({"wall_s": wall, "cpu_s": cpu, "peak_mb": peak, "n": n}))
"""


def run(variant: str, bag: Path, out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    p = subprocess.run([sys.executable, "-c", _CHILD, variant, str(bag), str(out)],
                       capture_output=True, text=True, env=env, check=False)  # fmt: skip
    if p.returncode:
        raise SystemExit(f"{variant} failed: {p.stderr.strip().splitlines()[-1]}")
    return json.loads(p.stdout)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--bag", type=Path, help="reuse (or create and keep) this bag file")
    a = ap.parse_args()
    n = round(a.minutes * 60 * a.rate)
    tmp = Path(tempfile.mkdtemp(prefix="bench_ros2_"))
    bag, out = a.bag or tmp / "imu.mcap", tmp / "session.mcap"
    t0 = time.perf_counter()
    if not bag.exists():
        write_bag(bag, n, a.rate)
    print(f"bag: {n:,} Imu messages ({a.minutes:g} min at {a.rate:g} Hz) + 10 Hz Temperature, "
          f"{bag.stat().st_size / 1e6:.0f} MB, written in {time.perf_counter() - t0:.0f} s")  # fmt: skip
    with open(bag, "rb") as f:
        while f.read(64 << 20):
            pass
    res = {}
    for v in ("read_floor", "decode_floor", "accellog"):
        res[v] = r = run(v, bag, out)
        print(f"{v:13s} wall {r['wall_s']:7.1f} s  {a.minutes * 60 / r['wall_s']:6.1f}x real time  "
              f"(process CPU {r['cpu_s']:6.1f} s: {a.minutes * 60 / r['cpu_s']:6.1f}x)  "
              f"peak RSS {r['peak_mb']:6.0f} MB  load avg {os.getloadavg()[0]:.2f}", flush=True)  # fmt: skip
    acc = res["accellog"]["wall_s"]
    print(f"\naccellog import / decode floor: {acc / res['decode_floor']['wall_s']:.2f}x; "
          f"/ read floor: {acc / res['read_floor']['wall_s']:.2f}x")  # fmt: skip
    print(f"load average at the end: {os.getloadavg()} (2 cores, shared with other jobs)")
    out.unlink(missing_ok=True)
    if a.bag is None:
        bag.unlink()
    tmp.rmdir()


if __name__ == "__main__":
    main()
