"""The typer application object shared by every command module in accellog.cli, and the options
several commands share."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(
    name="accellog",
    help="Record, calibrate and inspect MEMS accelerometers (MPU-9250): MCAP logs, error models "
    "with uncertainties, a model workbench and Rerun recordings.",
    no_args_is_help=True,
    rich_markup_mode="rich",
    pretty_exceptions_enable=False,
    add_completion=True,
)


def _print_version(value: bool) -> None:
    if value:
        from accellog.core.version import __version__

        typer.echo(f"accellog {__version__}")
        raise typer.Exit()


@app.callback()
def _top(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    pass


CompressionOpt = Annotated[
    str,
    typer.Option(
        "--compression",
        help="MCAP chunk compression: zstd (smaller files, faster from disk), lz4 (faster from the page "
        "cache) or none.",
    ),
]

EffectsOpt = Annotated[
    Path | None,
    typer.Option(
        "--effects-file",
        help="Python file of user effects, run with your rights: needed for a calibration whose model has "
        "user effects (its sha256 must match the one the calibration recorded; nothing named inside a "
        "calibration is ever run).",
    ),
]
