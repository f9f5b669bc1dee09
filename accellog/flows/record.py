"""`record`: a guided calibration session from real hardware (smbus2) or the emulated chip into an MCAP file.

The operator is told each pose, the recorder waits for stillness (or Enter), holds, and labels the
hold; an optional live Rerun view shows the raw data and a running calibration. A stop request
(``stop`` event, set by Ctrl-C/SIGTERM handlers of the caller) ends the recording at the next FIFO
read and the file is finished cleanly.
"""

from __future__ import annotations

import contextlib
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from accellog.acquire.device import configure_device, open_hardware_bus, parse_address, sample_rate_div
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import RealClock, SimClock
from accellog.acquire.recorder import (
    Recorder,
    RecorderUI,
    RecordSummary,
    StopRequested,
    raised_priority,
    session_meta,
)
from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.observe.segment import obs_from_pose_means
from accellog.core.device import check_serial
from accellog.core.errors import AccellogError, InputError
from accellog.core.protocol import parse_protocol
from accellog.core.session import Event, PoseLabel
from accellog.flows.simulate import Scenario, build_sensor_model
from accellog.present.rrd.live import LiveView
from accellog.present.tables import params_table
from accellog.present.views import table_markdown
from accellog.store.atomic import check_output
from accellog.store.writer import DEFAULT_COMPRESSION, SessionWriter, check_compression

WAIT_MODES = ("auto", "enter")


@dataclass
class RecordOptions:
    """What `accellog record` was asked for (units in names; see the CLI help)."""

    out: Path
    sim: bool = False
    bus: int | None = None
    address: str = "0x68"
    protocol: str = "six"
    hold_s: float = 30.0
    wait: str = "auto"
    rate_hz: float = 1000.0
    accel_range_g: int = 2
    gyro_range_dps: int = 250
    dlpf: int = 3
    mag: bool = True
    fast: bool = False
    seed: int = 1
    rerun: str | None = None
    serial: str = ""
    """The user's serial/name of this sensor (part of the device key)."""
    force: bool = False
    """Replace an existing output file (else an existing session is never overwritten)."""
    compression: str = DEFAULT_COMPRESSION
    """MCAP chunk compression: 'zstd', 'lz4' or 'none' (store.writer.DEFAULT_COMPRESSION)."""

    @property
    def use_sim(self) -> bool:
        return self.sim or self.bus is None

    def validate(self) -> None:
        """One-line InputError for any option the recording cannot use (before anything is opened)."""
        if self.accel_range_g not in (2, 4, 8, 16):
            raise InputError(f"--accel-range {self.accel_range_g}: use 2, 4, 8 or 16 (g)")
        if self.wait not in WAIT_MODES:
            raise InputError(f"--wait {self.wait!r}: use 'auto' or 'enter'")
        parse_protocol(self.protocol, self.hold_s)
        sample_rate_div(self.rate_hz)
        parse_address(self.address)
        check_serial(self.serial)
        check_compression(self.compression)
        check_output(self.out, overwrite=self.force)


@dataclass
class RecordResult:
    """The recording's summary and whether the operator stopped it early."""

    out: Path
    summary: RecordSummary
    notes: list[str]

    @property
    def interrupted(self) -> bool:
        return self.summary.interrupted


class RunningCalibration:
    """Refits the richest seed model the holds so far determine and shows it in the live view.

    The constructor runs the whole fit once on six ideal poses (nothing shown): the first refit
    would otherwise import scipy.optimize during the recording (0.4 s holding the GIL, while the
    reading thread must drain the FIFO every 36 ms)."""

    def __init__(self, live, warn=print) -> None:
        self.live = live
        self.warn = warn
        self.rows: list[tuple[str, tuple, np.ndarray, np.ndarray, int]] = []
        up = np.vstack([np.eye(3), -np.eye(3)])
        with contextlib.suppress(Exception):  # the first real hold reports what fails
            self._text([(f"warm-up {k}", tuple(u), u, np.full(3, 1e-3), 1000) for k, u in enumerate(up)])

    def __call__(self, label: PoseLabel, mean_g: np.ndarray, std_g: np.ndarray, n: int) -> None:
        try:
            self.rows.append((label.name, label.up_sensor, mean_g, std_g, n))
            self.live.running_calibration(self._text(self.rows))
        except Exception as exc:  # the live view must never stop the recording
            self.warn(f"live calibration skipped: {exc}")

    @staticmethod
    def _text(rows: list) -> str:
        """Markdown of the richest preset the rows (name, up_sensor, mean_g, std_g, n) determine."""
        names = [r[0] for r in rows]
        obs = obs_from_pose_means(
            *(np.array([r[k] for r in rows]) for k in (1, 2, 3, 4)), names=names, session="live"
        )
        text = f"holds so far: {', '.join(names)}\n\n"
        for preset in ("model3", "model2", "model1"):
            try:
                res = fit_model(obs, build_model(preset))
            except AccellogError as exc:
                text += f"- {preset}: not yet determined ({exc})\n"
                continue
            cal = Calibration.from_fit(res, obs=obs, gravity_convention="local")
            text += "\n" + table_markdown(params_table(cal, title=f"running {preset}"))
            break
        return text


LIVE_BLOCK_SAMPLES = 512
"""Samples the emulated chip computes per model call on the real clock: the read that crosses a
block pays for all of it (2048 samples: up to 2.3 ms of the read loop's CPU, 512: 1.4 ms, same
counts; benchmarks/bench_record_steps.py --block). The simulated clock keeps the chip's 2048
(fewer model calls, 20 % less of the chip's CPU)."""


def _open_bus(opts: RecordOptions):
    """(bus, sleep, clock_ns, source) of the emulated chip or of /dev/i2c-<bus>."""
    if opts.bus is not None and not opts.use_sim:
        return open_hardware_bus(opts.bus), time.sleep, None, "hardware"

    sc = Scenario(
        protocol=opts.protocol,
        hold_s=opts.hold_s + 6.0,
        sample_rate_hz=opts.rate_hz,
        accel_range_g=opts.accel_range_g,
        seed=opts.seed,
    )
    sc.validate()
    model, _motion = build_sensor_model(sc)
    clock = SimClock() if opts.fast else RealClock()
    address = parse_address(opts.address)
    chip = (
        EmulatedMpu9250(model, clock, seed=opts.seed, address=address)
        if opts.fast
        else EmulatedMpu9250(model, clock, seed=opts.seed, address=address, block_samples=LIVE_BLOCK_SAMPLES)
    )
    return chip, clock.sleep, clock.now_ns, "emulator"


def record_session(
    opts: RecordOptions,
    ui: RecorderUI | None = None,
    *,
    stop: threading.Event | None = None,
    warn=print,
    started=print,
) -> RecordResult:
    """Run the guided recording described by ``opts`` into ``opts.out``; return its summary.

    ui: tells the operator what to do (terminal); warn/started: one-line messages (live view
    failures, "recording to ..."). The live view (opts.rerun) never stops the MCAP recording.
    """
    opts.validate()
    poses = parse_protocol(opts.protocol, opts.hold_s)
    bus, sleep, clock_ns, source = _open_bus(opts)
    live = None
    try:
        dev = configure_device(
            bus,
            address=parse_address(opts.address),
            clock_ns=clock_ns,
            accel_range_g=opts.accel_range_g,
            gyro_range_dps=opts.gyro_range_dps,
            dlpf_cfg=opts.dlpf,
            sample_rate_div=sample_rate_div(opts.rate_hz),
            mag=opts.mag,
        )
        for note in dev.notes:
            warn(note)
        meta = session_meta(
            dev.info,
            dev.config,
            source=source,
            protocol=opts.protocol,
            serial=check_serial(opts.serial),
            i2c_bus="emulator" if opts.use_sim else f"/dev/i2c-{opts.bus}",
            i2c_address=parse_address(opts.address),
            ak8963_wia=dev.driver.ak8963_wia,
        )
        if opts.rerun:
            live = LiveView.from_option(opts.rerun)
            if live.failures:  # the viewer could not start (said once): record without feeding it
                live = None  # (not closed: closing would repeat the failure as "1 logging call dropped")
            else:
                ui = live.wrap_ui(ui)
        with SessionWriter(
            opts.out, meta, exclusive=True, overwrite=opts.force, compression=opts.compression
        ) as writer:
            dev.driver.start()
            real_time = not (opts.use_sim and opts.fast)  # the FIFO must be drained within 36 ms
            rec = Recorder(
                dev.driver,
                writer,
                sleep=sleep,
                ui=ui,
                read_mag=dev.read_mag,
                on_batch=live.on_batch if live else None,
                on_pose=RunningCalibration(live, warn) if live else None,
                stop=stop,
            )
            started(f"recording to {opts.out} (Ctrl-C finishes the file)")
            try:
                with raised_priority() if real_time else contextlib.nullcontext() as prio:
                    if prio is not None:
                        rec.post(writer.write_event, Event(0.0, "note", prio))
                    rec.run(poses, wait=opts.wait)
            except StopRequested:
                rec.summary.interrupted = True
                rec.summary.duration_s = rec.t_s
                note = "recording interrupted by the operator (Ctrl-C); file finished cleanly"
                rec.post(writer.write_event, Event(rec.t_s, "note", note))
            finally:
                rec.close()  # write what the helper thread still holds before the file closes
    finally:
        if live is not None:
            live.close()
        bus.close()  # the /dev/i2c-N file of real hardware (a no-op for the emulated chip)
    return RecordResult(Path(opts.out), rec.summary, dev.notes)
