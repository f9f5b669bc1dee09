"""`accellog export CAL.json --to kalibr|ros|px4|ardupilot|yaml`: calibrations for other tools."""

import enum
import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.cli.app import EffectsOpt, ForceOpt, app
from accellog.core.errors import InputError
from accellog.core.notices import note
from accellog.present.export_targets import TARGETS

Target = enum.Enum("Target", {t: t for t in TARGETS}, type=str)  # type: ignore[misc]  # from the one list
"""The --to choices (shell completion offers them)."""
HeldoutOpt = Annotated[
    Path | None,
    typer.Option(
        "--heldout",
        help="px4/ardupilot: a labelled session of the same sensor the calibration was not fitted on "
        "(a cool-down, another day): what the autopilot will leave on it, per axis, in the header.",
    ),
]
VerdictRrdOpt = Annotated[
    Path | None,
    typer.Option(
        "--rrd", help="With --heldout: a Rerun recording of the held-out residual against temperature."
    ),
]


@app.command("export", rich_help_panel="2. Calibrate")
def export_cmd(
    cal: Annotated[Path, typer.Argument(help="Calibration JSON (accellog fit -o).")],
    to: Annotated[Target, typer.Option("--to", help="The target's format.")],
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write here (default: stdout).")
    ] = None,
    noise_from: Annotated[
        Path | None,
        typer.Option(
            "--noise-from", help="Still recording (.mcap/.csv) for noise densities and random walks."
        ),
    ] = None,
    topic: Annotated[str, typer.Option("--topic", help="IMU topic (Kalibr rostopic).")] = "/imu/data",
    rotation: Annotated[
        str,
        typer.Option(
            "--rotation",
            help="px4/ardupilot: the driver's chip rotation applied before the offsets, by the targets' "
            "name or number (ROTATION_NONE, ROTATION_YAW_90, ROTATION_ROLL_180_YAW_270, ...).",
        ),
    ] = "ROTATION_NONE",
    device_id: Annotated[
        int | None,
        typer.Option(
            "--device-id",
            min=0,
            help="px4/ardupilot: the sensor's device id as the autopilot shows it (CAL_ACC0_ID / "
            "INS_ACC_ID); default: computed from the calibration's I2C bus and address when known.",
        ),
    ] = None,
    heldout: HeldoutOpt = None,
    rrd: VerdictRrdOpt = None,
    as_json: Annotated[
        bool, typer.Option("--json", help="Values, units and what the target cannot hold.")
    ] = False,
    effects_file: EffectsOpt = None,
    force: ForceOpt = False,
) -> None:
    """Write a calibration in another tool's format; the header says what that format cannot hold and
    how large the loss is on this calibration.

    Examples: `accellog export cal.json --to ros -o imu_calib.yaml` (imu_calib's SM/bias);
    `accellog export cal.json --to ardupilot --rotation ROTATION_YAW_270 -o cal.parm`;
    `accellog export cal.json --to kalibr --noise-from still.mcap -o imu.yaml`;
    `accellog export cal.json --to px4 --heldout cooldown.mcap -o cal.params` (judged on another session).
    """
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.calibrate.noise.imu_noise import NoiseCharacterisation
    from accellog.flows.characterise import characterise_noise
    from accellog.present.exports import export_calibration
    from accellog.store.atomic import check_outputs, write_text_atomic

    check_outputs([output, rrd], [cal, noise_from, heldout])
    _check_verdict_options(to.value, heldout, rrd)

    c = load_calibration(cal, effects_file)
    noise: NoiseCharacterisation | None
    if noise_from is not None:
        noise = NoiseCharacterisation.from_model(characterise_noise(noise_from))
    else:
        noise = NoiseCharacterisation.from_section(c.noise) if c.noise else None
    judged = _verdict(c, to.value, heldout)
    verdict = [] if judged is None else judged.lines()
    ex = export_calibration(
        c, to.value, noise=noise, topic=topic, rotation=rotation, device_id=device_id, verdict=verdict
    )
    if output is not None:
        write_text_atomic(output, ex.text, inputs=(cal, noise_from, heldout))
    if rrd is not None and judged is not None:
        judged.write_rrd(rrd)
    if as_json:
        typer.echo(json.dumps({k: v for k, v in ex.to_dict().items() if k != "text"}, default=float))
        return
    if output is None:
        typer.echo(ex.text, nl=False)
        return
    console = Console(stderr=True)
    console.print(f"wrote {output} ({to.value})")
    for x in ex.cannot_hold:
        console.print(f"[yellow]cannot hold:[/] {x}", soft_wrap=True)


def _check_verdict_options(target: str, heldout: Path | None, rrd: Path | None) -> None:
    """--heldout judges an autopilot's export; --rrd draws that verdict."""
    if heldout is not None and target not in ("px4", "ardupilot"):
        raise InputError(f"--heldout judges the px4 or ardupilot export, not --to {target}")
    if rrd is not None and heldout is None:
        raise InputError("--rrd draws the --heldout verdict: give --heldout S.mcap")


def _verdict(cal, target: str, heldout: Path | None):
    """export --heldout: the held-out verdict (flows.export_verdict), its lines said on stderr; None without."""
    if heldout is None:
        return None
    from accellog.flows.export_verdict import export_verdict

    judged = export_verdict(cal, target, heldout)
    for line in judged.lines():
        note(line)
    return judged
