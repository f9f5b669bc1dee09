"""The platform's floor for live recording (issue 27 item 6): how late a bare real-time thread
wakes up beside the background load of bench_record_load.py, whatever the recorder does.

Per load level (the ``mixed`` or ``busy`` background of bench_record_load.py, --warmup-s before
the first row), a process raises one thread to SCHED_RR (``raise_priority``, as ``accellog record``
does) and sleeps --period-ms (14 ms: the recorder's read period at 1 kHz, 0.4 of the 36 ms FIFO)
from one wake-up to the next, doing nothing else, for --seconds. Reported: the wake-ups, how many
came more than 20 ms after the previous one (the recorder's margin is gone), how many more than
36 ms after it (a full FIFO: the recorder would lose samples there, whatever its own work), the
worst gap, the share of time lost past 36 ms if every such gap lost its excess at 1 kHz (the loss a
recorder with zero work would still see), the 1-minute load average and the steal time.

    python benchmarks/bench_record_floor.py [--seconds 60] [--load 1 2 4] [--load-kind mixed|busy]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_record_load import Background, LoadSampler
from rich.console import Console
from rich.table import Table

from accellog.acquire.recorder import raise_priority

FIFO_S = 0.036  # 512-byte FIFO / 14-byte packets at 1 kHz
LATE_S = 0.020


def wakeups(seconds: float, period_s: float, rt: bool) -> dict:
    """Gaps (s) between the wake-ups of a thread sleeping period_s from one wake-up to the next."""
    prio = raise_priority() if rt else "normal"
    t = [time.perf_counter()]
    end = t[0] + seconds
    while t[-1] < end:
        left = period_s - (time.perf_counter() - t[-1])
        if left > 0:
            time.sleep(left)
        t.append(time.perf_counter())
    gap = np.diff(np.array(t))
    return {"gaps": gap, "priority": prio}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="wall seconds per row")
    ap.add_argument("--load", type=float, nargs="+", default=[1.0, 2.0, 4.0], help="background load levels")
    ap.add_argument("--load-kind", choices=("mixed", "busy"), default="mixed")
    ap.add_argument("--warmup-s", type=float, default=20.0, help="load before a level's first row")
    ap.add_argument("--period-ms", type=float, default=14.0)
    ap.add_argument("--normal", action="store_true", help="also a row at normal priority")
    args = ap.parse_args()
    la0 = os.getloadavg()
    tab = Table(
        title=f"a bare thread sleeping {args.period_ms:g} ms periods beside a {args.load_kind} background "
        f"load, {args.seconds:g} s per row, {os.cpu_count()} cores"
    )
    cols = ("load", "thread", "wake-ups", f"> {1e3 * LATE_S:.0f} ms", f"> {1e3 * FIFO_S:.0f} ms", "worst gap",
            "floor loss %", "load avg", "steal")  # fmt: skip
    for col in cols:
        tab.add_column(col, justify="left" if col == "thread" else "right")
    with tempfile.TemporaryDirectory(prefix="bench_floor_") as wd:
        for level in args.load:
            bg = Background(args.load_kind, level, Path(wd))
            try:
                time.sleep(args.warmup_s)
                for rt in (True, False) if args.normal else (True,):
                    sampler = LoadSampler()
                    with mp.Pool(1) as pool:  # a raised priority must not leak into the next row
                        r = pool.apply(wakeups, (args.seconds, args.period_ms / 1e3, rt))
                    g = r["gaps"]
                    lost_s = np.clip(g - FIFO_S, 0.0, None).sum()
                    tab.add_row(
                        f"{level:g}",
                        "SCHED_RR" if "SCHED_RR" in r["priority"] else r["priority"],
                        str(len(g)),
                        str(int((g > LATE_S).sum())),
                        str(int((g > FIFO_S).sum())),
                        f"{1e3 * g.max():.0f} ms",
                        f"{100 * lost_s / g.sum():.3f}",
                        f"{sampler.mean():.1f}",
                        f"{100 * sampler.steal():.1f} %",
                    )
            finally:
                bg.finish()
    console = Console(width=140)
    console.print(tab)
    console.print(f"load average before the run {la0[0]:.1f}, after {os.getloadavg()[0]:.1f} "
                  "(a shared machine: other jobs add to the background load)")  # fmt: skip


if __name__ == "__main__":
    main()
