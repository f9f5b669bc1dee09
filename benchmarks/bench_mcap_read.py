"""accellog's fast MCAP reader (store/mcap/) vs the ``mcap`` library's reader, on one file (issue #26).

``read_session`` of the same file twice per round: the fast path, and the generic reader
(``accellog.store.reader.FAST_READ = False``: ``mcap``'s ``make_reader`` + accellog's per-message
decoder, store/collect.py). Rounds interleaved, file read once before timing (page cache warm);
reported: best CPU time (user + sys of every thread, s) of each and their ratio.

    python benchmarks/bench_mcap_read.py [--file /tmp/accellog_bench/fit_3600s.mcap] [--repeat 3]

A recorder-layout file (one message per FIFO read) is written by bench_readback.write_recorder_layout.
"""

from __future__ import annotations

import argparse
import resource
from pathlib import Path

from accellog.store import reader


def cpu_s() -> float:
    """User + sys CPU time of this process (all threads), s."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", type=Path, default=Path("/tmp/accellog_bench/fit_3600s.mcap"))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    n = len(reader.read_session(args.file).t_s)
    best = {True: float("inf"), False: float("inf")}
    for _ in range(args.repeat):
        for fast in (True, False):
            reader.FAST_READ = fast
            c = cpu_s()
            reader.read_session(args.file)
            best[fast] = min(best[fast], cpu_s() - c)
    reader.FAST_READ = True
    print(f"{args.file.name}: {n} samples")
    print(f"fast path (store/mcap):       {best[True]:.2f} s CPU")
    print(f"mcap reader + decoder:        {best[False]:.2f} s CPU  ({best[False] / best[True]:.1f}x)")


if __name__ == "__main__":
    main()
