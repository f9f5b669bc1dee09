"""Live recording on a loaded host (issues 12 and 27): lost samples and CPU share at 1 kHz.

Background load (--load-kind):

- ``mixed`` (default, issue 27): a moderately busy host. For a load level L (--load, default
  1 2 4), 2 L worker processes each run bursts of mixed work (numpy allocations and FFTs, Python
  loops, a file write + fsync) for 20-300 ms of wall time, then sleep as long again (duty 0.5): each
  is runnable about half the time, so the 1-minute load average sits near L (plus whatever else the
  machine runs), and I/O and memory traffic come in bursts the way compilers, test runs and
  browsers make them;
- ``mixed-reuse``: the same, but the 8-64 MB arrays reuse one array made at the start instead of
  new pages from the kernel each time (a diagnostic: on this project's 2-core virtual machine the
  recorder's loss comes with the other processes' mapping and unmapping of large memory; see
  docs/data-safety.md);
- ``busy`` (issue 12): L processes spinning on the CPU.

Workers start --warmup-s before the first recording of a level (the load average is a 1-minute
mean). Then, per level, the live recorder records from the emulated chip on the RealClock at 1 kHz
for --seconds of wall time (the path of ``accellog record --sim``: chip registers -> Mpu9250 FIFO
driver -> Recorder -> SessionWriter MCAP, zstd chunks flushed every 0.5 s, magnetometer at
100 Hz, stillness detection on), once per --variants, each in its own process:

- ``inline``: the Recorder as ``accellog record`` runs it (writes on the reading thread);
- ``adaptive``: the same with ``write_thread=True``: MCAP writes, live view and running calibration
  handed to a helper thread (accellog.acquire.handoff), the reading thread only reads the FIFO;
- ``before``: the loop before issue 12 (sleep poll_s after every read, no flush before the first);
- suffix ``+rt``: after ``raised_priority()`` (SCHED_RR when permitted, as ``accellog record`` does
  on the real clock; without the suffix: normal priority, what a user without CAP_SYS_NICE gets);
- suffix ``+cal``: a guided six-pose session (holds of (seconds - 20) / 6 s) with the live view's
  running calibration refitted after every hold.

Figures: lost samples / expected (goal < 0.1 %), FIFO overflow events, the worst time between two
FIFO reads and where the long ones (> 30 ms; the 512-byte FIFO holds 36 ms at 1 kHz) went (late
wake-up from sleep / the loop's own work after a read / the read itself), CPU share of one core
of the recorder alone (process CPU minus the emulated chip's bus methods, as in bench_record.py;
goal < 10 %), the background's CPU (cores) and the 1-minute load average (mean over the row).

    python benchmarks/bench_record_load.py [--seconds 120] [--load 1 2 4] [--load-kind mixed|mixed-reuse|busy]
        [--variants inline+rt adaptive+rt adaptive inline+cal ...] [--poll-ms 20] [--fill 0.4]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import math
import multiprocessing as mp
import os
import resource
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from bench_record import make_chain, meta_for
from rich.console import Console
from rich.table import Table

from accellog.acquire.emulator.clock import RealClock
from accellog.acquire.recorder import Recorder, raised_priority
from accellog.core.protocol import parse_protocol
from accellog.flows.record import RunningCalibration
from accellog.flows.simulate import Scenario
from accellog.store.reader import read_session
from accellog.store.writer import SessionWriter

LONG_GAP_S = 0.030
LOAD_KINDS = ("mixed", "mixed-reuse", "busy")
DUTY = 0.5


def spin(stop, _seed, _path, cpu) -> None:  # pragma: no cover - runs in the load processes
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1
    cpu.value = time.process_time()


def mixed(stop, seed, path, cpu, reuse: bool = False) -> None:  # pragma: no cover - load processes
    """Bursts of mixed work (20-300 ms wall), then a sleep as long as the burst (duty 0.5).
    reuse: the 8-64 MB arrays are slices of one array made at the start, instead of new memory from
    the kernel each time (the same work and memory traffic, no mapping and unmapping of pages)."""
    rng = np.random.default_rng(seed)
    big = np.ones(8 << 20) if reuse else None  # 64 MB
    with open(path, "wb") as f:
        while not stop.is_set():
            burst_s = float(rng.uniform(0.02, 0.3))
            end = time.perf_counter() + burst_s
            wrote = False
            while time.perf_counter() < end:
                k = int(rng.integers(4))
                if k == 0:
                    np.fft.rfft(rng.standard_normal(1 << int(rng.integers(14, 19))))
                elif k == 1:
                    n = int(rng.integers(1, 8)) << 20
                    if big is None:
                        np.ones(n).cumsum()  # 2 x 8-64 MB of new pages touched, then given back
                    else:
                        big[:n] = 1.0
                        np.cumsum(big[:n], out=big[:n])
                elif k == 2 and not wrote:
                    if f.tell() > 64 << 20:
                        f.seek(0)
                    f.write(rng.bytes(int(rng.integers(64, 2048)) << 10))
                    f.flush()
                    os.fsync(f.fileno())
                    wrote = True
                else:
                    sum(i * i for i in range(20_000))
            stop.wait(burst_s * (1.0 - DUTY) / DUTY)
    cpu.value = time.process_time()


class BeforeRecorder(Recorder):
    """The loop before issue 12: a fixed sleep(poll_s) before every read, no flush at the start."""

    def _wait(self) -> None:
        self.sleep(self.poll_s)

    def _flush_before_first_read(self) -> None:
        pass


def cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


class GapProbe:
    """Times every FIFO read and the sleep before it (perf_counter s), wrapping driver.read and sleep."""

    def __init__(self, drv, sleep) -> None:
        self.rows: list[tuple[float, float, float, float, float]] = []  # read0, read1, sleep0, asked, sleep1
        self._sleep = sleep
        self._last = (math.nan, 0.0, math.nan)
        read = drv.read

        def timed_read():
            t0 = time.perf_counter()
            try:
                return read()
            finally:
                self.rows.append((t0, time.perf_counter(), *self._last))
                self._last = (math.nan, 0.0, math.nan)

        drv.read = timed_read

    def sleep(self, s: float) -> None:
        t0 = time.perf_counter()
        self._sleep(s)
        self._last = (t0, s, time.perf_counter())

    def summary(self) -> dict:
        """Worst gap between read starts (s) and, summed over gaps > LONG_GAP_S: late wake-ups,
        the loop's work between a read's end and the next sleep (or read), the reads (s)."""
        r = np.array(self.rows)
        if len(r) < 2:
            return {"worst_s": 0.0, "long": 0, "late_s": 0.0, "work_s": 0.0, "read_s": 0.0}
        gap = np.diff(r[:, 0])
        prev, cur = r[:-1], r[1:]
        slept = np.isfinite(cur[:, 2])
        late = np.where(slept, cur[:, 4] - cur[:, 2] - cur[:, 3], 0.0)
        work = np.where(slept, cur[:, 2], cur[:, 0]) - prev[:, 1]
        long = gap > LONG_GAP_S
        return {
            "worst_s": float(gap.max()),
            "long": int(long.sum()),
            "late_s": float(late[long].sum()),
            "work_s": float(work[long].sum()),
            "read_s": float((prev[long, 1] - prev[long, 0]).sum()),
        }


class NoView:
    """The live view's running-calibration panel, shown nowhere (the fit still runs)."""

    def running_calibration(self, text: str) -> None:
        pass


def run(kind: str, seconds: float, poll_s: float, out: Path, fill: float | None = None) -> dict:
    """One recording in this (pool) process, BLAS on one thread as `accellog record` runs it
    (cli._one_blas_thread): a BLAS worker thread at normal priority would hold up the read loop."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _run(kind, seconds, poll_s, out, fill)


def _run(kind: str, seconds: float, poll_s: float, out: Path, fill: float | None) -> dict:
    if fill is not None:  # the fraction of the FIFO allowed to fill between reads
        Recorder.FILL_TARGET = fill
    base = kind.split("+")[0]
    guided = "+cal" in kind  # six guided poses with the running calibration after each hold
    hold_s = max((seconds - 20.0) / 6.0, 2.0)
    sc = Scenario(protocol="six" if guided else "+z", hold_s=hold_s + 6.0 if guided else seconds + 30.0,
                  sample_rate_hz=1000.0, seed=1)  # fmt: skip
    clock = RealClock()
    timed: dict = {}
    _chip, drv, _ = make_chain(sc, clock, mag=True, timed=timed)
    cls = BeforeRecorder if base == "before" else Recorder
    probe = GapProbe(drv, time.sleep)
    extra = {"write_thread": base != "inline"} if base in ("inline", "adaptive") else {}
    if guided:
        extra["on_pose"] = RunningCalibration(NoView())
    with SessionWriter(out, meta_for(drv)) as w:
        drv.start()
        time.sleep(0.05)  # what opening files, viewers and printing costs before the loop starts
        rec = cls(drv, w, sleep=probe.sleep, poll_s=poll_s, read_mag=True, **extra)
        timed["chip_s"] = 0.0
        c0, w0 = cpu_s(), time.perf_counter()
        end = w0 + seconds
        try:  # the loop's thread raised as in `accellog record` (its helper threads are not)
            with raised_priority() if "+rt" in kind else contextlib.nullcontext("normal") as prio:
                if guided:
                    rec.run(parse_protocol("six", hold_s))
                while time.perf_counter() < end and not guided:
                    rec.step()
        finally:
            close = getattr(rec, "close", None)
            if close is not None:
                close()
        c1, w1 = cpu_s(), time.perf_counter()
    summ = rec.summary
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
        "reads": rec.reads,
        "priority": prio,
        "gaps": probe.summary(),
        "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


class Background:
    """The load processes of one level; ``cores()`` = their CPU time / wall time so far."""

    def __init__(self, kind: str, level: float, wd: Path) -> None:
        n = round(level) if kind == "busy" else round(level / DUTY)
        target = spin if kind == "busy" else functools.partial(mixed, reuse=kind == "mixed-reuse")
        self.stop = mp.Event()
        self.cpu = [mp.Value("d", 0.0) for _ in range(n)]
        self.procs = [
            mp.Process(target=target, args=(self.stop, i, wd / f"load{i}.bin", self.cpu[i]), daemon=True)
            for i in range(n)
        ]
        self.t0 = time.perf_counter()
        for p in self.procs:
            p.start()

    def finish(self) -> float:
        """Stop the workers; their CPU time in cores (CPU s / wall s)."""
        self.stop.set()
        for p in self.procs:
            p.join(10)
        return sum(c.value for c in self.cpu) / (time.perf_counter() - self.t0)


def cpu_ticks() -> tuple[int, int]:
    """(steal, total) CPU ticks of the machine since boot (/proc/stat; (0, 0) elsewhere)."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:9]]
    except (OSError, ValueError):
        return 0, 0
    return v[7], sum(v)


class LoadSampler:
    """Mean of the 1-minute load average, sampled every second on a thread of this process, and the
    share of CPU time the hypervisor stole from this virtual machine meanwhile (``steal()``)."""

    def __init__(self) -> None:
        self.ticks0 = cpu_ticks()
        self.values: list[float] = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()

    def _run(self) -> None:
        while not self._stop.wait(1.0):
            self.values.append(os.getloadavg()[0])

    def steal(self) -> float:
        """Stolen CPU time / all CPU time since the start (0..1)."""
        (s0, t0), (s1, t1) = self.ticks0, cpu_ticks()
        return (s1 - s0) / max(t1 - t0, 1)

    def mean(self) -> float:
        self._stop.set()
        self._t.join()
        return float(np.mean(self.values)) if self.values else os.getloadavg()[0]


COLUMNS = ("load", "loop", "samples", "lost", "lost %", "overflows", "worst gap",
           "long gaps: late / work / read", "recorder CPU", "background", "load avg", "steal")  # fmt: skip


def row(level: float, kind: str, r: dict, bg_cores: float, load: float, steal: float) -> list[str]:
    exp = r["samples"] + r["lost"]
    g, w = r["gaps"], r["wall_s"]
    return [
        f"{level:g}",
        kind,
        str(r["samples"]),
        str(r["lost"]),
        f"{100 * r['lost'] / max(exp, 1):.3f}",
        str(r["overflows"]),
        f"{1e3 * g['worst_s']:.0f} ms",
        f"{g['long']}: {1e3 * g['late_s']:.0f} / {1e3 * g['work_s']:.0f} / {1e3 * g['read_s']:.0f} ms",
        f"{100 * (r['cpu_s'] - r['chip_s']) / w:.1f} %",
        f"{bg_cores:.2f} cores",
        f"{load:.1f}",
        f"{100 * steal:.1f} %",
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="wall seconds per recording")
    ap.add_argument("--load", type=float, nargs="+", default=[1.0, 2.0, 4.0], help="background load levels")
    ap.add_argument("--load-kind", choices=LOAD_KINDS, default="mixed")
    ap.add_argument("--warmup-s", type=float, default=20.0, help="load before a level's first recording")
    ap.add_argument("--poll-ms", type=float, default=20.0)
    ap.add_argument("--variants", nargs="+", default=["inline+rt", "adaptive+rt"])
    ap.add_argument("--fill", type=float, nargs="+", default=[None], help="Recorder.FILL_TARGET values")
    args = ap.parse_args()
    console = Console(width=160)
    la0 = os.getloadavg()
    tab = Table(
        title=f"live 1 kHz recording beside a {args.load_kind} background load, {args.seconds:g} s per row, "
        f"{os.cpu_count()} cores (goals: lost < 0.1 %, recorder < 10 % of one core)"
    )
    for col in COLUMNS:
        tab.add_column(col, justify="left" if col in ("loop",) else "right")
    peak = 0.0
    with tempfile.TemporaryDirectory(prefix="bench_load_") as wd:
        for level in args.load:
            bg = Background(args.load_kind, level, Path(wd))
            try:
                time.sleep(args.warmup_s)
                results = []
                for kind, fill in ((k, f) for f in args.fill for k in args.variants):
                    sampler = LoadSampler()
                    with mp.Pool(1) as pool:  # a raised priority must not leak into the next row
                        r = pool.apply(
                            run, (kind, args.seconds, args.poll_ms / 1e3, Path(wd) / "r.mcap", fill)
                        )
                    kind = kind if fill is None else f"{kind} fill {fill:g}"
                    results.append((kind, r, sampler.mean(), sampler.steal()))
                    peak = max(peak, r["peak_mb"])
                    console.print(f"done: load {level:g}, {kind}: {r['lost']} lost")
            finally:
                cores = bg.finish()
            for kind, r, load, steal in results:
                tab.add_row(*row(level, kind, r, cores, load, steal))
    console.print(tab)
    console.print(
        f"peak RSS of a recording process {peak:.0f} MB; load average before the run {la0[0]:.1f}, "
        f"after {os.getloadavg()[0]:.1f} (a shared machine: other jobs add to the background load)"
    )


if __name__ == "__main__":
    main()
