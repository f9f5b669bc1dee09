"""`accellog record` (guided recording from hardware or the emulated chip) and `accellog simulate`."""

from __future__ import annotations

import math
import signal
import threading
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.console import Console

from accellog.cli.app import app
from accellog.core.errors import DeviceError, InputError
from accellog.core.protocol import PoseSpec, parse_protocol
from accellog.core.session import Event, PoseLabel
from accellog.store.atomic import check_output

console = Console(stderr=True)
ForceOpt = Annotated[bool, typer.Option("--force", help="Replace an existing output file.")]


class TerminalUI:
    """Tells the operator what to do, on stderr (rich)."""

    def __init__(self) -> None:
        self._last_wait = -1.0
        self._last_hold = -1

    def prompt(self, index: int, total: int, pose: PoseSpec) -> None:
        up = ", ".join(f"{v:+.0f}" for v in pose.up_sensor)
        console.print(
            f"[bold]pose {index + 1}/{total}: {pose.name}[/] - turn the sensor so that ({up}) points up, "
            f"then hold it still for {pose.hold_s:g} s"
        )
        self._last_wait, self._last_hold = -1.0, -1

    def waiting(self, moving: bool, still_for_s: float) -> None:
        if not console.is_terminal:
            return
        if still_for_s > 0 and int(still_for_s * 2) != int(self._last_wait * 2):
            console.print(f"  still for {still_for_s:.1f} s", end="\r")
        self._last_wait = still_for_s

    def holding(self, pose: PoseSpec, done_s: float) -> None:
        if not console.is_terminal:
            return
        pct = int(100 * min(done_s / pose.hold_s, 1.0))
        if pct // 10 != self._last_hold:
            bar = "#" * (pct // 5) + "-" * (20 - pct // 5)
            console.print(f"  holding {pose.name} [{bar}] {pct:3d}%", end="\r")
            self._last_hold = pct // 10

    def finished_pose(self, label: PoseLabel) -> None:
        console.print(f"  {label.name}: held {label.end_s - label.start_s:.1f} s" + " " * 30)


class RunningCalibration:
    """Refits the richest seed model the holds so far determine and shows it in the live view."""

    def __init__(self, live) -> None:
        self.live = live
        self.rows: list[tuple[str, tuple, np.ndarray, np.ndarray, int]] = []

    def __call__(self, label: PoseLabel, mean_g: np.ndarray, std_g: np.ndarray, n: int) -> None:
        try:
            self._update(label, mean_g, std_g, n)
        except Exception as exc:  # the live view must never stop the recording
            console.print(f"[yellow]live calibration skipped: {exc}[/]")

    def _update(self, label: PoseLabel, mean_g: np.ndarray, std_g: np.ndarray, n: int) -> None:
        from accellog.calibrate.fit import fit_model
        from accellog.calibrate.model import build_model
        from accellog.calibrate.segment import obs_from_pose_means
        from accellog.core.errors import AccellogError
        from accellog.present.tables import params_table
        from accellog.present.views import table_markdown

        self.rows.append((label.name, label.up_sensor, mean_g, std_g, n))
        names = [r[0] for r in self.rows]
        obs = obs_from_pose_means(
            np.array([r[1] for r in self.rows]),
            np.array([r[2] for r in self.rows]),
            np.array([r[3] for r in self.rows]),
            np.array([r[4] for r in self.rows]),
            names=names,
            session="live",
        )
        text = f"holds so far: {', '.join(names)}\n\n"
        for preset in ("model3", "model2", "model1"):
            try:
                res = fit_model(obs, build_model(preset))
            except AccellogError as exc:
                text += f"- {preset}: not yet determined ({exc})\n"
                continue
            from accellog.calibrate.calibration import Calibration

            cal = Calibration.from_fit(res, obs=obs, gravity_convention="local")
            text += "\n" + table_markdown(params_table(cal, title=f"running {preset}"))
            break
        self.live.running_calibration(text)


def _open_live(rerun: str | None):
    """A live Rerun view for the recorder, or None. Failures of the viewer never stop recording."""
    if not rerun:
        return None
    from accellog.present.rrd.live import LiveView

    return LiveView.from_option(rerun)


@app.command(rich_help_panel="1. Record")
def record(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output MCAP file.")] = Path("session.mcap"),
    sim: Annotated[
        bool, typer.Option("--sim", help="Record from the emulated chip (default without --bus).")
    ] = False,
    bus: Annotated[
        int | None, typer.Option("--bus", help="I2C bus number of real hardware (/dev/i2c-N).")
    ] = None,
    address: Annotated[str, typer.Option(help="I2C address of the MPU-9250 (0x68 or 0x69).")] = "0x68",
    protocol: Annotated[str, typer.Option(help="'six', '24' or a list of poses like '+z,-z,+x@90'.")] = "six",
    hold: Annotated[float, typer.Option(help="Hold time per pose (s).", min=1.0)] = 30.0,
    wait: Annotated[str, typer.Option(help="'auto' (stillness detection) or 'enter'.")] = "auto",
    rate: Annotated[float, typer.Option(help="Output data rate (Hz): 1000/(1+N).")] = 1000.0,
    accel_range: Annotated[int, typer.Option(help="Accelerometer full scale (+-g): 2, 4, 8 or 16.")] = 2,
    gyro_range: Annotated[int, typer.Option(help="Gyro full scale (+-deg/s): 250, 500, 1000, 2000.")] = 250,
    dlpf: Annotated[int, typer.Option(help="Gyro/temp DLPF_CFG 1..6 and accel A_DLPFCFG.")] = 3,
    mag: Annotated[bool, typer.Option("--mag/--no-mag", help="Also record the AK8963 magnetometer.")] = True,
    fast: Annotated[bool, typer.Option(help="With --sim: run on a simulated clock (no waiting).")] = False,
    seed: Annotated[int, typer.Option(help="With --sim: noise seed.")] = 1,
    rerun: Annotated[
        str | None, typer.Option(help="Live view: 'spawn', 'connect URL' or 'save FILE.rrd'.")
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Record a guided calibration session: the operator is told each pose, the hold is labelled."""
    from accellog.acquire.driver import Mpu9250
    from accellog.acquire.recorder import Recorder, RecorderUI, StopRequested, session_meta
    from accellog.store.writer import SessionWriter

    if accel_range not in (2, 4, 8, 16):
        raise InputError(f"--accel-range {accel_range}: use 2, 4, 8 or 16 (g)")
    if wait not in ("auto", "enter"):
        raise InputError(f"--wait {wait!r}: use 'auto' or 'enter'")
    poses = parse_protocol(protocol, hold)
    div = 1000.0 / rate - 1 if rate > 0 and math.isfinite(rate) else -1.0
    if rate <= 0 or abs(div - round(div)) > 1e-9 or not 0 <= round(div) <= 255:
        raise InputError(f"--rate {rate:g}: the chip supports 1000/(1+N) Hz, N = 0..255")
    use_sim = sim or bus is None
    try:
        addr = int(address, 0)
    except ValueError:
        raise InputError(f"--address {address!r} is not a number (use 0x68 or 0x69)") from None
    check_output(out, overwrite=force)

    if use_sim:
        from accellog.acquire.emulator.chip import EmulatedMpu9250
        from accellog.acquire.emulator.clock import RealClock, SimClock
        from accellog.flows.simulate import Scenario, build_sensor_model

        sc = Scenario(
            protocol=protocol, hold_s=hold + 6.0, sample_rate_hz=rate, accel_range_g=accel_range, seed=seed
        )
        sc.validate()
        model, _motion = build_sensor_model(sc)
        clock = SimClock() if fast else RealClock()
        device = EmulatedMpu9250(model, clock, seed=seed, address=addr)
        sleep, clock_ns, source = clock.sleep, clock.now_ns, "emulator"
    else:
        try:
            import smbus2

            device = smbus2.SMBus(bus)
        except (OSError, FileNotFoundError, PermissionError) as exc:
            raise DeviceError(f"cannot open /dev/i2c-{bus}: {exc.strerror or exc}") from None
        import time

        sleep, clock_ns, source = time.sleep, None, "hardware"

    # Ctrl-C / SIGTERM only set a flag; the recorder stops at its next FIFO read and the writer's
    # context finishes the file (an exception raised inside the MCAP writer could corrupt it).
    stop = threading.Event()
    old_handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    live = None
    try:
        driver = Mpu9250(device, address=addr, clock_ns=clock_ns)
        info = driver.probe()
        cfg = driver.configure(
            accel_range_g=accel_range,
            gyro_range_dps=gyro_range,
            dlpf_cfg=dlpf,
            a_dlpf_cfg=dlpf,
            sample_rate_div=round(div),
        )
        read_mag = mag and info.has_magnetometer
        if mag and not info.has_magnetometer:
            console.print(
                f"[yellow]{info.model} (WHO_AM_I=0x{info.who_am_i:02X}) has no magnetometer: not recorded[/]"
            )
        if read_mag:
            driver.enable_magnetometer()
        meta = session_meta(info, cfg, source=source, protocol=protocol)
        live = _open_live(rerun)
        ui: RecorderUI = TerminalUI()
        if live is not None:
            ui = live.wrap_ui(ui)
        interrupted = False
        with SessionWriter(out, meta, exclusive=True, overwrite=force) as writer:
            driver.start()
            rec = Recorder(
                driver,
                writer,
                sleep=sleep,
                ui=ui,
                read_mag=read_mag,
                on_batch=live.on_batch if live else None,
                on_pose=RunningCalibration(live) if live else None,
                stop=stop,
            )
            for sig in old_handlers:
                signal.signal(sig, lambda *_: stop.set())
            if not (use_sim and fast):  # real time: the FIFO must be drained within 36 ms
                from accellog.acquire.recorder import raise_priority

                writer.write_event(Event(0.0, "note", raise_priority()))
            console.print(f"recording to {out} (Ctrl-C finishes the file)")
            try:
                rec.run(poses, wait=wait)
            except StopRequested:
                interrupted = True
                rec.summary.duration_s = rec.t_s
                writer.write_event(
                    Event(
                        rec.t_s,
                        "note",
                        "recording interrupted by the operator (Ctrl-C); file finished cleanly",
                    )
                )
    finally:
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
        if live is not None:
            live.close()
        device.close()  # the /dev/i2c-N file of real hardware (a no-op for the emulated chip)
    s = rec.summary
    console.print(
        f"wrote {out}: {s.samples} samples in {s.duration_s:.1f} s, {len(s.poses)} poses, "
        f"{s.lost_samples} lost samples, {len(s.events)} events" + (" (interrupted)" if interrupted else "")
    )


@app.command(rich_help_panel="1. Record")
def simulate(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output MCAP file.")] = Path("sim.mcap"),
    scenario: Annotated[
        Path | None, typer.Option(help="Scenario TOML file (see accellog.flows.simulate).")
    ] = None,
    protocol: Annotated[str | None, typer.Option(help="'six', '24' or a pose list.")] = None,
    hold: Annotated[float | None, typer.Option(help="Hold time per pose (s).")] = None,
    rate: Annotated[float | None, typer.Option(help="Output data rate (Hz).")] = None,
    seed: Annotated[int | None, typer.Option(help="Noise seed of this session.")] = None,
    chip_seed: Annotated[
        int | None, typer.Option(help="Seed that draws the chip's error parameters.")
    ] = None,
    errors: Annotated[str | None, typer.Option(help="'datasheet' or 'perfect'.")] = None,
    motion: Annotated[str | None, typer.Option(help="'poses' or 'robot'.")] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="Override an error field, e.g. --set temp_bias_g_per_degC=0.001,0,0"),
    ] = None,
    temperature: Annotated[
        str | None,
        typer.Option(help="'constant:T', 'warmup:T_start:T_end:tau_s' or 'ramp:T0:rate_degC_per_s'."),
    ] = None,
    fault: Annotated[
        list[str] | None,
        typer.Option(
            "--fault",
            help="Inject a fault (repeatable), KEY=VALUE: i2c_error_rate (0..1 per transaction), "
            "fifo_glitch_rate (0..1 per FIFO read), host_stall_s + host_stall_every_s (s), "
            "disconnect_at_s + disconnect_s (s). The same keys work in a scenario TOML.",
        ),
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Write a whole simulated session (emulated chip, simulated clock) without waiting.

    Faults to rehearse a flaky setup (--fault KEY=VALUE or scenario keys): i2c_error_rate,
    fifo_glitch_rate, host_stall_s, host_stall_every_s, disconnect_at_s, disconnect_s; every lost
    sample is counted in the session's events."""
    from accellog.flows.simulate import Scenario
    from accellog.flows.simulate import simulate as run_simulation

    sc = Scenario.from_toml(scenario) if scenario else Scenario()
    for name, value in (
        ("protocol", protocol),
        ("hold_s", hold),
        ("sample_rate_hz", rate),
        ("seed", seed),
        ("chip_seed", chip_seed),
        ("errors", errors),
        ("motion", motion),
    ):
        if value is not None:
            setattr(sc, name, value)
    for item in set_ or []:
        key, sep, val = item.partition("=")
        if not sep:
            raise InputError(f"--set {item!r}: use FIELD=VALUE or FIELD=X,Y,Z")
        try:
            nums = [float(v) for v in val.split(",")]
        except ValueError:
            raise InputError(f"--set {item!r}: value is not a number") from None
        sc.set[key.strip()] = nums if len(nums) > 1 else nums[0]
    if temperature:
        sc.temperature = parse_temperature_option(temperature)
    for item in fault or []:
        key, sep, val = item.partition("=")
        try:
            value = float(val)
        except ValueError:
            value = None
        if not sep or value is None:
            raise InputError(f"--fault {item!r}: use KEY=NUMBER, e.g. --fault i2c_error_rate=0.01")
        from accellog.acquire.emulator.faults import FaultPlan

        FaultPlan.from_mapping({key.strip(): value}, where="--fault")
        setattr(sc, key.strip(), value)
    sc.validate()
    summary = run_simulation(sc, out, force=force)
    console.print(
        f"wrote {out}: {summary.samples} samples, {summary.duration_s:.1f} s simulated, "
        f"{len(summary.poses)} poses, {summary.lost_samples} lost samples"
    )


def parse_temperature_option(text: str) -> dict:
    """'constant:T' | 'warmup:T_start:T_end:tau_s' | 'ramp:T0:rate_degC_per_s' -> scenario dict."""
    kind, *vals = text.split(":")
    keys = {"constant": ["T"], "warmup": ["T_start", "T_end", "tau_s"], "ramp": ["T0", "rate_degC_per_s"]}
    if kind not in keys or len(vals) != len(keys[kind]):
        raise InputError(
            f"--temperature {text!r}: use constant:T, warmup:T_start:T_end:tau_s or ramp:T0:rate"
        )
    try:
        return {"kind": kind, **{k: float(v) for k, v in zip(keys[kind], vals, strict=True)}}
    except ValueError:
        raise InputError(f"--temperature {text!r}: values must be numbers") from None
