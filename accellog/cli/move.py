"""`accellog track`: strapdown tracks of a moving session, one per calibration, with their errors."""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.cli.app import EffectsOpt, app


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
    effects_file: EffectsOpt = None,
) -> None:
    """Integrate the session (gyro attitude + accel) per calibration; print the final and RMS
    position error against the truth (simulations) or the loop-closure error (real runs).

    Example: `accellog track robot.mcap --cal model3.json --zupt --rrd track.rrd`.
    """
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.core.jsonio import dumps
    from accellog.flows.track import track_session
    from accellog.present.tables import track_table

    cals = [load_calibration(c, effects_file) for c in cal or []]
    rep = track_session(session_path, cals, zupt=zupt)
    if rrd is not None:
        rep.write_rrd(rrd)
    if as_json:
        typer.echo(dumps(rep.to_dict(), indent=1))  # NaN/inf -> null
        return
    what = (
        "vs truth"
        if rep.reference == "truth"
        else "loop closure (no truth: the path must return to its start)"
    )
    title = f"{session_path.name}: tracks, {what}" + (", with ZUPT" if zupt else "")
    Console().print(track_table(title, rep.runs, zupt))
