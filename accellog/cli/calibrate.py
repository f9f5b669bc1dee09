"""Batch calibration commands: segment, fit, evaluate, drift, apply, run (pipelines).

Each command calls a plain function of accellog.flows.pipeline (run_fit, run_evaluate, run_drift,
run_pipeline; accellog.flows.apply.run_apply) and prints rich tables, or machine-readable JSON on stdout with --json.
"""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.cli.app import CompressionOpt, EffectsOpt, ForceOpt, app
from accellog.core.errors import InputError

_console = Console()

JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable JSON on stdout instead of tables.")]
RrdOpt = Annotated[
    Path | None,
    typer.Option("--rrd", help="Also write a Rerun recording (.rrd) of this run (open: accellog view)."),
]


SessionsArg = Annotated[
    list[Path],
    typer.Argument(
        help="Calibration session (.mcap), pose table CSV or observations JSON; several unlabelled "
        "sessions of one device are pooled (their stops)."
    ),
]

PriorOpt = Annotated[
    Path | None,
    typer.Option(help="A calibration of this device (the lab's): the sessions' stops update it."),
]

AddOpt = Annotated[
    list[str] | None,
    typer.Option("--add", help="Add an effect (repeatable; with --prior added to it at its typical size)."),
]

AgingOpt = Annotated[
    list[str] | None,
    typer.Option(
        help="EFFECT=SIGMA: how far the effect's parameters may have moved since the prior (its "
        "units; repeatable; default bias=0.01 scale=0.002 cross_axis=0.0005 misalignment_tri=0.0005)."
    ),
]


def _save_outcome(out, data, output: Path, rrd: Path | None, json_out: bool, inputs: tuple) -> bool:
    """Write the .rrd (if asked) first, so that an error there leaves no calibration behind, then the
    calibration (never over one of ``inputs``); with --json print the result; True when printed."""
    if rrd is not None:
        out.write_rrd(rrd, data)
    out.cal.save(output, inputs=inputs)
    if json_out:
        _echo_json({**out.to_dict(), "output": str(output)})
    return json_out


def _echo_json(data) -> None:
    from accellog.present import tables as report

    typer.echo(report.json_text(data))


@app.command(rich_help_panel="2. Calibrate")
def segment(
    session: Annotated[Path, typer.Argument(help="Session (.mcap, or a CSV the importers read).")],
    window_s: Annotated[float, typer.Option(help="Observation window within a hold (s).")] = 2.0,
    trim_s: Annotated[float, typer.Option(help="Dropped at both ends of every hold (s).")] = 0.5,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write observations JSON here.")
    ] = None,
    json_out: JsonOpt = False,
    force: ForceOpt = False,
) -> None:
    """Per-pose statistics (mean, std, autocorrelation-aware sem) and windowed observations.

    Example: `accellog segment cal.mcap --window-s 2 -o obs.json`, then `accellog fit obs.json -o
    cal.json`.
    """
    from accellog.calibrate.calfile.calibration import write_json_atomic
    from accellog.flows.stages import run_segment
    from accellog.present import tables as report
    from accellog.store.atomic import check_outputs

    check_outputs([output], [session])
    res = run_segment(session, window_s=window_s, trim_s=trim_s)
    if output is not None:
        write_json_atomic(output, res.obs_dict(), inputs=(session,))
    if json_out:
        _echo_json(res.to_dict(str(output or "")))
        return
    _console.print(
        report.segment_table(
            f"{session}: {len(res.stats)} holds, {res.obs.n} observations of ~{window_s:g} s", res.stats
        )
    )


@app.command(rich_help_panel="2. Calibrate")
def fit(
    sessions: SessionsArg,
    output: Annotated[Path, typer.Option("-o", "--output", help="Calibration JSON to write.")],
    model: Annotated[
        str, typer.Option("--model", "-m", help="model1 | model2 | model3 | effect+effect...")
    ] = "model3",
    add: AddOpt = None,
    effects_file: Annotated[Path | None, typer.Option(help="Python file with user effects.")] = None,
    unweighted: Annotated[
        bool, typer.Option("--unweighted", help="Unweighted least squares (the seed).")
    ] = False,
    orientation_free: Annotated[
        bool,
        typer.Option("--orientation-free", help="Fit |f| = g without pose labels (static holds detected)."),
    ] = False,
    gravity: Annotated[
        str, typer.Option(help="'local' (truth g_local/g0, standard g) or 'seed' (truth 1).")
    ] = "local",
    local_gravity: Annotated[
        float | None, typer.Option(help="Local gravity (m/s^2); default the session's.")
    ] = None,
    window_s: Annotated[float, typer.Option(help="Observation window (s).")] = 2.0,
    trim_s: Annotated[float, typer.Option(help="Trim at both ends of every hold (s).")] = 0.5,
    json_out: JsonOpt = False,
    rrd: RrdOpt = None,
    uncertainty: Annotated[
        str,
        typer.Option(
            help="1-sigma from: 'noise' (window noise only), 'between_hold' (plus the scatter between "
            "holds, as a variance component) or 'jackknife' (leave one hold out)."
        ),
    ] = "noise",
    relabel: Annotated[
        bool,
        typer.Option("--relabel", help="Replace hold labels that contradict the measured gravity direction."),
    ] = False,
    prior: PriorOpt = None,
    aging: AgingOpt = None,
    force: ForceOpt = False,
) -> None:
    """Fit an error model to static poses and write a calibration (parameters with 1-sigma).

    Examples: `accellog fit cal.mcap -o cal.json`; `accellog fit cal.mcap --add temp_bias -o cal.json
    --rrd fit.rrd`; hand-held (no labels): orientation-free; a robot's runs update the lab's
    calibration: `accellog fit run1.mcap run2.mcap --prior lab.json -o field.json`.
    """
    from accellog.calibrate.model.prior import source_line
    from accellog.flows.stages import load_input, run_fit
    from accellog.present import tables as report
    from accellog.store.atomic import check_outputs

    check_outputs([output, rrd], [*sessions, effects_file, prior])
    if len(sessions) > 1 and rrd is not None:
        raise InputError("--rrd draws one session: give one session with it")
    data = load_input(sessions[0]) if rrd is not None else sessions[0]  # a path: run_fit may stream it
    out = run_fit(sessions if len(sessions) > 1 else data, model, add=add or [], effects_file=effects_file,
                  weighted=not unweighted, orientation_free=orientation_free, gravity=gravity,
                  local_gravity_mps2=local_gravity, window_s=window_s, trim_s=trim_s, uncertainty=uncertainty,
                  relabel=relabel, prior=prior, aging=_aging(aging))  # fmt: skip
    if _save_outcome(out, data, output, rrd, json_out, inputs=(*sessions, effects_file, prior)):
        return
    _console.print(report.params_table(out.cal))
    for row in out.fit.prior_sources or []:
        _console.print(source_line(row))
    if out.fit.uncertainty_note:
        _console.print(f"1σ: {out.fit.uncertainty_note}")
    for w in out.fit.warnings:
        _console.print(f"[yellow]warning:[/] {w}")
    _console.print(f"wrote {output}")


def _aging(items: list[str] | None) -> dict[str, float] | None:
    """--aging EFFECT=SIGMA options as {effect: sigma} (None: the defaults)."""
    if not items:
        return None
    out = {}
    for it in items:
        name, _, val = it.partition("=")
        try:
            out[name.strip()] = float(val)
        except ValueError:
            raise InputError(f"--aging {it!r}: give EFFECT=SIGMA, e.g. bias=0.01") from None
        if not out[name.strip()] >= 0:
            raise InputError(f"--aging {it!r}: the sigma must be >= 0")
    return out


@app.command(name="evaluate", rich_help_panel="2. Calibrate")
def evaluate_cmd(
    test: Annotated[Path, typer.Argument(help="Static test session (one orientation).")],
    cal: Annotated[list[Path], typer.Option("--cal", help="Calibration JSON (repeatable to compare).")],
    until_s: Annotated[float | None, typer.Option(help="Use samples with t <= until_s only.")] = None,
    max_samples: Annotated[int | None, typer.Option(help="Use the first N samples only.")] = None,
    at_s: Annotated[float, typer.Option(help="Displacement table time (s).")] = 60.0,
    json_out: JsonOpt = False,
    rrd: RrdOpt = None,
    effects_file: EffectsOpt = None,
) -> None:
    """Residual of calibrated static data vs gravity (mean +- sem, chi2 vs noise) and displacement.

    A session with several labelled holds is evaluated window by window (per-hold mean residual,
    RMS, chi2 vs the noise estimate, displacement at --at-s extrapolated per hold from rest).

    Example: `accellog evaluate static.mcap --cal model2.json --cal model3.json` (side by side).
    """
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.flows.stages import run_evaluate_report
    from accellog.present import tables as report

    rep = run_evaluate_report(
        test,
        [load_calibration(c, effects_file) for c in cal],
        until_s=until_s,
        max_samples=max_samples,
        at_s=at_s,
        stream=rrd is None,
    )
    if rrd is not None:
        rep.write_rrd(rrd)
    if json_out:
        _echo_json(rep.to_dict())
        return
    if rep.poses:
        report.print_tables([report.pose_eval_table(p) for p in rep.poses], _console)
        report.print_tables([report.pass_eval_table(p) for p in rep.poses[1:]], _console)  # not the raw
        for line in report.pose_eval_summary(rep.poses, at_s):
            _console.print(line)
        for line in (f for p in rep.poses for f in p.flags):
            _console.print(f"[yellow]{line}[/]")
        return
    if rep.handheld:
        report.print_tables([report.handheld_eval_table(h) for h in rep.handheld], _console)
        _console.print(f"[dim]{rep.to_dict()['cannot_judge']}[/]")
        return
    evs = rep.single
    report.print_tables([report.static_means_table(evs), report.displacement_table(evs, at_s=at_s)], _console)
    drifted = [e for e in evs if e.drift_applied]
    if drifted:
        title = f"after the drift model at {at_s:g} s"
        report.print_tables(
            [report.displacement_table(drifted, at_s=at_s, drift=True, title=title)], _console
        )
    for e in evs:
        for n in e.notes:
            _console.print(f"[dim]{e.label}: {n}[/]")


@app.command(rich_help_panel="2. Calibrate")
def drift(
    static: Annotated[Path, typer.Argument(help="Static session at rest (one orientation).")],
    cal: Annotated[Path, typer.Option("--cal", help="Calibration JSON to apply first.")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Calibration JSON with the drift model added.")
    ],
    until_s: Annotated[float | None, typer.Option(help="Fit on samples with t <= until_s.")] = None,
    max_samples: Annotated[int | None, typer.Option(help="Fit on the first N samples.")] = None,
    json_out: JsonOpt = False,
    rrd: RrdOpt = None,
    effects_file: EffectsOpt = None,
    force: ForceOpt = False,
) -> None:
    """Fit the displacement-drift polynomial d' = d + 1/2 q2 t^2 + q1 t + q0 on calibrated static data.

    Example: `accellog drift static.mcap --cal cal.json -o cal_drift.json`.
    """
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.flows.stages import run_drift
    from accellog.present import tables as report
    from accellog.store.atomic import check_outputs
    from accellog.store.source import read_whole

    check_outputs([output, rrd], [static, cal, effects_file])
    c = load_calibration(cal, effects_file)
    data = (
        read_whole(static, what="drift") if rrd is not None else static
    )  # an MCAP file streams (no series to draw)
    out = run_drift(data, c, until_s=until_s, max_samples=max_samples)
    if _save_outcome(out, data, output, rrd, json_out, inputs=(static, cal)):
        return
    rows = [("calibrated", out.fit_eval.disp_end_m)]
    if out.fit_eval.disp_end_drift_m is not None:
        rows.append(("calibrated + drift model", out.fit_eval.disp_end_drift_m))
    report.print_tables(list(report.drift_table(rows, out.fit_eval.t_end_s, out.drift)), _console)
    _console.print(f"wrote {output}")


@app.command(rich_help_panel="2. Calibrate")
def apply(
    session: Annotated[Path, typer.Argument(help="Session (.mcap) to calibrate.")],
    cal: Annotated[Path, typer.Option("--cal", help="Calibration JSON.")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Output .mcap (copy + calibrated channels).")
    ],
    ros2: Annotated[
        Path | None,
        typer.Option(
            "--ros2", help="Also write a ROS 2 bag (sensor_msgs/Imu with covariances): OUT.mcap or a dir."
        ),
    ] = None,
    other_device: Annotated[
        str,
        typer.Option(help="A calibration of another device (device keys differ): 'refuse' or 'warn'."),
    ] = "refuse",
    compression: CompressionOpt = "zstd",
    effects_file: EffectsOpt = None,
    topic: Annotated[
        str | None,
        typer.Option("--topic", help="--ros2 IMU topic (default: the input bag's, else /imu/data)."),
    ] = None,
    frame_id: Annotated[
        str | None,
        typer.Option("--frame-id", help="--ros2 header frame_id (default: the input bag's, else imu_link)."),
    ] = None,
    force: ForceOpt = False,
) -> None:
    """Copy a session and add /derived/accel_calibrated (g) and /derived/accel_calibrated_mps2.

    Example: `accellog apply s.mcap --cal cal.json -o s_cal.mcap --ros2 s_cal_ros2.mcap` (a session
    imported from a ROS 2 bag keeps the bag's topic and frame_id).
    """
    import warnings

    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.cli.progress import progress_bar
    from accellog.flows.apply import OtherDeviceWarning, run_apply
    from accellog.store.atomic import check_outputs

    check_outputs([output, ros2], [session, cal, effects_file])
    c = load_calibration(cal, effects_file)
    with (
        warnings.catch_warnings(record=True) as caught,
        progress_bar("ROS 2 bag", show=None if ros2 else False) as bar,
    ):
        warnings.simplefilter("always", OtherDeviceWarning)
        p = run_apply(
            session, c, output, ros2=ros2, other_device=other_device, compression=compression,
            ros2_topic=topic, ros2_frame_id=frame_id, progress=bar,
        )  # fmt: skip
    for w in caught:
        if issubclass(w.category, OtherDeviceWarning):
            _console.print(f"[yellow]warning: {w.message}[/]")
    if ros2 is not None:
        _console.print(f"wrote {ros2}")
    _console.print(f"wrote {p}")


@app.command(rich_help_panel="2. Calibrate")
def run(
    pipeline: Annotated[Path, typer.Argument(help="Pipeline TOML (see pipelines/).")],
    sessions: Annotated[list[Path], typer.Argument(help="Input files in the order of pipeline.inputs.")],
    output_dir: Annotated[
        Path | None, typer.Option("-o", "--output-dir", help="Write calibrations + results.json.")
    ] = None,
    json_out: JsonOpt = False,
    rrd: RrdOpt = None,
    effects_file: EffectsOpt = None,
) -> None:
    """Run a pipeline file (segment -> fit -> evaluate -> drift -> report).

    Example: `accellog run pipelines/six_position.toml cal.mcap static.mcap static.mcap static2.mcap
    -o out` (the sessions in the order of the pipeline's inputs).
    """
    from accellog.flows.pipeline import run_pipeline
    from accellog.present import tables as report
    from accellog.store.atomic import check_outputs

    check_outputs([rrd], [pipeline, *sessions, effects_file])
    if output_dir is not None and output_dir.exists() and not output_dir.is_dir():
        raise InputError("--output-dir is an existing file, not a folder", where=str(output_dir))
    res = run_pipeline(pipeline, [str(s) for s in sessions], output_dir=output_dir, effects_file=effects_file)
    if rrd is not None:
        res.write_rrd(rrd)
    if json_out:
        _echo_json(res.to_dict())
        return
    report.print_tables(res.tables(), _console)
    for w in res.written:
        _console.print(f"wrote {w}")


@app.command(rich_help_panel="2. Calibrate")
def integrate(
    session: Annotated[Path, typer.Argument(help="Static session (one orientation) to integrate.")],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="CSV: t_s, velocity (m/s) and displacement (m).")
    ],
    cal: Annotated[
        Path | None, typer.Option("--cal", help="Calibration JSON (default: the raw reading).")
    ] = None,
    until_s: Annotated[float | None, typer.Option(help="Use samples with t <= until_s only.")] = None,
    json_out: JsonOpt = False,
    effects_file: EffectsOpt = None,
    force: ForceOpt = False,
) -> None:
    """Integrate a static session twice over its recorded (uneven) timestamps, gravity removed with
    local gravity: a = f * g_local - up * g_local (m/s^2); v, d by cumulative trapezoid.

    Example: `accellog integrate static.mcap --cal cal.json -o disp.csv`.
    """
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.flows.stages import run_integrate
    from accellog.present import tables as report
    from accellog.store.atomic import check_outputs

    check_outputs([output], [session, cal, effects_file])
    c = load_calibration(cal, effects_file) if cal is not None else None
    res = run_integrate(session, c, until_s=until_s, output=output)
    if json_out:
        _echo_json(res.to_dict(str(output)))
        return
    ev = res.evaluation
    report.print_tables([report.displacement_table([ev], at_s=float(ev.times_s[-1]))], _console)
    _console.print(f"wrote {output} ({ev.n} rows)")
