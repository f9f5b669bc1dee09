"""Batch calibration commands: segment, fit, evaluate, drift, apply, run (pipelines).

Each command calls a plain function of accellog.flows.pipeline (run_fit, run_evaluate, run_drift,
run_apply, run_pipeline) and prints rich tables, or machine-readable JSON on stdout with --json.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.calibrate.calibration import write_json_atomic
from accellog.calibrate.obs_file import obs_to_dict
from accellog.calibrate.segment import pose_stats
from accellog.cli.app import app
from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.flows.pipeline import run_pipeline
from accellog.flows.stages import load_input, run_apply, run_drift, run_evaluate, run_fit
from accellog.present import tables as report
from accellog.present import views
from accellog.store.atomic import check_outputs, write_text_atomic

_console = Console()

JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable JSON on stdout instead of tables.")]
RrdOpt = Annotated[
    Path | None,
    typer.Option("--rrd", help="Also write a Rerun recording (.rrd) of this run (open: accellog view)."),
]


def _echo_json(data) -> None:
    typer.echo(report.json_text(data))


def _recording(path: Path):
    """A RunRecording saving to path (written to a temporary name, renamed when complete)."""
    from accellog.present.rrd.recording import RunRecording

    return RunRecording(f"save:{path}")


@app.command(rich_help_panel="2. Calibrate")
def segment(
    session: Annotated[Path, typer.Argument(help="Session (.mcap, or a CSV the importers read).")],
    window_s: Annotated[float, typer.Option(help="Observation window within a hold (s).")] = 2.0,
    trim_s: Annotated[float, typer.Option(help="Dropped at both ends of every hold (s).")] = 0.5,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write observations JSON here.")
    ] = None,
    json_out: JsonOpt = False,
) -> None:
    """Per-pose statistics (mean, std, autocorrelation-aware sem) and windowed observations."""
    check_outputs([output], [session], mkdir=True)
    data = load_input(session)
    if not isinstance(data, Session):
        raise InputError("segment needs a recorded session (samples), not a pose table", where=str(session))
    stats = pose_stats(data, trim_s=trim_s)
    from accellog.calibrate.segment import observations

    obs = observations(data, window_s=window_s, trim_s=trim_s)
    if output is not None:
        write_json_atomic(output, obs_to_dict(obs), inputs=(session,))
    if json_out:
        _echo_json(
            {"poses": [p.to_dict() for p in stats], "n_observations": obs.n, "output": str(output or "")}
        )
        return
    from rich.table import Table

    t = Table(title=f"{session}: {len(stats)} holds, {obs.n} observations of ~{window_s:g} s")
    t.add_column("pose")
    t.add_column("t (s)")
    t.add_column("n", justify="right")
    for ax in "xyz":
        t.add_column(f"{ax} mean ± sem (g)", justify="right")
    t.add_column("tau (samples)", justify="right")
    t.add_column("T (degC)", justify="right")
    for p in stats:
        t.add_row(
            p.name,
            f"{p.start_s:.1f}-{p.end_s:.1f}",
            str(p.n),
            *(report.fmt_pm(float(m), float(s)) for m, s in zip(p.mean_g, p.sem_g, strict=True)),
            "/".join(f"{x:.1f}" for x in p.tau_samples),
            "-" if p.temp_degC is None else f"{p.temp_degC:.2f}",
        )
    _console.print(t)


@app.command(rich_help_panel="2. Calibrate")
def fit(
    session: Annotated[
        Path, typer.Argument(help="Calibration session (.mcap), pose table CSV or observations JSON.")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="Calibration JSON to write.")],
    model: Annotated[
        str, typer.Option("--model", "-m", help="model1 | model2 | model3 | effect+effect...")
    ] = "model3",
    add: Annotated[list[str] | None, typer.Option("--add", help="Add an effect (repeatable).")] = None,
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
    relabel: Annotated[
        bool,
        typer.Option("--relabel", help="Replace hold labels that contradict the measured gravity direction."),
    ] = False,
) -> None:
    """Fit an error model to static poses and write a calibration (parameters with 1-sigma)."""
    check_outputs([output, rrd], [session, effects_file], mkdir=True)
    data = load_input(session)
    if relabel and isinstance(data, Session):
        from accellog.calibrate.label_check import relabel_holds
        from accellog.core.notices import note

        data, changes = relabel_holds(data, trim_s=trim_s)
        for c in changes:
            note(f"{session}: relabelled {c.pose!r} as {c.likely!r}: {c.line()}")
    out = run_fit(
        data,
        model,
        add=add or [],
        effects_file=effects_file,
        weighted=not unweighted,
        orientation_free=orientation_free,
        gravity=gravity,
        local_gravity_mps2=local_gravity,
        window_s=window_s,
        trim_s=trim_s,
    )
    if rrd is not None:  # the recording first: an error there leaves no calibration behind
        with _recording(rrd) as rec:
            if isinstance(data, Session):
                views.log_session(rec, data, calibrations={out.fit.model.name: out.cal})
            views.log_fit(rec, out)
    out.cal.save(output, inputs=(session, effects_file))
    if json_out:
        d = out.to_dict()
        d["output"] = str(output)
        _echo_json(d)
        return
    _console.print(report.params_table(out.cal))
    for w in out.fit.warnings:
        _console.print(f"[yellow]warning:[/] {w}")
    _console.print(f"wrote {output}")


@app.command(name="evaluate", rich_help_panel="2. Calibrate")
def evaluate_cmd(
    test: Annotated[Path, typer.Argument(help="Static test session (one orientation).")],
    cal: Annotated[list[Path], typer.Option("--cal", help="Calibration JSON (repeatable to compare).")],
    until_s: Annotated[float | None, typer.Option(help="Use samples with t <= until_s only.")] = None,
    max_samples: Annotated[int | None, typer.Option(help="Use the first N samples only.")] = None,
    at_s: Annotated[float, typer.Option(help="Displacement table time (s).")] = 60.0,
    json_out: JsonOpt = False,
    rrd: RrdOpt = None,
) -> None:
    """Residual of calibrated static data vs gravity (mean +- sem, chi2 vs noise) and displacement.

    A session with several labelled holds is evaluated window by window (per-hold mean residual,
    RMS, chi2 vs the noise estimate, displacement at --at-s extrapolated per hold from rest)."""
    from accellog.calibrate.calibration import load_calibration

    cals = [load_calibration(c) for c in cal]
    names = [c.model_spec.get("name", "") for c in cals]
    labels = [p.stem for p in cal] if len(set(names)) < len(names) else None  # tell same-model files apart
    data = load_input(test)
    if isinstance(data, Session) and len(data.poses) > 1:
        _evaluate_holds(
            data, cals, at_s, json_out, until_s is not None or max_samples is not None, rrd, labels
        )
        return
    evs = run_evaluate(
        data if isinstance(data, Session) else test,
        cals,
        until_s=until_s,
        max_samples=max_samples,
        labels=labels,
    )
    if rrd is not None:
        with _recording(rrd) as rec:
            if isinstance(data, Session):
                views.log_session(
                    rec, data, calibrations={e.label: c for e, c in zip(evs[1:], cals, strict=True)}
                )
            views.log_evaluations(rec, evs)
    if json_out:
        _echo_json({"raw": evs[0].to_dict(), "calibrated": [e.to_dict() for e in evs[1:]]})
        return
    report.print_tables([report.static_means_table(evs), report.displacement_table(evs, at_s=at_s)], _console)
    drifted = [e for e in evs if e.drift_applied]
    if drifted:
        report.print_tables(
            [
                report.displacement_table(
                    drifted, at_s=at_s, drift=True, title=f"after the drift model at {at_s:g} s"
                )
            ],
            _console,
        )
    for e in evs:
        for n in e.notes:
            _console.print(f"[dim]{e.label}: {n}[/]")


def _evaluate_holds(
    session: Session,
    cals: list,
    at_s: float,
    json_out: bool,
    cut: bool,
    rrd: Path | None = None,
    labels: list[str] | None = None,
) -> None:
    """`evaluate` on a multi-pose session: evaluate_poses for the raw reading and each calibration;
    --rrd: the session (raw and calibrated) and the per-pose residual tables."""
    from accellog.navigate.evaluate import evaluate_poses

    if cut:
        raise InputError(
            "--until-s/--max-samples cut a single static hold; this session has "
            f"{len(session.poses)} labelled holds",
            where=session.path,
        )
    g = cals[0].local_gravity_mps2 if cals else None
    pes = [evaluate_poses(session, None, at_s=at_s, local_gravity_mps2=g)]
    pes += [evaluate_poses(session, c, at_s=at_s) for c in cals]
    if rrd is not None:
        with _recording(rrd) as rec:
            views.log_session(
                rec, session, calibrations=dict(zip(labels or [p.label for p in pes[1:]], cals, strict=True))
            )
            md = "\n".join(views.table_markdown(report.pose_eval_table(p)) for p in pes)
            rec.log_document("results/poses", md)
    if json_out:
        _echo_json({"kind": "poses", "raw": pes[0].to_dict(), "calibrated": [p.to_dict() for p in pes[1:]]})
        return
    report.print_tables([report.pose_eval_table(p) for p in pes], _console)
    for p in pes:
        d = p.to_dict()[f"displacement_{at_s:g}s_m"]
        _console.print(
            f"{p.label}: RMS {p.rms_g * p.mps2_per_unit:.4g} m/s^2, chi2/dof {p.chi2 / max(p.dof, 1):.3g}; "
            f"worst hold displacement at {at_s:g} s (from rest, extrapolated) "
            + ", ".join(f"{a} {v:+.3g} m" for a, v in zip("xyz", d, strict=True))
        )


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
) -> None:
    """Fit the displacement-drift polynomial d' = d + 1/2 q2 t^2 + q1 t + q0 on calibrated static data."""
    check_outputs([output, rrd], [static, cal], mkdir=True)
    data = load_input(static)
    out = run_drift(data, cal, until_s=until_s, max_samples=max_samples)
    if rrd is not None:  # the recording first: an error there leaves no calibration behind
        with _recording(rrd) as rec:
            if isinstance(data, Session):
                views.log_session(rec, data, calibrations={"calibrated + drift model": out.cal})
            views.log_evaluations(rec, [out.fit_eval])
    out.cal.save(output, inputs=(static, cal))
    if json_out:
        d = out.to_dict()
        d["output"] = str(output)
        _echo_json(d)
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
) -> None:
    """Copy a session and add /derived/accel_calibrated (g) and /derived/accel_calibrated_mps2."""
    check_outputs([output], [session, cal])
    p = run_apply(session, cal, output)
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
) -> None:
    """Run a pipeline file (segment -> fit -> evaluate -> drift -> report)."""
    check_outputs([rrd], [pipeline, *sessions], mkdir=True)
    if output_dir is not None and output_dir.exists() and not output_dir.is_dir():
        raise InputError("--output-dir is an existing file, not a folder", where=str(output_dir))
    res = run_pipeline(pipeline, [str(s) for s in sessions], output_dir=output_dir)
    if rrd is not None:
        with _recording(rrd) as rec:
            for name, fo in res.fits.items():
                views.log_fit(rec, fo, name)
            views.log_evaluations(rec, res.evaluations)
            if res.drift_evaluations:
                views.log_evaluations(rec, res.drift_evaluations, truth_label=None)
            rec.log_document(
                "results/tables", "\n".join(views.table_markdown(t) for t in res.tables() if t is not None)
            )
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
) -> None:
    """Integrate a static session twice over its recorded (uneven) timestamps, gravity removed with
    local gravity: a = f * g_local - up * g_local (m/s^2); v, d by cumulative trapezoid."""
    import io

    check_outputs([output], [session, cal])
    import numpy as np

    from accellog.calibrate.calibration import load_calibration
    from accellog.core.timeseries import cumtrapz

    data = load_input(session)
    if not isinstance(data, Session):
        raise InputError("integrate needs a recorded session (samples), not a pose table", where=str(session))
    c = load_calibration(cal) if cal is not None else None
    ev = run_evaluate(data, [c] if c else [], include_raw=c is None, until_s=until_s)[-1]
    t, d = ev.t_s, ev.disp_series_m
    v = cumtrapz(t, ev.resid_series_mps2)  # the residual acceleration (m/s^2) is what integrates to d
    buf = io.StringIO()
    buf.write("t_s,vx_mps,vy_mps,vz_mps,x_m,y_m,z_m\n")
    np.savetxt(buf, np.column_stack([t, v, d]), delimiter=",", fmt="%.9g")
    write_text_atomic(output, buf.getvalue(), inputs=(session, cal))
    summary = {
        "session": str(session),
        "calibration": str(cal) if cal else None,
        "label": ev.label,
        "t_end_s": ev.t_end_s,
        "disp_end_m": ev.disp_end_m.tolist(),
        "displacement_at_s": {f"{ts:g}": ev.disp_at(ts).tolist() for ts in ev.times_s},
        "output": str(output),
    }
    if json_out:
        _echo_json(summary)
        return
    report.print_tables([report.displacement_table([ev], at_s=float(ev.times_s[-1]))], _console)
    _console.print(f"wrote {output} ({len(t)} rows)")
