"""`accellog record` (guided recording from hardware or the emulated chip) and `accellog simulate`."""

import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console

from accellog.cli.app import CompressionOpt, ForceOpt, app
from accellog.core.errors import InputError

if TYPE_CHECKING:
    from accellog.core.protocol import PoseSpec
    from accellog.core.session import PoseLabel

console = Console(stderr=True)


class TerminalUI:
    """Tells the operator what to do, on stderr (rich)."""

    def __init__(self) -> None:
        self._last_wait = -1.0
        self._last_hold = -1

    def prompt(self, index: int, total: int, pose: "PoseSpec") -> None:
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

    def holding(self, pose: "PoseSpec", done_s: float) -> None:
        if not console.is_terminal:
            return
        pct = int(100 * min(done_s / pose.hold_s, 1.0))
        if pct // 10 != self._last_hold:
            bar = "#" * (pct // 5) + "-" * (20 - pct // 5)
            # markup off: rich would take "[####---]" for a style tag and drop it
            console.print(f"  holding {pose.name} [{bar}] {pct:3d}%", end="\r", markup=False, highlight=False)
            self._last_hold = pct // 10

    def finished_pose(self, label: "PoseLabel") -> None:
        console.print(f"  {label.name}: held {label.end_s - label.start_s:.1f} s" + " " * 30)


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
    serial: Annotated[
        str, typer.Option(help="Your serial/name of this sensor (device identity, e.g. IMU-0007).")
    ] = "",
    fast: Annotated[bool, typer.Option(help="With --sim: run on a simulated clock (no waiting).")] = False,
    seed: Annotated[int, typer.Option(help="With --sim: noise seed.")] = 1,
    rerun: Annotated[
        str | None, typer.Option(help="Live view: 'spawn', 'connect URL' or 'save FILE.rrd'.")
    ] = None,
    force: ForceOpt = False,
    compression: CompressionOpt = "zstd",
) -> None:
    """Record a guided calibration session: the operator is told each pose, the hold is labelled.

    Examples: `accellog record --bus 1 --protocol 24 --hold 20 -o cal.mcap` (an MPU-9250 on
    /dev/i2c-1); `accellog record --sim --fast --protocol six --hold 10 -o cal.mcap` (the emulated chip).
    """
    from accellog.flows.record import RecordOptions, record_session

    opts = RecordOptions(
        out=out,
        sim=sim,
        bus=bus,
        address=address,
        protocol=protocol,
        hold_s=hold,
        wait=wait,
        rate_hz=rate,
        accel_range_g=accel_range,
        gyro_range_dps=gyro_range,
        dlpf=dlpf,
        mag=mag,
        fast=fast,
        seed=seed,
        rerun=rerun,
        serial=serial,
        force=force,
        compression=compression,
    )
    # Ctrl-C / SIGTERM only set a flag; the recorder stops at its next FIFO read and the writer's
    # context finishes the file (an exception raised inside the MCAP writer could corrupt it).
    stop = threading.Event()
    old_handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in old_handlers:
        signal.signal(sig, lambda *_: stop.set())
    try:
        res = record_session(
            opts,
            TerminalUI(),
            stop=stop,
            warn=lambda m: console.print(f"[yellow]{m}[/]"),
            started=console.print,
        )
    finally:
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
    s = res.summary
    console.print(
        f"wrote {out}: {s.samples} samples in {s.duration_s:.1f} s, {len(s.poses)} poses, "
        f"{s.lost_samples} lost samples, {len(s.events)} events"
        + (" (interrupted)" if res.interrupted else "")
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
        typer.Option(
            help="'constant:T', 'warmup:T_start:T_end:tau_s', 'ramp:T0:rate_degC_per_s' or 'freezer' (warm-up 5 -> 45 degC, tau 300 s)."
        ),
    ] = None,
    fleet: Annotated[
        int | None,
        typer.Option(
            min=1, help="Simulate a fleet of N devices (ageing, one damaged) into the directory -o."
        ),
    ] = None,
    fleet_sessions: Annotated[int, typer.Option(min=1, help="With --fleet: sessions per device.")] = 3,
    jobs: Annotated[int, typer.Option(min=1, help="With --fleet: processes.")] = 1,
    fault: Annotated[
        list[str] | None,
        typer.Option(
            "--fault",
            help="Inject a fault (repeatable), KEY=VALUE: i2c_error_rate (0..1 per transaction), "
            "fifo_glitch_rate (0..1 per FIFO read), host_stall_s + host_stall_every_s (s), "
            "disconnect_at_s + disconnect_s (s). The same keys go in a scenario TOML's [faults] table.",
        ),
    ] = None,
    force: ForceOpt = False,
    compression: CompressionOpt = "zstd",
) -> None:
    """Write a whole simulated session (emulated chip, simulated clock) without waiting.

    Faults to rehearse a flaky setup (--fault KEY=VALUE or a scenario's [faults]): i2c_error_rate,
    fifo_glitch_rate, host_stall_s, host_stall_every_s, disconnect_at_s, disconnect_s; every lost
    sample is counted in the session's events.

    Examples: `accellog simulate --protocol six --hold 10 -o cal.mcap`;
    `accellog simulate --protocol +z --hold 120 -o still.mcap`; `accellog simulate --motion robot -o robot.mcap`.
    """
    from accellog.cli.progress import progress_bar
    from accellog.flows.simulate import scenario_from_options
    from accellog.flows.simulate import simulate as run_simulation

    if fleet is not None:
        _simulate_fleet(out, fleet, fleet_sessions, seed, jobs)
        return

    sc = scenario_from_options(
        scenario,
        protocol=protocol,
        hold_s=hold,
        sample_rate_hz=rate,
        seed=seed,
        chip_seed=chip_seed,
        errors=errors,
        motion=motion,
        set_items=set_,
        temperature=temperature,
        faults=fault,
    )
    with progress_bar("simulate (s)") as bar:
        summary = run_simulation(sc, out, force=force, compression=compression, progress=bar)
    console.print(
        f"wrote {out}: {summary.samples} samples, {summary.duration_s:.1f} s simulated, "
        f"{len(summary.poses)} poses, {summary.lost_samples} lost samples"
    )


def _simulate_fleet(out: Path, n: int, sessions: int, seed: int | None, jobs: int) -> None:
    from accellog.flows.fleet_sim import FleetSpec, simulate_fleet

    if out.suffix.lower() == ".mcap":
        raise InputError("--fleet writes a directory of sessions: give -o DIR", where=str(out))
    res = simulate_fleet(FleetSpec(n_devices=n, sessions_per_device=sessions, seed=seed or 0), out, jobs=jobs)
    console.print(
        f"wrote {len(res.sessions)} sessions of {n} devices to {out} (damaged: {res.damaged_serial}; "
        f"truth in {res.truth_file})"
    )
