"""Which zstd level accellog's chunks are written at (accellog.store.zstd_level.ZSTD_LEVEL).

Usage: python benchmarks/bench_zstd_level.py [--minutes 10] [--repeat 5] [--levels 1 2 3]

Two files shaped like users' sessions, written by accellog: a recording (bench_readback.simulate:
1 kHz accel/gyro/temp counts, one message per 36-sample FIFO read) and a CSV import (the importer on
bench_csv_import.write_csv's 1 kHz file: float64 values in g, deg/s, degC). Their chunks are taken
back uncompressed, then compressed at each level (``zstandard.compress(data, level)``, what mcap's
Writer calls per chunk), best of --repeat: the compressed size over the uncompressed size and the
speed (MB/s of uncompressed data, one core). The last column is each level's time over level 3's
(zstd's default, what mcap's Writer uses when no level is set), measured in the same run.
"""

from __future__ import annotations

import argparse
import struct
import sys
import tempfile
import time
from pathlib import Path

import zstandard
from mcap.reader import make_reader

sys.path.insert(0, str(Path(__file__).parent))
from bench_csv_import import write_csv
from bench_readback import simulate, write_recorder_layout

from accellog.store.importers.csv import import_csv_to_mcap
from accellog.store.zstd_level import ZSTD_LEVEL


def chunks(path: Path) -> list[bytes]:
    """Every chunk of an MCAP file, uncompressed."""
    out = []
    with open(path, "rb") as f:
        for ci in make_reader(f).get_summary().chunk_indexes:
            f.seek(ci.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4)  # opcode, length, times, size, crc
            (n,) = struct.unpack("<I", f.read(4))
            f.seek(n, 1)
            (size,) = struct.unpack("<Q", f.read(8))
            data = f.read(size)
            out.append(zstandard.ZstdDecompressor().decompress(data, max_output_size=ci.uncompressed_size))
    return out


def measure(data: list[bytes], level: int, repeat: int) -> tuple[float, float]:
    """(compressed / uncompressed size, best time in s) of compressing every chunk at level."""
    best, size = float("inf"), 0
    for _ in range(repeat):
        t0 = time.process_time()
        size = sum(len(zstandard.compress(d, level)) for d in data)
        best = min(best, time.process_time() - t0)
    return size / sum(map(len, data)), best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--levels", type=int, nargs="+", default=[1, 2, 3])
    a = ap.parse_args()
    n = round(a.minutes * 60_000)
    with tempfile.TemporaryDirectory() as tmp:
        rec, csv, imported = Path(tmp, "rec.mcap"), Path(tmp, "s.csv"), Path(tmp, "csv.mcap")
        write_recorder_layout(rec, simulate(n))
        write_csv(csv, n, 1000.0)
        import_csv_to_mcap(csv, imported)
        files = {"recording (counts)": chunks(rec), "CSV import (float64)": chunks(imported)}
    levels = sorted(set(a.levels) | {3})
    print(f"{a.minutes:g} min at 1 kHz; accellog writes level {ZSTD_LEVEL}")
    print(f"{'layout':22} {'level':>5} {'size':>7} {'MB/s':>6} {'time vs 3':>10}")
    for name, data in files.items():
        mb = sum(map(len, data)) / 1e6
        res = {lv: measure(data, lv, a.repeat) for lv in levels}
        for lv in levels:
            ratio, t = res[lv]
            print(f"{name:22} {lv:5d} {ratio:7.3f} {mb / t:6.0f} {t / res[3][1]:9.2f}x")


if __name__ == "__main__":
    main()
