"""CSV import speed and memory: `accellog import csv` (streamed into MCAP) vs plain pyarrow parses.

Usage: python benchmarks/bench_csv_import.py [--minutes 240] [--rate 1000] [--keep]

Data: a seeded logger CSV (t in s with 6 decimals; ax..az in g, gx..gz in deg/s, temp in degC),
written once with pyarrow in slices. Each variant runs in its own fresh Python process, so its peak
RSS (VmHWM of /proc/self/status; ru_maxrss would also count this process's memory when it spawned
the child) is its own; the page cache is warmed first.
Variants:
- accellog: ``import_csv_to_mcap`` (block parse + checks + conversion + MCAP write, zstd: the default);
- accellog (parse only): the same blocks and checks without writing (``CsvImport.chunks``);
- pyarrow read_csv: one whole-file parse to a table, then numpy columns (memory grows with the file);
- pyarrow open_csv: streaming batches (the parse floor in bounded memory).
Ratios are wall-time and CPU-time ratios to the pyarrow baselines measured in the same run; the load
average is printed with every figure (the machine is shared: compare CPU time when it is loaded).
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

HEADER = ["t", "ax", "ay", "az", "gx", "gy", "gz", "temp"]


def write_csv(path: Path, n: int, rate_hz: float, seed: int = 0, slice_rows: int = 1_000_000) -> None:
    import pyarrow as pa
    import pyarrow.csv as pacsv

    rng = np.random.default_rng(seed)
    with open(path, "wb") as f:
        f.write((",".join(HEADER) + "\n").encode())
        for s in range(0, n, slice_rows):
            k = min(slice_rows, n - s)
            i = np.arange(s, s + k)
            cols = {"t": np.round(i / rate_hz, 6)}
            for j, (name, mean, sd) in enumerate(
                [
                    ("ax", 0.02, 0.004),
                    ("ay", -0.01, 0.004),
                    ("az", 1.0, 0.004),
                    ("gx", 0.2, 0.05),
                    ("gy", -0.1, 0.05),
                    ("gz", 0.05, 0.05),
                ]
            ):
                cols[name] = np.round(mean + sd * rng.standard_normal(k), 6 if j < 3 else 4)
            cols["temp"] = np.round(30 + 5 * (1 - np.exp(-i / 6e5)), 2)
            table = pa.table(cols)
            pacsv.write_csv(table, f, write_options=pacsv.WriteOptions(include_header=False))


_CHILD = r"""
import json, resource, sys, time
from pathlib import Path
variant, src, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
t0 = time.perf_counter()
if variant == "accellog":
    from accellog.store.importers.csv import import_csv_to_mcap
    n = import_csv_to_mcap(src, out).samples
elif variant == "accellog_parse":
    from accellog.store.importers.csv import CsvImport, CsvOptions
    imp = CsvImport(src, CsvOptions())
    n = sum(c.t_s.shape[0] for c in imp.chunks())
elif variant == "pyarrow_read_csv":
    import pyarrow.csv as pacsv
    tab = pacsv.read_csv(src)
    cols = [tab.column(c).to_numpy() for c in tab.column_names]
    n = tab.num_rows
elif variant == "pyarrow_open_csv":
    import pyarrow.csv as pacsv
    n = 0
    for b in pacsv.open_csv(src, read_options=pacsv.ReadOptions(block_size=16 << 20)):
        cols = [c.to_numpy() for c in b.columns]
        n += b.num_rows
wall = time.perf_counter() - t0
ru = resource.getrusage(resource.RUSAGE_SELF)
peak_kb = next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith("VmHWM"))
print(json.dumps({"wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime, "peak_mb": peak_kb / 1024, "n": n}))
"""


def run(variant: str, src: Path, out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    p = subprocess.run(
        [sys.executable, "-c", _CHILD, variant, str(src), str(out)],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    if p.returncode:
        raise SystemExit(f"{variant} failed: {p.stderr.strip().splitlines()[-1]}")
    return json.loads(p.stdout)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=240.0)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--keep", action="store_true", help="keep the CSV and MCAP in the temp folder")
    a = ap.parse_args()
    n = round(a.minutes * 60 * a.rate)
    tmp = Path(tempfile.mkdtemp(prefix="bench_csv_"))
    src, out = tmp / "log.csv", tmp / "log.mcap"
    t0 = time.perf_counter()
    write_csv(src, n, a.rate)
    size_mb = src.stat().st_size / 1e6
    print(f"CSV: {n:,} rows ({a.minutes:g} min at {a.rate:g} Hz), {size_mb:.0f} MB, written in "
          f"{time.perf_counter() - t0:.1f} s")  # fmt: skip
    with open(src, "rb") as f:  # warm the page cache
        while f.read(64 << 20):
            pass
    res = {}
    for v in ("pyarrow_open_csv", "pyarrow_read_csv", "accellog_parse", "accellog"):
        res[v] = run(v, src, out)
        r = res[v]
        print(f"{v:18s} wall {r['wall_s']:7.2f} s  CPU {r['cpu_s']:7.2f} s  peak RSS {r['peak_mb']:7.0f} MB  "
              f"rows {r['n']:,}  load avg {os.getloadavg()[0]:.2f}", flush=True)  # fmt: skip
    acc = res["accellog"]["wall_s"]
    cpu = res["accellog"]["cpu_s"]
    print(
        f"\nCPU time (process, all threads; the figure a loaded machine does not inflate): accellog import "
        f"{cpu:.2f} s = {cpu / res['pyarrow_open_csv']['cpu_s']:.2f}x open_csv, "
        f"{cpu / res['pyarrow_read_csv']['cpu_s']:.2f}x read_csv; parse only "
        f"{res['accellog_parse']['cpu_s'] / res['pyarrow_open_csv']['cpu_s']:.2f}x open_csv"
    )
    print(
        f"\naccellog import / pyarrow open_csv (streaming parse): {acc / res['pyarrow_open_csv']['wall_s']:.2f}x"
    )
    print(
        f"accellog import / pyarrow read_csv (whole-file parse): {acc / res['pyarrow_read_csv']['wall_s']:.2f}x"
    )
    print(
        f"accellog import speed: {a.minutes * 60 / acc:.0f}x real time, MCAP {out.stat().st_size / 1e6:.0f} MB"
    )
    print(f"load average at the end: {os.getloadavg()} (2 cores, shared with other jobs)")
    if not a.keep:
        src.unlink()
        out.unlink(missing_ok=True)
        tmp.rmdir()
    else:
        print(f"kept in {tmp}")


if __name__ == "__main__":
    main()
