"""The recording loop: driver -> MCAP writer, with guided poses and labelled holds.

``Recorder.run`` drains the chip's FIFO continuously (every sample of the whole session is
written, moves included), tells the operator which pose is next, waits until the sensor has moved
and then been still for ``settle_s`` (automatic stillness detection) or until the operator presses
Enter, holds for the pose's duration, and writes a PoseLabel for the hold. Ctrl-C (or any error)
finishes the file cleanly: the writer's context closes the MCAP with an event saying why.
"""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from accellog.acquire.handoff import Handoff
from accellog.acquire.registers import FIFO_SIZE_BYTES, PACKET_BYTES
from accellog.acquire.stillness import StillnessDetector
from accellog.core.protocol import PoseSpec
from accellog.core.session import Event, PoseLabel, SessionMeta

NS = 1_000_000_000


def session_meta(info, cfg, *, source: str, protocol: str, **fields) -> SessionMeta:
    """SessionMeta of a recording from the driver's ChipInfo and DriverConfig (+ extra fields, e.g.
    the device identity: serial, i2c_bus, i2c_address, ak8963_wia; see accellog.core.device)."""
    import platform

    from accellog.core.version import __version__

    return SessionMeta(
        source=source,
        chip=info.model if source == "hardware" else f"emulated {info.model}",
        who_am_i=info.who_am_i,
        accel_range_g=float(cfg.accel_range_g),
        gyro_range_dps=float(cfg.gyro_range_dps),
        accel_lsb_per_g=cfg.accel_lsb_per_g,
        gyro_lsb_per_dps=cfg.gyro_lsb_per_dps,
        dlpf_cfg=cfg.dlpf_cfg,
        a_dlpf_cfg=cfg.a_dlpf_cfg,
        sample_rate_hz=cfg.sample_rate_hz,
        software=f"accellog {__version__}",
        protocol=protocol,
        **{"host": platform.node(), **fields},
    )


@contextlib.contextmanager
def raised_priority(rt_priority: int = 20, nice: int = -10) -> Iterator[str]:
    """Within the block the OS runs the calling thread (the read loop) before ordinary work, so that
    a busy host does not hold it off longer than the FIFO lasts (36 ms at 1 kHz): SCHED_RR at
    rt_priority (needs root, CAP_SYS_NICE or an rtprio limit), else a lower nice value; yields what
    it got, for the session's events. The loop uses < 10 % of a core, and Linux caps real-time
    threads at 95 % of the CPU, so the rest of the system keeps running. On leaving, the thread's
    scheduling is restored (threads it starts meanwhile inherit the raised one: start them before)."""
    import os

    try:
        before = (os.sched_getscheduler(0), os.sched_getparam(0))
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(rt_priority))
    except (AttributeError, OSError):
        pass
    else:
        try:
            yield f"read loop scheduled SCHED_RR priority {rt_priority}"
        finally:
            os.sched_setscheduler(0, *before)
        return
    try:
        was = got = os.nice(0)
        if nice < got:
            got = os.nice(nice - got)
    except OSError:
        yield "read loop at normal priority (no permission to raise it)"
        return
    try:
        yield f"read loop at nice {got} (no permission for real-time scheduling)"
    finally:
        with contextlib.suppress(OSError):
            os.nice(was - os.nice(0))


class StopRequested(Exception):
    """The operator asked to stop (Ctrl-C, SIGTERM). Raised only between FIFO reads, so the MCAP
    writer is never interrupted half-way through a message and the file can be finished cleanly."""


class RecorderUI(Protocol):
    """What the loop tells the operator (terminal, live viewer, or nothing)."""

    def prompt(self, index: int, total: int, pose: PoseSpec) -> None: ...
    def waiting(self, moving: bool, still_for_s: float) -> None: ...
    def holding(self, pose: PoseSpec, done_s: float) -> None: ...
    def finished_pose(self, label: PoseLabel) -> None: ...


class QuietUI:
    """A RecorderUI that shows nothing (tests, simulation)."""

    def prompt(self, index: int, total: int, pose: PoseSpec) -> None:
        pass

    def waiting(self, moving: bool, still_for_s: float) -> None:
        pass

    def holding(self, pose: PoseSpec, done_s: float) -> None:
        pass

    def finished_pose(self, label: PoseLabel) -> None:
        pass


class EnterKey:
    """Non-blocking 'operator pressed Enter' flag read from stdin on a daemon thread."""

    def __init__(self) -> None:
        self._event = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        for _line in sys.stdin:
            self._event.set()

    def pressed(self) -> bool:
        if self._event.is_set():
            self._event.clear()
            return True
        return False


@dataclass
class RecordSummary:
    """What a recording produced (counts, not data)."""

    samples: int = 0
    batches: int = 0
    lost_samples: int = 0
    events: list[Event] = field(default_factory=list)
    poses: list[PoseLabel] = field(default_factory=list)
    duration_s: float = 0.0
    interrupted: bool = False


class Recorder:
    """Connects a configured, started ``Mpu9250`` driver to a ``SessionWriter``.

    sleep: how to wait between FIFO reads (real ``time.sleep`` or a simulated clock's sleep).
    poll_s: longest time between FIFO reads (s). The 512-byte FIFO holds 36 samples (36 ms at
    1 kHz), so the loop adapts (see ``read_period_s``): it reads at least every FILL_TARGET of the
    FIFO's capacity, measures the wait from the start of the previous read (time spent reading and
    writing counts), and reads again at once when a read found the FIFO more than half full. A
    long poll therefore never livelocks in overflow/reset cycles.
    on_batch: optional callback (e.g. a live Rerun view) given every batch; it must not raise.
    on_pose: optional callback (label, mean_g (3,), std_g (3,), n) after every labelled hold.
    stop: optional event (set by a signal handler); the loop stops at the next FIFO read.
    write_thread: hand the MCAP writes, on_batch, on_pose and the UI calls to one helper thread
    (accellog.acquire.handoff, in order), so the reading thread only reads the FIFO and tracks
    stillness; ``close()`` then writes what is still queued. Off by default and in ``accellog
    record``: on a loaded 2-core host it did not lower the loss (benchmarks/bench_record_load.py,
    ``adaptive`` vs ``inline``) and costs 1.5-2.5 % more of a core; for writes that block (slow
    storage).
    """

    def __init__(
        self,
        driver,
        writer,
        *,
        sleep: Callable[[float], None] = time.sleep,
        poll_s: float = 0.02,
        ui: RecorderUI | None = None,
        stillness: StillnessDetector | None = None,
        on_batch: Callable[[object, np.ndarray], None] | None = None,
        on_pose: Callable[[PoseLabel, np.ndarray, np.ndarray, int], None] | None = None,
        read_mag: bool = False,
        stop: threading.Event | None = None,
        write_thread: bool = False,
    ) -> None:
        self.driver = driver
        self.writer = writer
        self.sleep = sleep
        self.poll_s = poll_s
        self.ui = ui or QuietUI()
        self.stillness = stillness or StillnessDetector()
        self.on_batch = on_batch
        self.on_pose = on_pose
        self.read_mag = read_mag
        self.stop = stop
        self.handoff = Handoff(threaded=write_thread)
        self.post = self.handoff.post
        """post(fn, *args): run fn after everything the loop wrote so far (on the helper thread)."""
        self._hold_sum = np.zeros(3)
        self._hold_sq = np.zeros(3)
        self._hold_n = 0
        self._holding = False
        self._hold_first_s: float | None = None
        self.summary = RecordSummary()
        self._t_last_s = 0.0
        self._last_read_ns: int | None = None
        self._catch_up = False
        self.reads = 0

    # -- timing ----------------------------------------------------------------------------------
    FILL_TARGET = 0.4
    """Fraction of the FIFO's capacity allowed to fill between reads (0.4 x 36 ms at 1 kHz)."""

    @property
    def read_period_s(self) -> float:
        """Time between FIFO reads: min(poll_s, FILL_TARGET * 36 packets / ODR) (s)."""
        cfg = getattr(self.driver, "config", None)
        rate = getattr(cfg, "sample_rate_hz", None)
        if not rate:
            return self.poll_s
        return min(self.poll_s, self.FILL_TARGET * (FIFO_SIZE_BYTES // PACKET_BYTES) / rate)

    def _wait(self) -> None:
        clock = getattr(self.driver, "clock_ns", None)
        if self._catch_up:
            self._catch_up = False
            return
        period = self.read_period_s
        if clock is None or self._last_read_ns is None:
            self.sleep(period)
            return
        left = period - (int(clock()) - self._last_read_ns) * 1e-9
        if left > 0:
            self.sleep(left)

    def _flush_before_first_read(self) -> None:
        """Discard what the FIFO gathered between start() and the first read (configuration,
        opening files and viewers): the stream restarts at index 0, so no overflow at t = 0."""
        if (
            self.reads == 0
            and getattr(self.driver, "next_index", None) == 0
            and hasattr(self.driver, "start")
        ):
            self.driver.start()

    # -- one read --------------------------------------------------------------------------------
    def step(self, *, detect_stillness: bool = True) -> None:
        """Wait one poll period, read the FIFO, write the batch and its events, update stillness
        (skipped with detect_stillness=False: unguided recording does not need it).
        Raises StopRequested (before reading) once the stop event is set."""
        if self.stop is not None and self.stop.is_set():
            raise StopRequested
        if self.reads == 0:
            self._flush_before_first_read()
        self._wait()
        clock = getattr(self.driver, "clock_ns", None)
        self._last_read_ns = int(clock()) if clock is not None else None
        batch = self.driver.read()
        self.reads += 1
        post = self.post
        for ev in batch.events:
            post(self.writer.write_event, ev)
            self.summary.events.append(ev)
            self.summary.lost_samples += ev.lost_samples
        n = len(batch.t_ns)
        self._catch_up = n >= (FIFO_SIZE_BYTES // PACKET_BYTES) // 2  # behind: read again at once
        if n:
            post(
                self.writer.write_imu,
                batch.first_index,
                batch.t_ns,
                accel_counts=batch.accel_counts,
                gyro_counts=batch.gyro_counts,
                temp_counts=batch.temp_counts,
                host_time_ns=batch.host_time_ns,
            )
            self.summary.samples += n
            self.summary.batches += 1
            t_s = batch.t_ns / NS
            self._t_last_s = float(t_s[-1])
            cfg = self.driver.config
            accel_g = batch.accel_counts / cfg.accel_lsb_per_g
            gyro_dps = batch.gyro_counts / cfg.gyro_lsb_per_dps
            if detect_stillness:
                self.stillness.update(t_s, accel_g, gyro_dps)
            if self._holding:
                if self._hold_first_s is None:
                    self._hold_first_s = float(t_s[0])
                self._hold_sum += accel_g.sum(axis=0)
                self._hold_sq += (accel_g**2).sum(axis=0)
                self._hold_n += n
            if self.on_batch is not None:
                post(self.on_batch, batch, accel_g)
        if self.read_mag:
            mag = self.driver.read_mag()
            if mag is not None:
                post(self.writer.write_mag_reading, mag)

    def close(self) -> None:
        """Write everything still handed to the helper thread and stop it (idempotent); raises a
        write's error. Call it before the SessionWriter closes."""
        self.handoff.close()

    @property
    def t_s(self) -> float:
        """Sensor time of the newest sample (s)."""
        return self._t_last_s

    def run_for(self, seconds: float) -> None:
        """Record without prompting for ``seconds`` of sensor time."""
        end = self.t_s + seconds
        while self.t_s < end:
            self.step(detect_stillness=False)

    # -- guided protocol -------------------------------------------------------------------------
    def run(
        self,
        poses: Sequence[PoseSpec],
        *,
        wait: str = "auto",
        timeout_s: float = 120.0,
        enter: EnterKey | None = None,
    ) -> RecordSummary:
        """Guide the operator through ``poses`` and label each hold.

        wait: 'auto' (stillness detection: after the first pose the sensor must first move, then be
        still for settle_s) or 'enter' (the operator presses Enter when the pose is set).
        A pose whose stillness is not reached within timeout_s is recorded as an event and skipped.
        """
        if wait == "enter" and enter is None:
            enter = EnterKey()
        for k, pose in enumerate(poses):
            self.post(self.ui.prompt, k, len(poses), pose)
            prompt = f"pose {k + 1}/{len(poses)}: {pose.name}"
            self.post(self.writer.write_event, Event(self.t_s, "pose_prompt", prompt))
            if not self._wait_ready(k, wait, timeout_s, enter):
                ev = Event(self.t_s, "note", f"pose {pose.name}: not still within {timeout_s:g} s, skipped")
                self.post(self.writer.write_event, ev)
                self.summary.events.append(ev)
                continue
            start = self.t_s
            moved = False
            self._hold_sum[:], self._hold_sq[:], self._hold_n, self._holding = 0.0, 0.0, 0, True
            self._hold_first_s = None
            while self.t_s - start < pose.hold_s:
                self.step()
                self.post(self.ui.holding, pose, self.t_s - start)
                if not self.stillness.still:
                    moved = True
            self._holding = False
            # [first hold sample, last hold sample + one period): exactly the samples of the hold
            first = self._hold_first_s if self._hold_first_s is not None else start
            end = self.t_s + 1.0 / self.driver.config.sample_rate_hz
            label = PoseLabel(pose.name, first, end, pose.up_sensor, pose.q_sensor_to_world, k)
            if moved:
                ev = Event(start, "note", f"pose {pose.name}: sensor moved during the hold")
                self.post(self.writer.write_event, ev)
                self.summary.events.append(ev)
            self.post(self.writer.write_pose, label)
            self.summary.poses.append(label)
            self.post(self.ui.finished_pose, label)
            if self.on_pose is not None and self._hold_n > 1:
                mean = self._hold_sum / self._hold_n
                std = np.sqrt(np.maximum(self._hold_sq / self._hold_n - mean**2, 0.0))
                self.post(self.on_pose, label, mean, std, self._hold_n)
        self.summary.duration_s = self.t_s
        return self.summary

    def _wait_ready(self, k: int, wait: str, timeout_s: float, enter: EnterKey | None) -> bool:
        start = self.t_s
        moved = k == 0
        while self.t_s - start < timeout_s:
            self.step()
            if wait == "enter":
                if enter is not None and enter.pressed():
                    return True
                continue
            if not self.stillness.still:
                moved = True
            self.post(self.ui.waiting, not self.stillness.still, self.stillness.still_for_s)
            if moved and self.stillness.settled:
                return True
        return False
