"""Which chunk compression accellog writes by default: zstd against lz4 on sessions shaped like users'.

Usage: python benchmarks/bench_compression.py [--minutes 60] [--repeat 5] [--mibps 40 110]

One seeded 1 kHz session (bench_readback.simulate: accel/gyro/temp counts, a host time per 36-sample
FIFO read) written in both layouts users have: the recorder's (one message per FIFO read, a chunk
every 0.5 s) and write_session's (imports, simulations: 1 MiB chunks), each with zstd (the default)
and lz4. For each file:
- size, and the CPU / wall time to write it (SessionWriter / write_session, the same samples);
- read from the page cache: ``read_session`` and a streamed ``iter_imu`` pass, best of --repeat
  interleaved runs (the file read once before);
- read from storage: the page cache dropped, then ``read_session`` in a fresh process whose reads
  are throttled to each --mibps (MiB/s; ~40: SD card or USB 2 stick, ~110: disk or 1 GbE share) by
  a block-I/O cgroup (v1 blkio.throttle or v2 io.max), best of --repeat. Needs root; skipped with
  the reason otherwise.
The last column is zstd's figure over lz4's, measured in the same run; the load average is printed
before and after.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_readback import simulate, write_recorder_layout

from accellog.store.reader import read_session
from accellog.store.stream import iter_imu
from accellog.store.writer import DEFAULT_COMPRESSION, write_session

COMPRESSIONS = ("zstd", "lz4")
CGROUP = "accellog-bench"

_CHILD = """
import sys, time
open(sys.argv[1], "w").write(str(__import__("os").getpid()))
from accellog.store.reader import read_session
t0 = time.perf_counter()
read_session(sys.argv[2])
print(time.perf_counter() - t0)
"""


def load() -> str:
    return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def disk_of(path: Path) -> str:
    """MAJ:MIN of the whole disk holding ``path`` (throttles apply to disks, not partitions)."""
    st = os.stat(path)
    dev = f"{os.major(st.st_dev)}:{os.minor(st.st_dev)}"
    sysdir = Path("/sys/dev/block") / dev
    if (sysdir / "partition").exists():
        return (sysdir.resolve().parent / "dev").read_text().strip()
    return dev


class Throttle:
    """A block-I/O cgroup whose reads from one disk are capped (cgroup v1 blkio or v2 io)."""

    def __init__(self, disk: str) -> None:
        self.disk = disk
        v1, v2 = Path("/sys/fs/cgroup/blkio"), Path("/sys/fs/cgroup")
        if (v1 / "blkio.throttle.read_bps_device").exists():
            self.dir, self.v2 = v1 / CGROUP, False
        elif "io" in (v2 / "cgroup.subtree_control").read_text().split():
            self.dir, self.v2 = v2 / CGROUP, True
        else:
            raise OSError("no blkio (v1) or io (v2) cgroup controller")
        self.dir.mkdir(exist_ok=True)

    def cap(self, mibps: int) -> None:
        rate = mibps << 20
        if self.v2:
            (self.dir / "io.max").write_text(f"{self.disk} rbps={rate}\n")
        else:
            (self.dir / "blkio.throttle.read_bps_device").write_text(f"{self.disk} {rate}\n")

    def procs(self) -> str:
        return str(self.dir / "cgroup.procs")

    def remove(self) -> None:
        self.dir.rmdir()


def storage_read(path: Path, throttle: Throttle) -> float:
    """Wall time of read_session in a fresh process in the throttled cgroup, page cache dropped."""
    os.sync()
    Path("/proc/sys/vm/drop_caches").write_text("3\n")
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, throttle.procs(), str(path)],
        capture_output=True,
        text=True,
        check=True,
        cwd="/",
    )
    return float(out.stdout)


def timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def stream_all(path: Path) -> None:
    for _block in iter_imu(path):
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--mibps", type=int, nargs="*", default=[40, 110])
    a = ap.parse_args()
    n = int(a.minutes * 60_000)
    print(f"{a.minutes:g} min at 1 kHz = {n:,} samples; default compression: {DEFAULT_COMPRESSION}; {load()}")
    s = simulate(n)
    writers = {
        "recorder": lambda p, c: write_recorder_layout(p, s, c),
        "write_session": lambda p, c: write_session(p, s, compression=c),
    }
    rows: dict[tuple[str, str], dict[str, float]] = {}
    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR", "/tmp")) as d:
        files = {}
        for layout, write in writers.items():
            for comp in COMPRESSIONS:
                p = files[layout, comp] = Path(d) / f"{layout}_{comp}.mcap"
                t0, c0 = time.perf_counter(), time.process_time()
                write(p, comp)
                rows[layout, comp] = {
                    "size MB": p.stat().st_size / 1e6,
                    "write CPU s": time.process_time() - c0,
                    "write wall s": time.perf_counter() - t0,
                }
                read_session(p)  # warm the page cache
        for _ in range(a.repeat):  # interleaved, so load from other processes hits all alike
            for key, p in files.items():
                r = rows[key]
                r["read_session s"] = min(r.get("read_session s", 9e9), timed(lambda p=p: read_session(p)))
                r["iter_imu s"] = min(r.get("iter_imu s", 9e9), timed(lambda p=p: stream_all(p)))
        try:
            throttle = Throttle(disk_of(Path(d)))
        except OSError as exc:
            print(f"reads from storage skipped: {exc} (needs root and a block-I/O cgroup)")
            throttle = None
        if throttle is not None:
            try:
                for mibps in a.mibps:
                    throttle.cap(mibps)
                    col = f"from storage at {mibps} MiB/s s"
                    for _ in range(a.repeat):
                        for key, p in files.items():
                            got = storage_read(p, throttle)
                            rows[key][col] = min(rows[key].get(col, 9e9), got)
            finally:
                throttle.remove()
    cols = list(next(iter(rows.values())))
    print(f"{'layout':14s} {'figure':34s}" + "".join(f"{c:>9s}" for c in COMPRESSIONS) + "  zstd/lz4")
    for layout in writers:
        for c in cols:
            z, lz = rows[layout, "zstd"][c], rows[layout, "lz4"][c]
            print(f"{layout:14s} {c:34s}{z:9.3f}{lz:9.3f}{z / lz:9.2f}x")
    print(load())


if __name__ == "__main__":
    main()
