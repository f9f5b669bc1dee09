"""`accellog diagnose`, `accellog workbench` (the model workbench) and `accellog effects` (the effect
library): each parses, calls one library function (accellog.flows.diagnose_run.run_diagnose,
accellog.flows.workbench.run_workbench, accellog.calibrate.model.effects.describe) and presents
(accellog.present.discovery_text)."""

from pathlib import Path
from typing import Annotated

import typer

from accellog.cli.app import ForceOpt, app


@app.command(rich_help_panel="3. Discover")
def effects(
    effects_file: Annotated[
        Path | None, typer.Option("--effects-file", help="Python file with user effects (docs/effects.md).")
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Machine-readable list on stdout.")] = False,
) -> None:
    """List the effect library: name, parameters with units, driver signals, meaning.

    Example: `accellog effects --effects-file examples/effects_creep.py`.
    """
    from accellog.calibrate.model.effects import describe, load_effects_file
    from accellog.core.jsonio import dumps
    from accellog.present.discovery_text import print_effects

    rows = describe(load_effects_file(effects_file) if effects_file else None)
    if as_json:
        print(dumps(rows, indent=1))
        return
    print_effects(rows)


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
    the orientation-free gravity-norm residual.

    Examples: `accellog diagnose cal.mcap`; `accellog diagnose cal.mcap --model model3+temp_bias
    --heldout other.mcap`.
    """
    from accellog.flows.diagnose_run import run_diagnose

    out = run_diagnose(
        session,
        model=model,
        add=add or [],
        effects_file=effects_file,
        window_s=window_s,
        weighted=not unweighted,
        gravity_g=gravity_g,
        heldout=heldout or [],
        detect_window_s=detect_window_s,
        threshold=threshold,
        noise_from=noise_from,
        rrd=rrd,
    )
    if as_json:
        print(out.to_json())  # strict JSON (core.jsonio): not the table module (calibrate/, navigate/)
        return
    from accellog.present.discovery_text import print_diagnose_outcome

    print_diagnose_outcome(out)


@app.command(name="workbench", rich_help_panel="3. Discover")
def workbench_cmd(
    sessions: Annotated[
        list[Path],
        typer.Argument(
            help="Calibration session (.mcap or CSV): labelled static holds, or a hand-held session "
            "(no labels: detected static intervals, gravity-norm residual). Several sessions of one "
            "sensor: fitted together, each candidate judged by leaving one session out.",
            show_default=False,
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
    force: ForceOpt = False,
) -> None:
    """Diagnose, add the missing effect, refit - until the model fits to the noise; then the ladder
    model1 -> model2 -> model3 -> + each found effect, judged on held-out data and a static test.

    Example: `accellog workbench warmup.mcap --heldout other.mcap --static static.mcap -o cal.json`.
    """
    from accellog.flows.workbench import run_workbench
    from accellog.present.discovery_text import print_notes, print_workbench, step_printer, terminal
    from accellog.present.tables import json_text

    con = terminal(stderr=as_json)
    out = run_workbench(
        sessions,
        heldout=heldout or [],
        static=static,
        model=model,
        max_steps=max_steps,
        effects_file=effects_file,
        at_s=at_s,
        output=output,
        rrd=rrd,
        on_step=step_printer(con),
    )
    print_notes(out.notes)
    if as_json:
        print(json_text(out.to_dict()))
        return
    print_workbench(out, con)
