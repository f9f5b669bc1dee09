"""Worst-case CPU time of one iteration of the recording loop, step by step (issue 27 item 6).

The FIFO holds 36 ms at 1 kHz: one iteration of the read loop that works longer than a few ms
eats into that margin whatever the scheduler does. This runs the path of ``accellog record --sim``
(emulated MPU-9250 -> Mpu9250 FIFO driver -> Recorder -> SessionWriter MCAP, magnetometer at 100 Hz,
stillness detection, a guided six-pose session with the live view's running calibration refitted
after every hold) on a simulated clock, so the figures are CPU time of the loop's thread
(``time.thread_time``) and do not depend on how loaded the machine is. Per iteration it charges:

- ``chip``: the emulated chip's bus methods (on hardware the chip does this work itself);
- ``read``: the driver's FIFO read minus ``chip``; ``mag``: the magnetometer read minus ``chip``;
- ``write``: the SessionWriter calls (MCAP messages, zstd chunk flushes);
- ``stillness``: the stillness detector; ``on_pose``: the running calibration refit;
- ``gc``: Python's cyclic garbage collector (gc.callbacks);
- ``loop``: the whole iteration (from one wait to the next) minus ``chip``: what the recorder
  itself costs.

Reports max, 99.9th and 99th percentile and mean per step (ms), and how many iterations did more
than 3 ms of work.

    python benchmarks/bench_record_steps.py [--seconds 120] [--repeat 1]
"""

from __future__ import annotations

import argparse
import gc
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_record import BUS_METHODS, meta_for
from rich.console import Console
from rich.table import Table

from accellog.acquire.driver import Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.recorder import Recorder
from accellog.core.protocol import parse_protocol
from accellog.flows.record import RunningCalibration
from accellog.flows.simulate import Scenario, build_sensor_model
from accellog.store.writer import SessionWriter

STEPS = ("loop", "chip", "read", "write", "stillness", "mag", "on_pose", "gc")


class NoView:
    def running_calibration(self, text: str) -> None:
        pass


class Meter:
    """Thread CPU time (s) charged to named steps during the current iteration."""

    def __init__(self) -> None:
        self.cur = dict.fromkeys(STEPS, 0.0)
        self.rows: list[list[float]] = []
        self._gc_t0 = 0.0

    def wrap(self, obj, name: str, step: str) -> None:
        fn = getattr(obj, name)
        cur = self.cur

        def timed(*a, _fn=fn, **kw):
            t0 = time.thread_time()
            try:
                return _fn(*a, **kw)
            finally:
                cur[step] += time.thread_time() - t0

        setattr(obj, name, timed)

    def gc_callback(self, phase: str, _info: dict) -> None:
        if phase == "start":
            self._gc_t0 = time.thread_time()
        else:
            self.cur["gc"] += time.thread_time() - self._gc_t0

    def end_iteration(self, loop_s: float) -> None:
        c = self.cur
        c["loop"] = loop_s - c["chip"]
        self.rows.append([c[s] for s in STEPS])
        for s in STEPS:
            c[s] = 0.0


def measure(seconds: float, out: Path, block: int | None = None) -> np.ndarray:
    """(iterations, len(STEPS)) thread CPU seconds of one guided +cal session on a SimClock."""
    hold_s = max((seconds - 20.0) / 6.0, 2.0)
    sc = Scenario(protocol="six", hold_s=hold_s + 6.0, sample_rate_hz=1000.0, seed=1)
    model, _motion = build_sensor_model(sc)
    clock = SimClock()
    kw = {} if block is None else {"block_samples": block}
    chip = EmulatedMpu9250(model, clock, seed=sc.seed, **kw)
    m = Meter()
    chip_total = [0.0]
    for name in BUS_METHODS:  # chip time: counted once, subtracted from read/mag below
        fn = getattr(chip, name)

        def bus(*a, _fn=fn, **kw):
            t0 = time.thread_time()
            try:
                return _fn(*a, **kw)
            finally:
                dt = time.thread_time() - t0
                m.cur["chip"] += dt
                chip_total[0] += dt

        setattr(chip, name, bus)
    drv = Mpu9250(chip, clock_ns=clock.now_ns)
    drv.probe()
    drv.configure(sample_rate_div=sc.sample_rate_div)
    drv.enable_magnetometer()
    cal = RunningCalibration(NoView())
    with SessionWriter(out, meta_for(drv)) as w:
        drv.start()
        t_it = [time.thread_time()]

        def sleep(s: float) -> None:  # an iteration: from one wait to the next
            t = time.thread_time()
            m.end_iteration(t - t_it[0])
            clock.sleep(s)
            t_it[0] = time.thread_time()

        rec = Recorder(drv, w, sleep=sleep, read_mag=True, on_pose=cal)
        for name in ("write_imu", "write_event", "write_mag_reading", "write_pose"):
            m.wrap(w, name, "write")
        m.wrap(rec.stillness, "update", "stillness")
        for name, step in (("read", "read"), ("read_mag", "mag")):
            fn = getattr(drv, name)

            def net(*a, _fn=fn, _step=step, **kw):  # the driver's own time, without the chip's
                c0, t0 = m.cur["chip"], time.thread_time()
                try:
                    return _fn(*a, **kw)
                finally:
                    m.cur[_step] += time.thread_time() - t0 - (m.cur["chip"] - c0)

            setattr(drv, name, net)
        rec.on_pose = lambda *a: _timed(m, "on_pose", cal, *a)
        gc.callbacks.append(m.gc_callback)
        try:
            rec.run(parse_protocol("six", hold_s))
        finally:
            gc.callbacks.remove(m.gc_callback)
            rec.close()
    return np.array(m.rows[1:])  # the first: set-up before the first wait


def _timed(m: Meter, step: str, fn, *a) -> None:
    t0 = time.thread_time()
    try:
        fn(*a)
    finally:
        m.cur[step] += time.thread_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0, help="simulated seconds per session")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--block", type=int, default=None, help="the emulated chip's block_samples")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_steps_") as wd:
        r = np.vstack(
            [measure(args.seconds, Path(wd) / f"s{k}.mcap", args.block) for k in range(args.repeat)]
        )
    tab = Table(
        title=f"CPU ms per iteration of the read loop, {len(r)} iterations (guided six poses + running calibration, 1 kHz)"
    )
    for col in ("step", "max", "p99.9", "p99", "mean", "iterations > 3 ms"):
        tab.add_column(col, justify="left" if col == "step" else "right")
    for k, s in enumerate(STEPS):
        v = 1e3 * r[:, k]
        tab.add_row(s, f"{v.max():.2f}", f"{np.percentile(v, 99.9):.2f}", f"{np.percentile(v, 99):.2f}",
                    f"{v.mean():.3f}", str(int((v > 3.0).sum())))  # fmt: skip
    console = Console(width=140)
    console.print(tab)
    worst = np.argsort(r[:, 0])[::-1][:5]
    console.print(
        "worst iterations (ms): "
        + "; ".join(
            ", ".join(f"{s} {1e3 * r[i, k]:.2f}" for k, s in enumerate(STEPS) if r[i, k] >= 1e-4)
            for i in worst
        )
    )


if __name__ == "__main__":
    main()
