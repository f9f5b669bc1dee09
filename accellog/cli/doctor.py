"""`accellog doctor FILE`: rate, jitter, gaps, duplicates, bursts, clipping, events, temperature, still
intervals and the calibrations a log supports; table, --json, --rrd."""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.cli.app import app


@app.command("doctor", rich_help_panel="4. Inspect")
def doctor_cmd(
    file: Annotated[
        Path, typer.Argument(help="Any input accellog reads: .mcap (accellog or ROS 2), bag dir, CSV.")
    ],
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable report on stdout.")] = False,
    rrd: Annotated[
        Path | None,
        typer.Option("--rrd", help="Also write a Rerun recording (interval histogram, findings)."),
    ] = None,
    strict: Annotated[bool, typer.Option("--strict", help="Exit 1 when any defect is found.")] = False,
) -> None:
    """Check a log before calibrating with it.

    Example: `accellog doctor logger.csv --strict` (exit 1 on a defect).
    """
    from accellog.flows.doctor import examine, open_any
    from accellog.present import doctor_view

    r, t_s = examine(open_any(file), keep_times=rrd is not None)
    if rrd is not None:
        from accellog.present.rrd.recording import RunRecording

        with RunRecording(f"save:{rrd}", blueprint=None) as rec:
            assert t_s is not None  # keep_times on a file: every sample time
            doctor_view.log_doctor(rec, r, t_s)
    if as_json:
        typer.echo(r.to_json())
    else:
        console = Console()
        for t in doctor_view.tables(r):
            console.print(t)
    if strict and not r.healthy:
        raise typer.Exit(1)
