"""`accellog magcal`: hard and soft iron of the AK8963 magnetometer from a rotating session."""

from pathlib import Path
from typing import Annotated

import typer

from accellog.cli.app import ForceOpt, app
from accellog.core.errors import InputError


@app.command("magcal", rich_help_panel="2. Calibrate")
def magcal_cmd(
    session_path: Annotated[
        Path, typer.Argument(metavar="SESSION.mcap", help="Session that turns the sensor in all directions.")
    ],
    form: Annotated[
        str, typer.Option("--form", help="Soft-iron form: eye, diag or sym (as MATLAB magcal).")
    ] = "sym",
    field_uT: Annotated[
        float | None,
        typer.Option("--field-uT", help="Expected local field strength (uT), e.g. from a WMM model."),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable results on stdout.")] = False,
    rrd: Annotated[
        Path | None,
        typer.Option("--rrd", help="Also write a Rerun recording: raw and corrected samples on a sphere."),
    ] = None,
    cal: Annotated[
        Path | None,
        typer.Option(
            "--cal", help="Calibration JSON to copy with a 'magnetometer' section added (needs --out)."
        ),
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Where to write that calibration.")] = None,
    force: ForceOpt = False,
) -> None:
    """Ellipsoid fit of the magnetometer: hard iron h and soft iron A with 1-sigma, field strength vs the
    expected local field, residual vs noise, and the residual's trends against time, temperature and rate.

    Example: `accellog magcal examples/mag_session.mcap --field-uT 48 --cal cal.json -o cal_mag.json`.
    """
    from accellog.flows.magcal import run_magcal

    if (cal is None) != (out is None):
        raise InputError("--cal and --out go together (the calibration is copied, never overwritten)")
    if cal is not None and out is not None and out.resolve() == cal.resolve():
        raise InputError("--out must differ from --cal (the original calibration is kept)", where=str(out))
    c, session = run_magcal(session_path, form, field_uT)
    if cal is not None and out is not None:
        from accellog.calibrate.calfile.calibration import load_calibration

        k = load_calibration(cal)
        k.magnetometer = c
        k.save(out)
    if rrd is not None:
        from accellog.present.mag_views import log_magcal

        assert session.mag_uT is not None  # run_magcal refuses a session without magnetometer samples
        log_magcal(rrd, c, session.mag_uT)
    if as_json:
        typer.echo(c.to_json())
        return
    from accellog.present.mag_views import print_magcal

    print_magcal(c, session_path.name)
