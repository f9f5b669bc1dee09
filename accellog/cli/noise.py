"""`accellog noise`: Allan-variance noise characterisation of a long static session."""

from pathlib import Path
from typing import Annotated

import typer

from accellog.cli.app import ForceOpt, app
from accellog.core.errors import InputError


@app.command("noise", rich_help_panel="2. Calibrate")
def noise_cmd(
    session_path: Annotated[
        Path, typer.Argument(metavar="SESSION", help="Long static session: .mcap (streamed) or .csv.")
    ],
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable results on stdout.")] = False,
    rrd: Annotated[
        Path | None, typer.Option("--rrd", help="Also write a Rerun recording: log-log Allan plots.")
    ] = None,
    cal: Annotated[
        Path | None,
        typer.Option("--cal", help="Calibration JSON to copy with a 'noise' section added (needs --out)."),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Where to write the calibration with its noise section."),
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Overlapping Allan deviation per axis (accel, gyro) with confidence intervals; fitted white noise,
    bias instability and random walk with 1-sigma, in SI and datasheet units, and the session length each
    needs; quantisation and temperature-driven stretches flagged.

    Example: `accellog noise still.mcap --rrd allan.rrd --cal cal.json -o cal_noise.json`.
    """
    from accellog.flows.characterise import characterise_noise

    if (cal is None) != (out is None):
        raise InputError("--cal and --out go together (the calibration is copied, never overwritten)")
    if cal is not None and out is not None and out.resolve() == cal.resolve():
        raise InputError("--out must differ from --cal (the original calibration is kept)", where=str(out))
    model = characterise_noise(session_path)
    if cal is not None and out is not None:
        from accellog.calibrate.calfile.calibration import load_calibration
        from accellog.calibrate.noise.noise_model import calibration_section

        c = load_calibration(cal)
        c.noise = calibration_section(model)
        c.save(out)
    if rrd is not None:
        from accellog.present.noise_views import log_noise

        log_noise(rrd, model)
    if as_json:
        typer.echo(model.to_json())
        return
    from accellog.present.noise_views import print_noise

    print_noise(model)
