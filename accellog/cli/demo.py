"""`accellog demo`: the main job on the emulated chip (see accellog.flows.demo)."""

from pathlib import Path
from typing import Annotated

import typer

from accellog.cli.app import app


@app.command(rich_help_panel="Start here")
def demo(
    out: Annotated[
        Path, typer.Option("-o", "--out", help="Folder for sessions, calibrations and the .rrd.")
    ] = Path("accellog-demo"),
    rrd: Annotated[Path | None, typer.Option(help="Rerun recording to write (default OUT/demo.rrd).")] = None,
    no_rrd: Annotated[bool, typer.Option("--no-rrd", help="Do not write a Rerun recording.")] = False,
    quick: Annotated[bool, typer.Option(help="Shorter holds (faster, noisier).")] = False,
) -> None:
    """Simulate calibration, static and moving sessions on the emulated MPU-9250; fit Models 1-3,
    print the seed's tables, find a hidden effect with the workbench, track a moving robot.

    Example: `accellog demo --quick -o demo-out` (shorter holds), then `accellog view
    demo-out/demo.rrd`.
    """
    from accellog.cli.progress import StepBar
    from accellog.flows.demo import run_demo

    bar = StepBar("simulate sessions")
    try:
        run_demo(out, rrd=None if no_rrd else (rrd or out / "demo.rrd"), quick=quick, progress=bar)
    finally:
        bar.close()
