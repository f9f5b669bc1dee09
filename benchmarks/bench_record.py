"""Recording speed: simulated sessions as a multiple of real time, and CPU share when recording live.

(a) Simulated recording (goal >= 100x real time): a 1 kHz six-position session through the whole
    path ``accellog.flows.simulate.simulate`` uses (emulated chip -> Mpu9250 FIFO driver -> Recorder ->
    SessionWriter MCAP, plus pose labels and the truth channel) on a SimClock, for --minutes
    simulated minutes each (default 10 and 60). Side by side on the 10-minute session, the parts:
    Recorder + SessionWriter without labels/truth, the same with stillness detection switched off,
    and driver + chip reads alone (no Recorder, no file).
(b) Live recording (goal < 10 % of one core): the same Recorder loop as ``accellog record --sim``
    (20 ms polls, magnetometer at 100 Hz, MCAP writer flushing every 0.5 s) on the RealClock for
    --live-s seconds of wall time, once per --poll-ms (20 ms is the Recorder's default; 10 ms shows
    what halving it costs and saves). CPU = process time (user + sys, resource.getrusage) / wall time.
    The emulator's own work (register file, FIFO, sample generation in SensorModel) is timed
    inside the chip's bus methods (thread CPU time) and subtracted: what is left is what the
    recorder costs on real hardware (where the bus transfers are kernel ioctls instead).

    python benchmarks/bench_record.py [--minutes 10 60] [--live-s 20] [--poll-ms 20 10]
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.table import Table

from accellog.acquire.driver import Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import RealClock, SimClock
from accellog.acquire.recorder import Recorder
from accellog.acquire.stillness import StillnessDetector
from accellog.core.session import SessionMeta
from accellog.flows.record import LIVE_BLOCK_SAMPLES
from accellog.flows.simulate import Scenario, build_sensor_model, simulate
from accellog.store.reader import read_session
from accellog.store.writer import SessionWriter

BUS_METHODS = ("read_byte_data", "write_byte_data", "read_i2c_block_data", "write_i2c_block_data", "i2c_rdwr")


def scenario_for(minutes: float, rate_hz: float = 1000.0) -> Scenario:
    """Six poses whose holds fill ``minutes``: 1 s start delay + 6 holds + 5 moves of 3 s."""
    hold = (minutes * 60.0 - 1.0 - 5 * 3.0) / 6.0
    return Scenario(protocol="six", hold_s=hold, sample_rate_hz=rate_hz, seed=1)


class NoStillness(StillnessDetector):
    """Stillness detection switched off (update does nothing): isolates its cost in run_for."""

    def update(self, t_s, accel_g, gyro_dps=None) -> bool:
        return False


def cpu_s() -> float:
    """User + system CPU time of this process (s), all threads."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def make_chain(sc: Scenario, clock, *, mag: bool = False, timed: dict | None = None):
    """Emulated chip + configured, started driver for a scenario (as simulate / record --sim do;
    on the real clock with record --sim's LIVE_BLOCK_SAMPLES).

    timed: if given, the chip's bus methods add their thread CPU time (s) to timed['chip_s'].
    """
    model, motion = build_sensor_model(sc)
    block = {"block_samples": LIVE_BLOCK_SAMPLES} if isinstance(clock, RealClock) else {}
    chip = EmulatedMpu9250(model, clock, seed=sc.seed, **block)
    if timed is not None:
        timed.setdefault("chip_s", 0.0)
        for name in BUS_METHODS:
            fn = getattr(chip, name)

            def wrapper(*a, _fn=fn, **kw):
                t0 = time.thread_time()
                try:
                    return _fn(*a, **kw)
                finally:
                    timed["chip_s"] += time.thread_time() - t0

            setattr(chip, name, wrapper)
    drv = Mpu9250(chip, clock_ns=clock.now_ns)
    drv.probe()
    drv.configure(sample_rate_div=sc.sample_rate_div)
    if mag:
        drv.enable_magnetometer()
    return chip, drv, motion


def meta_for(drv: Mpu9250) -> SessionMeta:
    c = drv.config
    return SessionMeta(
        source="emulator",
        accel_lsb_per_g=c.accel_lsb_per_g,
        gyro_lsb_per_dps=c.gyro_lsb_per_dps,
        sample_rate_hz=c.sample_rate_hz,
    )


def timed_call(fn) -> tuple[float, float, int, float]:
    """(wall s, CPU s, samples, simulated s) of fn() -> (samples, simulated s)."""
    c0, t0 = cpu_s(), time.perf_counter()
    n, sim_s = fn()
    return time.perf_counter() - t0, cpu_s() - c0, n, sim_s


def run_simulate(sc: Scenario, out: Path) -> tuple[int, float]:
    """Whole path: accellog.flows.simulate.simulate. (samples, simulated s)."""
    s = simulate(sc, out)
    return s.samples, s.duration_s


def run_recorder(sc: Scenario, out: Path, seconds: float, stillness: bool = True) -> tuple[int, float]:
    """Recorder.run_for + SessionWriter on a SimClock (no labels, no truth)."""
    clock = SimClock()
    _chip, drv, _ = make_chain(sc, clock)
    with SessionWriter(out, meta_for(drv)) as w:
        drv.start()
        rec = Recorder(
            drv, w, sleep=clock.sleep, poll_s=0.025, stillness=None if stillness else NoStillness()
        )
        rec.run_for(seconds)
    return rec.summary.samples, rec.t_s


def run_reads(sc: Scenario, seconds: float) -> tuple[int, float]:
    """Driver + chip alone: Mpu9250.read every 25 ms of simulated time."""
    clock = SimClock()
    _chip, drv, _ = make_chain(sc, clock)
    drv.start()
    n = 0
    for _ in range(round(seconds / 0.025)):
        clock.sleep(0.025)
        n += drv.read().n
    return n, n / drv.config.sample_rate_hz


def run_live(seconds: float, out: Path, poll_s: float = 0.02) -> dict:
    """Recorder on the RealClock (as `accellog record --sim`): CPU time of the process and of the chip."""
    sc = Scenario(protocol="six", hold_s=seconds + 10.0, seed=1)
    clock = RealClock()
    timed: dict = {}
    _chip, drv, _ = make_chain(sc, clock, mag=True, timed=timed)
    with SessionWriter(out, meta_for(drv)) as w:
        drv.start()
        rec = Recorder(drv, w, sleep=time.sleep, poll_s=poll_s, read_mag=True)
        timed["chip_s"] = 0.0
        c0, w0 = cpu_s(), time.perf_counter()
        end = w0 + seconds
        while time.perf_counter() < end:
            rec.step()
        c1, w1 = cpu_s(), time.perf_counter()
    s = read_session(out)
    return {
        "wall_s": w1 - w0,
        "cpu_s": c1 - c0,
        "chip_s": timed["chip_s"],
        "samples": rec.summary.samples,
        "lost": s.lost_samples(),
        "file_samples": s.n,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[10.0, 60.0], help="simulated minutes")
    ap.add_argument("--live-s", type=float, default=20.0, help="wall seconds of each live (RealClock) run")
    ap.add_argument(
        "--poll-ms", type=float, nargs="+", default=[20.0, 10.0], help="Recorder poll periods (ms)"
    )
    args = ap.parse_args()
    os.environ.setdefault("RERUN_ANALYTICS", "0")
    console = Console(width=130)
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench_record_") as wd:
        d = Path(wd)
        m0 = min(args.minutes)
        sc0 = scenario_for(m0)
        rows = [
            (f"simulate(): whole path, {m:g}", lambda m=m: run_simulate(scenario_for(m), d / "r.mcap"))
            for m in args.minutes
        ]
        rows += [
            (
                f"Recorder + SessionWriter (no truth/labels), {m0:g}",
                lambda: run_recorder(sc0, d / "r.mcap", m0 * 60),
            ),
            (
                f"  same, stillness detection off, {m0:g}",
                lambda: run_recorder(sc0, d / "r.mcap", m0 * 60, stillness=False),
            ),
            (f"driver + chip reads only (no file), {m0:g}", lambda: run_reads(sc0, m0 * 60)),
        ]
        tab = Table(
            title=f"(a) simulated 1 kHz recording on a SimClock (goal >= 100x real time); load average {load:.1f}"
        )
        for col in (
            "path, simulated minutes",
            "samples",
            "wall s",
            "CPU s",
            "x real time (wall)",
            "x (CPU)",
            "MB",
        ):
            tab.add_column(col, justify="left" if col.startswith("path") else "right")
        for name, fn in rows:
            wall, cpu, n, sim_s = timed_call(fn)
            out = d / "r.mcap"
            mb = f"{out.stat().st_size / 1e6:.1f}" if out.exists() else "-"
            out.unlink(missing_ok=True)
            tab.add_row(
                name, f"{n}", f"{wall:.2f}", f"{cpu:.2f}", f"{sim_s / wall:.0f}", f"{sim_s / cpu:.0f}", mb
            )
        console.print(tab)
        console.print("(x (CPU) = simulated time / process CPU time: the figure on an idle core)")

        tab2 = Table(
            title=f"(b) live 1 kHz recording, RealClock, {args.live_s:g} s each (goal < 10 % of one core)"
        )
        for col in (
            "poll",
            "process CPU",
            "inside the emulated chip",
            "recorder alone (hardware)",
            "lost samples",
        ):
            tab2.add_column(col, justify="left" if col == "poll" else "right")
        for poll_ms in args.poll_ms:
            live = run_live(args.live_s, d / "live.mcap", poll_s=poll_ms / 1000.0)
            w = live["wall_s"]
            rest = live["cpu_s"] - live["chip_s"]
            tab2.add_row(
                f"{poll_ms:g} ms",
                *(f"{100 * c / w:.1f} %" for c in (live["cpu_s"], live["chip_s"], rest)),
                f"{live['lost']} of {live['file_samples'] + live['lost']}",
            )
        console.print(tab2)
        console.print(
            "(share of one core = CPU s / wall s; recorder alone = process minus the chip's bus methods. Lost "
            "samples: FIFO overflows (36 samples = 36 ms at 1 kHz) when the process is descheduled longer than "
            f"36 ms - poll; each is an event. Load average now {os.getloadavg()[0]:.1f})"
        )


if __name__ == "__main__":
    main()
