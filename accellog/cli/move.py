"""`accellog track`: strapdown tracks of a moving session, one per calibration, with their errors."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from accellog.cli.app import app
from accellog.core.errors import InputError


def _fmt(x: float, unit: str = "m") -> str:
    return "-" if x != x else f"{x:.3g} {unit}"


@app.command("track", rich_help_panel="5. Move")
def track_cmd(
    session_path: Annotated[
        Path, typer.Argument(metavar="SESSION.mcap", help="Recorded or simulated session.")
    ],
    cal: Annotated[
        list[Path] | None,
        typer.Option("--cal", help="Calibration JSON (repeatable); each gives its own track next to 'raw'."),
    ] = None,
    zupt: Annotated[
        bool, typer.Option("--zupt/--no-zupt", help="Zero-velocity updates at detected stops.")
    ] = True,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable results on stdout.")] = False,
    rrd: Annotated[
        Path | None,
        typer.Option("--rrd", help="Also write a Rerun recording: tracks vs truth, errors, stops."),
    ] = None,
) -> None:
    """Integrate the session (gyro attitude + accel) per calibration; print the final and RMS
    position error against the truth (simulations) or the loop-closure error (real runs)."""
    from accellog.calibrate.calibration import dumps, load_calibration
    from accellog.navigate.track_eval import run_session_tracks
    from accellog.store.reader import read_session

    if not session_path.is_file():
        raise InputError("no such session file", where=str(session_path))
    session = read_session(session_path)
    cals: dict[str, object] = {}
    for p in cal or []:
        c = load_calibration(p)
        name = p.stem
        while name in cals or name == "raw":
            name += "'"
        cals[name] = c
    runs = run_session_tracks(session, cals, use_zupt=zupt)
    if rrd is not None:
        from accellog.present.rrd.recording import RunRecording
        from accellog.present.views import log_session, log_track_runs

        with RunRecording(f"save:{rrd}") as rec:
            log_session(rec, session)
            log_track_runs(rec, runs, session.truth, group="track")
    reference = runs[0].error.reference
    if as_json:
        out = {
            "session": str(session_path),
            "reference": reference,
            "zupt": zupt,
            "tracks": [
                {
                    **r.error.to_dict(),
                    "without_zupt": None if r.error_without_zupt is None else r.error_without_zupt.to_dict(),
                }
                for r in runs
            ],
        }
        typer.echo(dumps(out, indent=1))  # NaN/inf -> null
        return
    what = (
        "vs truth" if reference == "truth" else "loop closure (no truth: the path must return to its start)"
    )
    table = Table(title=f"{session_path.name}: tracks, {what}" + (", with ZUPT" if zupt else ""))
    table.add_column("calibration")
    table.add_column("final error", justify="right")
    table.add_column("RMS error", justify="right")
    table.add_column("% of path", justify="right")
    if zupt:
        table.add_column("final w/o ZUPT", justify="right")
        table.add_column("stops", justify="right")
    for r in runs:
        e = r.error
        row = [r.name, _fmt(e.final_error_m), _fmt(e.rms_error_m), f"{e.final_error_pct_of_path:.2g}"]
        if zupt:
            row += [_fmt(r.error_without_zupt.final_error_m), str(e.zupt_stops)]
        table.add_row(*row)
    Console().print(table)
