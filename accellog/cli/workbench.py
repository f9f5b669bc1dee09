"""`accellog diagnose` (the model workbench) and `accellog effects` (the effect library)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from accellog.cli.app import app
from accellog.core.errors import InputError


def _fmt(v, spec: str = ".3g") -> str:
    import numpy as np

    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return format(v, spec)


@app.command(rich_help_panel="3. Discover")
def effects(
    effects_file: Annotated[
        Path | None, typer.Option("--effects-file", help="Python file with user effects (docs/effects.md).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable list on stdout.")] = False,
) -> None:
    """List the effect library: name, parameters with units, driver signals, meaning."""
    from rich.table import Table

    from accellog.calibrate.effects import describe, load_effects_file

    ef = load_effects_file(effects_file) if effects_file else None
    rows = describe(ef)
    if as_json:
        print(json.dumps(rows, indent=1))
        return
    t = Table(title="accellog effect library (names accepted by --add)")
    for c in ("effect", "parameters [unit]", "drivers", "meaning", "revealed by"):
        t.add_column(c, overflow="fold")
    for r in rows:
        params = (
            ", ".join(f"{p} [{u}]" for p, u in zip(r["params"], r["units"], strict=True))
            or "(none in static model)"
        )
        t.add_row(
            r["effect"],
            escape(params),
            ", ".join(r["drivers"]) or "-",
            escape(r["meaning"]),
            escape(r["reveal"]),
        )
    Console(width=200).print(t)
    print("presets: model1 = bias; model2 = bias+scale; model3 = bias+scale+cross_axis")


@app.command(rich_help_panel="3. Discover")
def diagnose(
    session: Annotated[
        Path,
        typer.Argument(
            help="Session with labelled static holds (.mcap, or a CSV the importers read: capstone pose "
            "table or static test file, generic CSV), or an observations JSON."
        ),
    ],
    model: Annotated[str, typer.Option("--model", "-m", help="Preset or '+'-joined effects.")] = "model3",
    add: Annotated[list[str] | None, typer.Option("--add", help="Extra effect (repeatable).")] = None,
    effects_file: Annotated[
        Path | None, typer.Option("--effects-file", help="Python file with user effects (docs/effects.md).")
    ] = None,
    window_s: Annotated[float, typer.Option(help="Averaging window within each hold (s).", min=0.01)] = 2.0,
    unweighted: Annotated[
        bool, typer.Option("--unweighted", help="Fit without sigma weights (seed).")
    ] = False,
    gravity_g: Annotated[float, typer.Option(help="Truth magnitude in g (local gravity / g0).")] = 1.0,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable diagnosis on stdout.")] = False,
    rrd: Annotated[
        Path | None,
        typer.Option("--rrd", help="Also write a Rerun recording: residuals per pose, verdict, candidates."),
    ] = None,
    heldout: Annotated[
        list[Path] | None,
        typer.Option(
            help="Another session of the same sensor (repeatable): candidates are judged by how well they "
            "predict it (else by blocked validation over temperature and time within the session)."
        ),
    ] = None,
    detect_window_s: Annotated[
        float,
        typer.Option(
            help="Hand-held sessions (no pose labels): static-detector variance window (s).", min=0.01
        ),
    ] = 1.0,
    threshold: Annotated[
        float | None,
        typer.Option(
            help="Hand-held sessions: detector threshold factor k (still when variance < k x reference); "
            "default: swept 2..10, best by the orientation-free residual.",
            min=1.0,
        ),
    ] = None,
    noise_from: Annotated[
        Path | None,
        typer.Option(
            help="Calibration JSON with a noise section (`accellog noise --cal`): its white noise (Allan) "
            "floors each window's sigma, so chi2 is judged against the characterised noise."
        ),
    ] = None,
) -> None:
    """Fit a model, compare it with the noise floor and rank the effects that could be missing.
    A session without pose labels (hand-held) is diagnosed on its detected static intervals with
    the orientation-free gravity-norm residual."""
    import numpy as np

    from accellog.calibrate import diagnose as dg
    from accellog.calibrate.model import build_model
    from accellog.present.tables import json_text

    if not session.is_file():
        raise InputError("session file not found", where=str(session))
    from accellog.calibrate.segment import observations
    from accellog.core.session import ObsTable, Session
    from accellog.flows.stages import as_session, load_input
    from accellog.flows.stream_input import open_labelled

    streamed = open_labelled(session, window_s=window_s, host=True) if rrd is None else None
    data = (
        streamed if streamed is not None else load_input(session)
    )  # pose tables and observation files: ObsTable
    if isinstance(data, Session) and not data.poses:
        return _diagnose_handheld(
            data, session, model, add, effects_file, window_s, detect_window_s, threshold, as_json
        )
    m = build_model(model, add=add or [], effects_file=effects_file)
    host = None
    if isinstance(data, ObsTable):
        obs = data
    elif streamed is not None:  # an MCAP session, chunk by chunk (bounded memory)
        obs, host = streamed.obs, streamed.host_clock
    else:
        obs = observations(data, window_s=window_s)
        if data.host_time_s is not None and np.all(np.isfinite(data.host_time_s)) and data.n > 2:
            host = (data.t_s, data.host_time_s)

    helds = [observations(as_session(h, "--heldout"), window_s=window_s) for h in heldout or []]
    if noise_from is not None:
        from accellog.calibrate.calibration import load_calibration
        from accellog.calibrate.noise_model import floor_obs_sigma

        section = load_calibration(noise_from).noise
        if not section:
            raise InputError(
                "no noise section: add one with `accellog noise STILL.mcap --cal C -o C2`",
                where=str(noise_from),
            )
        meta = getattr(data, "meta", None)
        rate = meta.sample_rate_hz if meta is not None else None
        obs, helds = floor_obs_sigma(obs, section, rate), [floor_obs_sigma(h, section, rate) for h in helds]
    d = dg.diagnose(obs, m, weighted=not unweighted, gravity_g=gravity_g, host_time=host, heldout=helds)
    if rrd is not None:
        from accellog.present.residual_views import log_diagnosis_residuals
        from accellog.present.rrd.recording import RunRecording
        from accellog.present.views import log_diagnosis, log_session

        with RunRecording(f"save:{rrd}") as rec:
            if not isinstance(data, ObsTable):
                log_session(rec, data)
            log_diagnosis(rec, d, obs)
            log_diagnosis_residuals(rec, d, obs)
            rec.log_series(
                "residuals/windows",
                np.asarray(obs.t_s, float),
                np.asarray(d.fit.residual_g, float) * 1000.0,
                [f"{d.model.name} residual {a} (mg)" for a in "xyz"],
                points=True,
            )
    if as_json:
        out = d.to_dict()
        out["session"] = str(session)
        print(json_text(out))
        return
    _print(d, str(session))


def _diagnose_handheld(
    data, session, model, add, effects_file, window_s, detect_window_s, threshold, as_json
):
    """diagnose on an unlabelled session: detected static intervals, gravity-norm residual."""
    from accellog.calibrate.handheld import HANDHELD_START, detect_holds, diagnose_handheld
    from accellog.calibrate.model import build_model
    from accellog.present.tables import json_text

    name = HANDHELD_START if model == "model3" else model  # model3's cross_axis is not identifiable here
    m = build_model(name, add=add or [], effects_file=effects_file)
    obs, det = detect_holds(data, window_s=detect_window_s, threshold=threshold, obs_window_s=window_s)
    d = diagnose_handheld(obs, m)
    if as_json:
        out = d.to_dict()
        out.update(session=str(session), handheld=True, detected=det.to_dict())
        print(json_text(out))
        return
    con = Console(width=160)
    con.print(
        f"[bold]{session}[/]: no pose labels: {len(det.intervals)} static intervals detected "
        f"(window {det.window_s:g} s, threshold {det.threshold if det.threshold is not None else 'swept 2..10'})"
    )
    _print(d, str(session))


def _print(d, source: str) -> None:
    from rich.table import Table

    con = Console(width=160)
    f = d.fit
    con.print(f"[bold]{source}[/]: {f.n_obs} windows, model {d.model.name} ({d.model.n_params} params)")
    t = Table(title="parameters (1-sigma: noise-only Cramer-Rao bound)")
    for c in ("param", "value", "1-sigma", "unit"):
        t.add_column(c, justify="right" if c in ("value", "1-sigma") else "left")
    for n, v, s, u in zip(f.param_names, f.theta, f.sigma, f.param_units, strict=True):
        t.add_row(n, f"{v:.6g}", f"{s:.2g}", u)
    con.print(t)
    if d.choice is not None:
        con.print(
            f"out-of-sample evidence ({d.choice.evidence}): base chi2/eq {d.choice.base_score.chi2_per_eq:.3g}; "
            + escape(d.choice.reason)
        )
    t = Table(title="candidate effects (model + effect; OOS = held-out or blocked validation)")
    for c in (
        "#",
        "effect",
        "ident.",
        "signif.",
        "chi2/dof",
        "dBIC",
        "CV chi2/eq",
        "OOS chi2/eq",
        "p",
        "reason / what to record",
    ):
        t.add_column(c, overflow="fold")
    for c in d.candidates:
        t.add_row(
            str(c["rank"]),
            c["effect"],
            "yes" if c["identifiable"] else "no",
            "YES" if c.get("significant") else "",
            _fmt(c.get("chi2_dof")),
            _fmt(c.get("delta_bic"), ".1f"),
            _fmt(c.get("cv_chi2_per_eq")),
            _fmt(c.get("oos_chi2_per_eq")),
            _fmt(c.get("p_value"), ".2g"),
            escape(c.get("reason", "")),
        )
    con.print(t)
    t = Table(title="residuals vs driver signals (top 10; dchi2 = drop if added as a term on that axis)")
    for c in ("signal", "axis", "corr", "partial R^2", "dchi2", "p"):
        t.add_column(c)
    for s in d.driver_signals[:10]:
        t.add_row(
            s["signal"] + (" *" if s["significant"] else ""),
            s["axis"],
            f"{s['correlation']:+.2f}",
            f"{s['partial_r2']:.3f}",
            f"{s['delta_chi2']:.3g}",
            f"{s['p_value']:.2g}",
        )
    con.print(t)
    con.print(("[bold red]MISSING[/] " if d.missing else "[bold green]OK[/] ") + escape(d.verdict))
    for a in d.advice:
        con.print(f"  - {escape(a)}")


@app.command(name="workbench", rich_help_panel="3. Discover")
def workbench_cmd(
    session: Annotated[
        Path,
        typer.Argument(
            help="Calibration session (.mcap or CSV): labelled static holds, or a hand-held session "
            "(no labels: detected static intervals, gravity-norm residual)."
        ),
    ],
    heldout: Annotated[
        list[Path] | None,
        typer.Option(
            help="Another session of the same sensor (repeatable): each candidate effect is judged by how "
            "well it predicts it, so effects that do not transfer are not chosen."
        ),
    ] = None,
    static: Annotated[
        Path | None, typer.Option(help="A static test session: |displacement| after --at-s per step.")
    ] = None,
    model: Annotated[
        str, typer.Option("--model", "-m", help="Start model (preset or '+'-joined).")
    ] = "model3",
    max_steps: Annotated[int, typer.Option(help="At most this many effects are added.", min=0)] = 4,
    effects_file: Annotated[
        Path | None, typer.Option("--effects-file", help="Python file with user effects (docs/effects.md).")
    ] = None,
    at_s: Annotated[float, typer.Option(help="Drift time of the static test (s).")] = 60.0,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write the final model's calibration JSON.")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable ladder on stdout.")] = False,
    rrd: Annotated[
        Path | None, typer.Option("--rrd", help="Also write a Rerun recording of the ladder.")
    ] = None,
) -> None:
    """Diagnose, add the missing effect, refit - until the model fits to the noise; then the ladder
    model1 -> model2 -> model3 -> + each found effect, judged on held-out data and a static test."""
    import numpy as np

    from accellog.calibrate.segment import observations
    from accellog.core.session import Session
    from accellog.flows.stages import as_session, load_input
    from accellog.flows.workbench import discover, ladder_rows, log_ladder, steps_for
    from accellog.present.tables import json_text, ladder_table

    data = load_input(session)
    if not isinstance(data, Session):
        raise InputError(
            "the workbench needs a recorded session (samples), not a pose table", where=str(session)
        )
    if not data.poses:  # hand-held: detected static intervals, gravity-norm residual
        test = as_session(static, "--static") if static is not None else None
        if heldout:
            Console(stderr=True).print(
                "note: --heldout is not used on a hand-held session (not yet supported)"
            )
        return _workbench_handheld(
            data, session, model, max_steps, effects_file, test, at_s, output, as_json, rrd
        )
    obs = observations(data)
    helds = [observations(as_session(h, "--heldout")) for h in heldout or []]
    held = helds[0] if helds else None
    test = as_session(static, "--static") if static is not None else None
    host = None
    if data.host_time_s is not None and np.all(np.isfinite(data.host_time_s)) and data.n > 2:
        host = (data.t_s, data.host_time_s)
    con = Console(stderr=as_json, width=160)
    found = discover(
        obs,
        model,
        heldout=helds,
        max_steps=max_steps,
        effects_file=effects_file,
        host_time=host,
        on_step=lambda d: con.print(
            f"step {d.model.name}: {escape(d.choice.reason if d.choice else d.verdict)}"
        ),
    )
    rows = ladder_rows(
        data,
        obs,
        steps_for(found),
        heldout=held,
        static_test=test,
        effects_file=effects_file,
        at_s=at_s,
        gyro=output is not None or rrd is not None,  # the gyro goes into the calibration file / .rrd
    )
    if output is not None:
        rows[-1].fit.cal.save(output)
    if rrd is not None:
        from accellog.present.residual_views import log_workbench_residuals
        from accellog.present.rrd.recording import RunRecording
        from accellog.present.views import log_diagnosis, log_session

        with RunRecording(f"save:{rrd}") as rec:
            log_session(rec, data, calibrations={found.final_model: rows[-1].fit.cal})
            for i, d in enumerate(found.diagnoses, 1):
                log_diagnosis(rec, d, obs, label=f"step {i}")
            log_ladder(rec, rows, obs)
            log_workbench_residuals(rec, obs, found.diagnoses[0].fit, rows[-1].fit.fit)
    if as_json:
        print(json_text({"session": str(session), **found.to_json(), "ladder": [r.to_dict() for r in rows]}))
        return
    ok = found.decided and found.transfers is not False and not found.diagnoses[-1].missing
    con.print(("[bold green]OK[/] " if ok else "[bold red]CHECK[/] ") + escape(found.verdict))
    for a in found.advice:
        con.print(f"advice: {escape(a)}")
    con.print(ladder_table(rows, title="watch the error fall: each step of model building"))
    if output is not None:
        con.print(f"wrote {output} ({found.final_model})")


def _workbench_handheld(data, session, model, max_steps, effects_file, test, at_s, output, as_json, rrd):
    """The workbench on an unlabelled session (accellog.flows.handheld_workbench)."""
    from accellog.flows.handheld_workbench import discover_handheld
    from accellog.present.tables import json_text, ladder_table

    start = None if model == "model3" else model  # model3's cross_axis is not identifiable here
    found = discover_handheld(
        data, start, max_steps=max_steps, effects_file=effects_file, static_test=test, at_s=at_s
    )
    if output is not None:
        from accellog.flows.stages import run_fit

        # the full orientation-free fit: gyro from the detected intervals and the rotations between them
        run_fit(
            data, found.start, add=found.added, effects_file=effects_file, orientation_free=True
        ).cal.save(output)
    if rrd is not None:
        from accellog.present.detection_views import log_detection
        from accellog.present.rrd.recording import RunRecording
        from accellog.present.views import log_session

        with RunRecording(f"save:{rrd}") as rec:
            log_session(rec, data)
            log_detection(rec, found.detection)
            rec.log_ladder(found.ladder)
    if as_json:
        print(json_text({"session": str(session), **found.to_dict()}))
        return
    con = Console(width=160)
    det = found.detection
    con.print(
        f"[bold]{session}[/]: no pose labels: {len(det.intervals)} static intervals detected "
        f"(window {det.window_s:g} s, threshold {det.threshold if det.threshold is not None else 'swept 2..10'}); "
        "judged on the gravity norm"
    )
    for d in found.diagnoses:
        con.print(f"step {escape(d.verdict)}")
    for a in found.cannot_identify:
        con.print(f"cannot identify: {escape(a)}")
    con.print(
        ladder_table(found.ladder, title="hand-held: each step of model building (gravity-norm residual)")
    )
    if output is not None:
        con.print(f"wrote {output} ({found.final_model})")
