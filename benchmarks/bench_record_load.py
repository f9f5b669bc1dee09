"""Live recording on a loaded host (issue 12, item 5): lost samples and CPU share at 1 kHz.

A load generator starts --busy processes that spin on the CPU (default 2: every core of the
2-core target machine busy), then records live from the emulated chip on the RealClock at 1 kHz
(the path of ``accellog record --sim``: chip registers -> Mpu9250 FIFO driver -> Recorder ->
SessionWriter MCAP) for --seconds of wall time per variant, side by side in the same run:

- ``before``: the previous loop (sleep poll_s after every read, whatever the FIFO holds; no
  FIFO flush before the first read) - the baseline;
- ``adaptive``: the Recorder now (FIFO flushed before the first read; reads at least every 40 %
  of the FIFO's 36 ms, the wait measured from the previous read's start; an immediate re-read when
  a read found the FIFO more than half full);
- ``adaptive+rt``: the same with ``raise_priority()`` (SCHED_RR when permitted, as ``accellog
  record`` does on the real clock).

Each variant runs in its own process (a raised priority does not leak into the next row).

Each at --poll-ms (default 20 ms, the default poll, and 50 ms, where the old loop livelocked).
Figures: lost samples / expected (goal < 0.1 %), FIFO overflow events (and whether one was at
t = 0), CPU share of one core of the recorder alone (process CPU minus the emulated chip's own
bus methods, as in bench_record.py; goal < 10 %), peak RSS, and the load average.

    python benchmarks/bench_record_load.py [--seconds 120] [--busy 2] [--poll-ms 20 50] [--variants ...]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import resource
import tempfile
import time
from pathlib import Path

from bench_record import make_chain, meta_for
from rich.console import Console
from rich.table import Table

from accellog.acquire.emulator.clock import RealClock
from accellog.acquire.recorder import Recorder, raise_priority
from accellog.flows.simulate import Scenario
from accellog.store.reader import read_session
from accellog.store.writer import SessionWriter


def spin(stop) -> None:  # pragma: no cover - runs in the load processes
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


class BeforeRecorder(Recorder):
    """The loop before issue 12: a fixed sleep(poll_s) before every read, no flush at the start."""

    def _wait(self) -> None:
        self.sleep(self.poll_s)

    def _flush_before_first_read(self) -> None:
        pass


def cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def run(kind: str, seconds: float, poll_s: float, out: Path) -> dict:
    sc = Scenario(protocol="+z", hold_s=seconds + 30.0, sample_rate_hz=1000.0, seed=1)
    clock = RealClock()
    timed: dict = {}
    _chip, drv, _ = make_chain(sc, clock, timed=timed)
    cls = BeforeRecorder if kind == "before" else Recorder
    prio = raise_priority() if kind == "adaptive+rt" else "normal"
    with SessionWriter(out, meta_for(drv)) as w:
        drv.start()
        time.sleep(0.05)  # what opening files, viewers and printing costs before the loop starts
        rec = cls(drv, w, sleep=time.sleep, poll_s=poll_s)
        timed["chip_s"] = 0.0
        c0, w0 = cpu_s(), time.perf_counter()
        end = w0 + seconds
        while time.perf_counter() < end:
            rec.step(detect_stillness=False)
        c1, w1 = cpu_s(), time.perf_counter()
    summ = rec.summary  # (read_session would refuse a session without samples: the old 50 ms case)
    over = [e for e in summ.events if e.kind == "fifo_overflow"]
    if summ.samples:
        assert read_session(out).n == summ.samples
    return {
        "wall_s": w1 - w0,
        "cpu_s": c1 - c0,
        "chip_s": timed["chip_s"],
        "samples": summ.samples,
        "lost": summ.lost_samples,
        "overflows": len(over),
        "at_t0": bool(over) and over[0].sample_index == 0,
        "reads": rec.reads,
        "priority": prio,
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="wall seconds per variant")
    ap.add_argument("--busy", type=int, default=2, help="busy-looping load processes")
    ap.add_argument("--poll-ms", type=float, nargs="+", default=[20.0, 50.0])
    ap.add_argument("--variants", nargs="+", default=["before", "adaptive", "adaptive+rt"])
    args = ap.parse_args()
    console = Console(width=140)
    stop = mp.Event()
    load = [mp.Process(target=spin, args=(stop,), daemon=True) for _ in range(args.busy)]
    for p in load:
        p.start()
    la0 = os.getloadavg()
    peak = 0.0
    tab = Table(
        title=f"live 1 kHz recording with {args.busy} busy processes, {args.seconds:g} s per row "
        f"(goals: lost < 0.1 %, recorder < 10 % of one core)"
    )
    peak = 0.0
    for col in (
        "loop",
        "poll",
        "samples",
        "lost",
        "lost %",
        "overflows",
        "at t=0",
        "reads/s",
        "recorder CPU",
        "process CPU",
        "load avg (1 min)",
    ):
        tab.add_column(col, justify="left" if col in ("loop", "poll") else "right")
    try:
        with tempfile.TemporaryDirectory(prefix="bench_load_") as wd:
            for poll_ms in args.poll_ms:
                for kind in args.variants:
                    # each variant in its own process: a raised priority must not leak into the next row
                    with mp.Pool(1) as pool:
                        r = pool.apply(run, (kind, args.seconds, poll_ms / 1000.0, Path(wd) / "r.mcap"))
                    exp = r["samples"] + r["lost"]
                    peak = max(peak, r["peak_mb"])
                    w = r["wall_s"]
                    tab.add_row(
                        kind,
                        f"{poll_ms:g} ms",
                        str(r["samples"]),
                        str(r["lost"]),
                        f"{100 * r['lost'] / max(exp, 1):.3f}",
                        str(r["overflows"]),
                        "yes" if r["at_t0"] else "no",
                        f"{r['reads'] / w:.0f}",
                        f"{100 * (r['cpu_s'] - r['chip_s']) / w:.1f} %",
                        f"{100 * r['cpu_s'] / w:.1f} %",
                        f"{os.getloadavg()[0]:.1f}",
                    )
                    console.print(f"done: {kind}, {poll_ms:g} ms poll")
    finally:
        stop.set()
        for p in load:
            p.join(5)
    console.print(tab)
    console.print(
        f"peak RSS of a recording process {peak:.0f} MB; load average at start {la0[0]:.1f} / {la0[1]:.1f} / {la0[2]:.1f}, "
        f"at end {os.getloadavg()[0]:.1f} (a shared machine: other jobs add to the {args.busy} busy processes)"
    )


if __name__ == "__main__":
    main()
