"""`accellog fleet run PIPELINE.toml 'SESSIONS/**/*.mcap' -o FLEET/` and `accellog fleet report FLEET/`.

The library does the work (accellog.flows.fleet, accellog.flows.fleet_report); this module parses,
shows a progress bar and presents the typed results (rich tables, or JSON on stdout with --json).
"""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.cli.app import app

fleet_app = typer.Typer(
    help="Calibrate many sessions/sensors as Dask tasks and track each device over time.",
    no_args_is_help=True,
)
app.add_typer(fleet_app, name="fleet", rich_help_panel="2. Calibrate")

_console = Console(stderr=True)
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the result as JSON on stdout.")]


@fleet_app.command("run")
def run(
    pipeline: Annotated[Path, typer.Argument(help="Pipeline TOML (e.g. pipelines/fleet.toml).")],
    sessions: Annotated[str, typer.Argument(help="Glob of session files, quoted: 'SESSIONS/**/*.mcap'.")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Fleet directory (fleet.parquet, cal/).")],
    scheduler: Annotated[
        str | None, typer.Option(help="Address of a running Dask scheduler, e.g. tcp://HOST:8786.")
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(min=0, help="Local worker processes (default: cores; 0: serial loop, no Dask)."),
    ] = None,
    force: Annotated[bool, typer.Option(help="Recompute sessions already in the table.")] = False,
    workers_write: Annotated[
        bool | None,
        typer.Option(
            "--workers-write/--client-writes",
            help="Who writes FLEET/cal/: the workers (default with local workers; with --scheduler only "
            "when FLEET/ is on a filesystem every worker shares under the same path) or this process.",
        ),
    ] = None,
    json_out: JsonOpt = False,
) -> None:
    """Run the pipeline on every session as independent tasks; update FLEET/fleet.parquet.

    Example: `accellog fleet run pipelines/fleet.toml 'sessions/**/*.mcap' -o fleet --workers 2`.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from accellog.flows.fleet import run_fleet
    from accellog.present import fleet_tables

    with Progress(
        TextColumn("fleet"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeRemainingColumn(),
        console=_console,
        transient=True,
        disable=json_out or not _console.is_terminal,
    ) as bar:
        task = bar.add_task("sessions", total=None)

        def progress(done: int, total: int, _result: dict) -> None:
            bar.update(task, completed=done, total=total)

        res = run_fleet(pipeline, sessions, out, scheduler=scheduler, workers=workers, force=force,
                        workers_write=workers_write, on_progress=progress)  # fmt: skip
    if json_out:
        typer.echo(res.to_json())
        return
    _console.print(fleet_tables.run_table(res))
    if res.errors:
        _console.print(fleet_tables.errors_table(res.errors))


@fleet_app.command("report")
def report(
    fleet_dir: Annotated[Path, typer.Argument(help="Fleet directory written by `accellog fleet run`.")],
    model: Annotated[str | None, typer.Option(help="Model to report (default: the richest).")] = None,
    k_sigma: Annotated[
        float, typer.Option(help="Flag 'recalibrate' when a change exceeds k combined sigmas.")
    ] = 5.0,
    rerun: Annotated[
        str | None, typer.Option(help="Rerun recording: 'save:FILE.rrd', 'spawn' or 'connect[:URL]'.")
    ] = None,
    json_out: JsonOpt = False,
) -> None:
    """Per-device history, 'recalibrate' flags and fleet distributions vs the datasheet.

    Example: `accellog fleet report fleet --k-sigma 3`.
    """
    from accellog.flows.fleet_report import fleet_report
    from accellog.present import fleet_tables

    rep = fleet_report(fleet_dir, model=model, k_sigma=k_sigma)
    if rerun:
        from accellog.present.rrd.fleet import write_fleet_recording

        write_fleet_recording(rep, rerun)
    if json_out:
        typer.echo(rep.to_json())
        return
    out = Console()
    out.print(fleet_tables.devices_table(rep))
    out.print(fleet_tables.distribution_table(rep))
    if rep.errors:
        out.print(fleet_tables.errors_table(rep.errors))
    flagged = ", ".join(h.device + (f" (proposed: {h.proposed})" if h.proposed else "") for h in rep.flagged)
    flagged = flagged or "none"
    out.print(f"recalibrate: {flagged}; outliers: {', '.join(rep.outliers) or 'none'}")
