"""`accellog import capstone|imucal|csv|ros2|ulog|dataflash FILE -o OUT.mcap`: other tools' recordings
-> accellog MCAP."""

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console

from accellog.cli.app import CompressionOpt, ForceOpt, app
from accellog.core.errors import InputError

if TYPE_CHECKING:
    from accellog.core.session import Session

import_app = typer.Typer(
    help="Import recordings (capstone CSV, imucal, any logger's CSV, ROS 2 bags, PX4 ULog, ArduPilot "
    "DataFlash) into accellog MCAP files.",
    no_args_is_help=True,
)
app.add_typer(import_app, name="import", rich_help_panel="1. Record")

OutOpt = Annotated[Path, typer.Option("-o", "--out", help="Output MCAP file (written atomically).")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print a machine-readable summary on stdout.")]
BatchOpt = Annotated[int, typer.Option("--batch-size", min=1, help="Samples per /imu message.")]
AccelScaleOpt = Annotated[
    float,
    typer.Option(
        "--accel-scale",
        help="Multiply the g or m/s^2 values (a logger that converted with another range's LSB/g: 4 for a "
        "+-8 g log printed as +-2 g).",
    ),
]
BadRowsOpt = Annotated[
    str,
    typer.Option(
        "--bad-rows",
        help="A row that does not parse (a serial glitch): 'refuse' the file, or 'skip' it, each skipped "
        "row counted as an event of the session with its line.",
    ),
]
DetectHoldsOpt = Annotated[
    bool,
    typer.Option(
        "--detect-holds",
        help="Label the still intervals (detect_static) as the table faces they lie on (+x..-z), when "
        "all six are found; else the session stays unlabelled.",
    ),
]


def _facts(session: "Session", src: Path, out: Path) -> dict:
    t = session.t_s
    return {
        "input": str(src),
        "output": str(out),
        "source": session.meta.source,
        "samples": session.n,
        "duration_s": float(t[-1] - t[0]) if session.n else 0.0,
        "sample_rate_hz": session.meta.sample_rate_hz,
        "accel_storage": (
            f"counts ({session.meta.accel_lsb_per_g:g} LSB/g)"
            if session.accel_counts is not None
            else "g (float64)"
        ),
        "source_unit": session.meta.extra.get("source_unit", ""),
        "gyro": session.gyro_dps is not None,
        "temperature": session.temp_degC is not None,
        "poses": [p.name for p in session.poses],
        "events": len(session.events),
        "notes": {
            k: v
            for k, v in session.meta.extra.items()
            if k.startswith(
                (
                    "ros2_topic",
                    "stamp_",
                    "out_of",
                    "dup",
                    "ulog_",
                    "dataflash_",
                    "accel_device",
                    "gyro_device",
                )
            )
        },
    }


def _check_out(out: Path, src: Path, compression: str, force: bool) -> None:
    """Refuse an unknown compression, and an output that is a directory, in a missing folder, the
    input itself (accellog.store.atomic.check_output: same file by samefile or resolved path) or,
    without --force, an existing file."""
    from accellog.store.atomic import check_output
    from accellog.store.writer import check_compression

    check_compression(compression)
    check_output(out, [src], overwrite=force)


def _write(
    session: "Session", src: Path, out: Path, as_json: bool, batch_size: int, compression: str, force: bool
) -> None:
    from accellog.store.writer import write_session

    write_session(out, session, batch_size=batch_size, compression=compression, overwrite=force)
    _present(_facts(session, src, out), src, out, as_json)


def _present(facts: dict, src: Path, out: Path, as_json: bool) -> None:
    from rich.table import Table

    if as_json:
        typer.echo(json.dumps(facts))
        return
    table = Table(title=f"imported {src.name} -> {out.name}", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value")
    for k, v in facts.items():
        if isinstance(v, dict):
            v = "; ".join(f"{a}: {b}" for a, b in v.items())
        table.add_row(
            k, ", ".join(v) if isinstance(v, list) else (f"{v:.6g}" if isinstance(v, float) else str(v))
        )
    Console().print(table)


@import_app.command("capstone")
def import_capstone_cmd(
    file: Annotated[Path, typer.Argument(help="A capstone static test file (six_position_test_data*.csv).")],
    out: OutOpt,
    as_json: JsonOpt = False,
    batch_size: BatchOpt = 500,
    compression: CompressionOpt = "zstd",
    force: ForceOpt = False,
) -> None:
    """Capstone static test file (t in s; x, y, z in g) -> MCAP with one '+z' hold; counts at 16384 LSB/g.

    Example: `accellog import capstone six_position_test_data.csv -o static.mcap`.
    """
    from accellog.store.importers import import_capstone

    _check_out(out, file, compression, force)
    _write(import_capstone(file), file, out, as_json, batch_size, compression, force)


@import_app.command("imucal")
def import_imucal_cmd(
    file: Annotated[Path, typer.Argument(help="example_ferraris_session.csv or annotated_session.csv.")],
    out: OutOpt,
    sections: Annotated[
        Path | None,
        typer.Option(
            "--sections",
            help="Section list JSON {label: {start, end}} (default: beside the file, STEM_list.json).",
        ),
    ] = None,
    rate_hz: Annotated[
        float | None, typer.Option("--rate-hz", min=0.001, help="Sample rate (default 102.4 / 204.8 Hz).")
    ] = None,
    as_json: JsonOpt = False,
    batch_size: BatchOpt = 500,
    compression: CompressionOpt = "zstd",
    force: ForceOpt = False,
) -> None:
    """imucal Ferraris recording -> MCAP (x_p..z_a -> poses +x..-z; x_rot.. -> motion_segment events).

    Example: `accellog import imucal example_ferraris_session.csv -o ferraris.mcap`.
    """
    from accellog.store.importers import import_imucal

    _check_out(out, file, compression, force)
    session = import_imucal(file, sections, sample_rate_hz=rate_hz)
    _write(session, file, out, as_json, batch_size, compression, force)


@import_app.command("csv")
def import_csv_cmd(
    file: Annotated[
        Path, typer.Argument(help="Any logger's CSV with a header row (t,ax,ay,az[,temp,gx,gy,gz,pose,...]).")
    ],
    out: OutOpt,
    unit: Annotated[str, typer.Option("--unit", help="Accelerometer unit: g, m/s^2 or counts.")] = "g",
    lsb_per_g: Annotated[
        float | None, typer.Option("--lsb-per-g", help="Counts per g (needed with --unit counts).")
    ] = None,
    accel_scale: AccelScaleOpt = 1.0,
    count_offset: Annotated[
        float,
        typer.Option(
            "--count-offset",
            help="Subtracted from every counts column: ax,ay,az with --unit counts, gx,gy,gz with "
            "--gyro-unit counts (32768 for offset-binary/unsigned).",
        ),
    ] = 0.0,
    gyro_count_offset: Annotated[
        float | None,
        typer.Option(
            "--gyro-count-offset", help="Subtracted from the gyro counts instead of --count-offset."
        ),
    ] = None,
    gyro_unit: Annotated[
        str | None, typer.Option("--gyro-unit", help="Gyro unit: deg/s (default), rad/s or counts.")
    ] = None,
    gyro_lsb_per_dps: Annotated[
        float | None,
        typer.Option("--gyro-lsb-per-dps", help="Gyro counts per deg/s (with --gyro-unit counts)."),
    ] = None,
    columns: Annotated[
        str | None,
        typer.Option("--columns", help="Column map NAME=COLUMN,... e.g. t=time,ax=acc_x,gx=gyr_x."),
    ] = None,
    rate: Annotated[
        float | None, typer.Option("--rate", help="Sample rate (Hz) when there is no time column.")
    ] = None,
    time_unit: Annotated[
        str | None, typer.Option("--time-unit", help="Unit of the time column: s (default), ms, us, ns.")
    ] = None,
    delimiter: Annotated[
        str, typer.Option("--delimiter", help="Field separator (one character, or tab).")
    ] = ",",
    comment: Annotated[str, typer.Option("--comment", help="Lines starting with this are skipped.")] = "#",
    bad_rows: BadRowsOpt = "refuse",
    detect_holds: DetectHoldsOpt = False,
    as_json: JsonOpt = False,
    batch_size: BatchOpt = 500,
    compression: CompressionOpt = "zstd",
    force: ForceOpt = False,
) -> None:
    """Any logger's CSV -> MCAP, streamed in blocks (memory independent of the file's length).

    temp in degC; 'pose' names label static holds. Examples: offset-binary counts
    `--unit counts --lsb-per-g 16384 --count-offset 32768 --gyro-unit counts --gyro-lsb-per-dps 131`;
    no time column `--rate 100` (or a '# rate: 100 Hz' line above the header); a table protocol
    without a pose column `--detect-holds` (read in memory, as `import ros2 --detect-holds`).

    Example: `accellog import csv examples/handheld.csv -o hand.mcap`; a serial log with glitched
    rows and a +-8 g range printed as +-2 g: `accellog import csv log.csv --bad-rows skip --accel-scale
    4 -o s.mcap`.
    """
    from accellog.cli.progress import progress_bar, wanted
    from accellog.store.importers.csv import CsvOptions, import_csv_to_mcap

    opts = CsvOptions.make(unit=unit, lsb_per_g=lsb_per_g, accel_scale=accel_scale, count_offset=count_offset,
                           gyro_count_offset=gyro_count_offset, gyro_unit=gyro_unit,
                           gyro_lsb_per_dps=gyro_lsb_per_dps, columns=columns, rate_hz=rate,
                           time_unit=time_unit, delimiter=delimiter, comment=comment,
                           bad_rows=bad_rows)  # fmt: skip
    _check_out(out, file, compression, force)
    if detect_holds:
        _write(_labelled_csv(file, opts), file, out, as_json, batch_size, compression, force)
        return
    with progress_bar("import csv (MB)", show=wanted(as_json)) as bar:
        result = import_csv_to_mcap(
            file, out, opts, batch_size=batch_size, compression=compression, overwrite=force, progress=bar
        )
    _note_skipped(result.skipped_rows)
    _present(result.to_dict(), file, out, as_json)


def _note_skipped(details: list[str]) -> None:
    """One note naming the rows --bad-rows skip dropped (each is an event of the session too)."""
    from accellog.core.notices import note

    if details:
        lines = ", ".join(d.split(": ", 1)[0] for d in details[:5]) + (", ..." if len(details) > 5 else "")
        note(f"{len(details)} row(s) that do not parse skipped ({lines}): each is a 'skipped_row' event")


def _labelled_csv(file: Path, opts) -> "Session":
    """The CSV read whole and labelled with its detected face holds (the ros2 importer's path)."""
    from accellog.calibrate.observe.detected_holds import label_detected_holds
    from accellog.store.importers.csv import import_csv

    session = import_csv(file, opts)
    _note_skipped([e.detail for e in session.events if e.kind == "skipped_row"])
    if session.poses:
        raise InputError(
            "--detect-holds is for a file without pose labels: it has a pose column", where=str(file)
        )
    return label_detected_holds(session)


@import_app.command("ros2")
def import_ros2_cmd(
    bag: Annotated[Path, typer.Argument(help="rosbag2 directory, or a single .mcap / .db3 file.")],
    out: Annotated[
        Path | None, typer.Option("-o", "--out", help="Output MCAP file (without it: list the bag's topics).")
    ] = None,
    topic: Annotated[str | None, typer.Option("--topic", help="sensor_msgs/msg/Imu topic.")] = None,
    temperature_topic: Annotated[
        str | None,
        typer.Option(
            "--temperature-topic",
            help="sensor_msgs/msg/Temperature topic (default: the bag's only one, or the one in the IMU "
            "topic's namespace).",
        ),
    ] = None,
    mag_topic: Annotated[
        str | None, typer.Option("--mag-topic", help="sensor_msgs/msg/MagneticField topic.")
    ] = None,
    detect_holds: DetectHoldsOpt = False,
    as_json: JsonOpt = False,
    batch_size: BatchOpt = 500,
    compression: CompressionOpt = "zstd",
    force: ForceOpt = False,
) -> None:
    """ROS 2 bag -> MCAP session: header stamps, m/s^2 -> g, rad/s -> deg/s, T -> uT; provenance kept.

    Without -o, lists the bag's topics (IMU topics first) and exits. --detect-holds labels a six-face
    table protocol; a hand-held bag stays unlabelled and `fit` fits it orientation-free.
    Example: `accellog import ros2 examples/imu_bag.mcap --topic /imu/data --detect-holds -o s.mcap`.
    """
    from rich.table import Table

    from accellog.calibrate.observe.detected_holds import label_detected_holds
    from accellog.cli.progress import progress_bar, wanted
    from accellog.store.importers.ros2 import IMU_TYPE, import_ros2, list_topics

    if out is None:
        topics = sorted(list_topics(bag), key=lambda t: (t.msgtype != IMU_TYPE, t.topic))
        if as_json:
            typer.echo(json.dumps([t.__dict__ for t in topics]))
            return
        table = Table(title=f"topics of {bag.name} (import one IMU topic with --topic NAME -o OUT.mcap)")
        for col in ("topic", "type", "messages"):
            table.add_column(col)
        for t in topics:
            table.add_row(t.topic, t.msgtype, str(t.count))
        Console().print(table)
        return
    _check_out(out, bag, compression, force)
    if not detect_holds:  # streamed (flat memory); None: stamps to sort or zero, imported in memory
        from accellog.store.importers.ros2_stream import import_ros2_to_mcap

        with progress_bar("import ros2 (messages)", show=wanted(as_json)) as bar:
            facts = import_ros2_to_mcap(bag, out, topic=topic, temperature_topic=temperature_topic,
                                        mag_topic=mag_topic, batch_size=batch_size, compression=compression,
                                        overwrite=force, progress=bar)  # fmt: skip
        if facts is not None:
            head = {"input": str(bag), "output": str(out), "source": "import:ros2"}
            _present({**head, **facts}, bag, out, as_json)
            return
    with progress_bar("import ros2 (messages)", show=wanted(as_json)) as bar:
        session = import_ros2(
            bag, topic=topic, temperature_topic=temperature_topic, mag_topic=mag_topic, progress=bar
        )
    if detect_holds:
        session = label_detected_holds(session)
    _write(session, bag, out, as_json, batch_size, compression, force)


ImuOpt = Annotated[int, typer.Option("--imu", min=0, help="IMU instance (0 = the first).")]


@import_app.command("ulog")
def import_ulog_cmd(
    file: Annotated[Path, typer.Argument(help="PX4 ULog file (.ulg).")],
    out: OutOpt,
    imu: ImuOpt = 0,
    as_json: JsonOpt = False,
    batch_size: BatchOpt = 500,
    compression: CompressionOpt = "zstd",
    force: ForceOpt = False,
) -> None:
    """PX4 ULog -> MCAP: sensor_accel instance --imu with its temperature and device_id, the same
    device's sensor_gyro; m/s^2 -> g, rad/s -> deg/s. Example: `accellog import ulog log.ulg -o s.mcap`."""
    from accellog.store.importers.ulog import import_ulog

    _check_out(out, file, compression, force)
    _write(import_ulog(file, imu=imu), file, out, as_json, batch_size, compression, force)


@import_app.command("dataflash")
def import_dataflash_cmd(
    file: Annotated[Path, typer.Argument(help="ArduPilot DataFlash log (.bin).")],
    out: OutOpt,
    imu: ImuOpt = 0,
    as_json: JsonOpt = False,
    batch_size: BatchOpt = 500,
    compression: CompressionOpt = "zstd",
    force: ForceOpt = False,
) -> None:
    """ArduPilot DataFlash log -> MCAP: the IMU messages of instance --imu (AccX..Z, GyrX..Z, T), device
    ids from INS_ACC_ID / INS_GYR_ID. Example: `accellog import dataflash 00000042.BIN -o s.mcap`."""
    from accellog.store.importers.dataflash import import_dataflash

    _check_out(out, file, compression, force)
    _write(import_dataflash(file, imu=imu), file, out, as_json, batch_size, compression, force)
