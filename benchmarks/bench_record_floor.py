"""The platform's floor for live recording (issue 27 item 6): how late a real-time thread wakes up,
and how long a fixed piece of work takes it, beside the background load of bench_record_load.py,
whatever the recorder does.

Per load level (the ``mixed`` or ``busy`` background of bench_record_load.py, --warmup-s before
the first row), a process raises one thread to SCHED_RR (``raised_priority``, as ``accellog record``
does, BLAS on one thread) and sleeps --period-ms (14 ms: the recorder's read period at 1 kHz, 0.4
of the 36 ms FIFO) from one wake-up to the next, for --seconds. After each wake-up it does --work-ms
of fixed numpy work on preallocated arrays (default 0.4 ms: the median CPU of one recorder
iteration; 0: a bare thread that does nothing). Reported: the wake-ups, how many came more than
20 ms after the previous one (the recorder's margin is gone), how many more than 36 ms after it (a
full FIFO: the recorder would lose samples there), the worst gap, the share of time lost past 36 ms
if every such gap lost its excess at 1 kHz (the loss a recorder with this work would still see),
how often the fixed work took more than 10 ms and its worst time, where those slow pieces spent
their time (the thread's /proc schedstat: on a CPU / runnable but waiting for one / neither, i.e.
blocked or its virtual CPU not running), the 1-minute load average and the steal time.

    python benchmarks/bench_record_floor.py [--seconds 60] [--load 1 2 4] [--load-kind mixed|mixed-reuse|busy]
        [--work-ms 0.4]
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_record_load import LOAD_KINDS, Background, LoadSampler
from rich.console import Console
from rich.table import Table

from accellog.acquire.recorder import raised_priority

FIFO_S = 0.036  # 512-byte FIFO / 14-byte packets at 1 kHz
LATE_S = 0.020


def fixed_work(work_s: float):
    """A function doing about work_s (s) of small numpy operations on preallocated arrays (one FIFO
    read's worth of samples: 36 x 7), the same amount each call."""
    a = np.arange(36 * 7, dtype=float).reshape(36, 7)
    out = np.empty_like(a)

    def unit(k: int) -> None:
        for _ in range(k):
            np.multiply(a, 1.0001, out=out)
            np.cumsum(out, axis=0, out=out)

    t0 = time.perf_counter()
    unit(200)
    k = max(round(work_s / ((time.perf_counter() - t0) / 200)), 0)
    return lambda: unit(k)


def wakeups(seconds: float, period_s: float, rt: bool, work_s: float = 0.0) -> dict:
    """Gaps (s) between the wake-ups of a thread sleeping period_s from one wake-up to the next, and
    the time (s) of the fixed work done after each wake-up."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"), contextlib.ExitStack() as stack:
        prio = stack.enter_context(raised_priority()) if rt else "normal"
        work = fixed_work(work_s)
        t = [time.perf_counter()]
        took, where = [], []
        end = t[0] + seconds
        while t[-1] < end:
            s0 = schedstat()
            work()
            took.append(time.perf_counter() - t[-1])
            where.append(schedstat() - s0)
            left = period_s - (time.perf_counter() - t[-1])
            if left > 0:
                time.sleep(left)
            t.append(time.perf_counter())
    return {"gaps": np.diff(np.array(t)), "work": np.array(took), "where": np.array(where), "priority": prio}


def schedstat() -> np.ndarray:
    """(time on a CPU, time runnable waiting for one) of the calling thread so far (s; Linux
    /proc/thread-self/schedstat; zeros elsewhere). What a slow piece of work spent in neither,
    the thread was blocked (a page fault's I/O, a lock) or its virtual CPU was not running."""
    try:
        with open("/proc/thread-self/schedstat") as f:
            on_cpu, waiting = f.read().split()[:2]
    except (OSError, ValueError):
        return np.zeros(2)
    return np.array([int(on_cpu), int(waiting)]) / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="wall seconds per row")
    ap.add_argument("--load", type=float, nargs="+", default=[1.0, 2.0, 4.0], help="background load levels")
    ap.add_argument("--load-kind", choices=LOAD_KINDS, default="mixed")
    ap.add_argument("--warmup-s", type=float, default=20.0, help="load before a level's first row")
    ap.add_argument("--period-ms", type=float, default=14.0)
    ap.add_argument("--work-ms", type=float, default=0.4, help="fixed work after each wake-up (0: none)")
    ap.add_argument("--normal", action="store_true", help="also a row at normal priority")
    args = ap.parse_args()
    la0 = os.getloadavg()
    tab = Table(
        title=f"a thread sleeping {args.period_ms:g} ms periods, {args.work_ms:g} ms of fixed work after each "
        f"wake-up, beside a {args.load_kind} background load, {args.seconds:g} s per row, {os.cpu_count()} cores"
    )
    cols = ("load", "thread", "wake-ups", f"> {1e3 * LATE_S:.0f} ms", f"> {1e3 * FIFO_S:.0f} ms", "worst gap",
            "floor loss %", "work median", "work > 10 ms", "worst work", "slow work: cpu / queued / neither",
            "load avg", "steal")  # fmt: skip
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
                        r = pool.apply(wakeups, (args.seconds, args.period_ms / 1e3, rt, args.work_ms / 1e3))
                    g, w = r["gaps"], r["work"]
                    slow = w > 0.010
                    cpu_s, queued_s = r["where"][slow].sum(axis=0) if slow.any() else (0.0, 0.0)
                    neither_s = w[slow].sum() - cpu_s - queued_s
                    lost_s = np.clip(g - FIFO_S, 0.0, None).sum()
                    tab.add_row(
                        f"{level:g}",
                        "SCHED_RR" if "SCHED_RR" in r["priority"] else r["priority"],
                        str(len(g)),
                        str(int((g > LATE_S).sum())),
                        str(int((g > FIFO_S).sum())),
                        f"{1e3 * g.max():.0f} ms",
                        f"{100 * lost_s / g.sum():.3f}",
                        f"{1e3 * np.median(w):.2f} ms",
                        str(int((w > 0.010).sum())),
                        f"{1e3 * w.max():.1f} ms",
                        f"{1e3 * cpu_s:.0f} / {1e3 * queued_s:.0f} / {1e3 * neither_s:.0f} ms",
                        f"{sampler.mean():.1f}",
                        f"{100 * sampler.steal():.1f} %",
                    )
            finally:
                bg.finish()
    console = Console(width=180)
    console.print(tab)
    console.print(f"load average before the run {la0[0]:.1f}, after {os.getloadavg()[0]:.1f} "
                  "(a shared machine: other jobs add to the background load)")  # fmt: skip


if __name__ == "__main__":
    main()
