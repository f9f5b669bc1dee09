"""Inspection commands: replay a session (live view or .rrd), compare calibrations, view an .rrd.

    accellog replay SESSION.mcap [--speed 1|4|max] [--cal cal.json ...] [--rrd FILE | --rerun spawn|connect URL]
    accellog compare TEST.mcap --cal A.json --cal B.json ... [--rrd OUT.rrd] [--json]
    accellog view RUN.rrd [--web] [--screenshot PNG]

Session files are only read. .rrd files are written to a temporary name and renamed when complete.
"""

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.cli.app import EffectsOpt, app
from accellog.core.errors import InputError

_console = Console()

CalOpt = Annotated[list[Path] | None, typer.Option("--cal", help="Calibration JSON (repeatable).")]
RrdOpt = Annotated[Path | None, typer.Option("--rrd", help="Write a Rerun recording (.rrd) here.")]
RerunOpt = Annotated[
    str | None,
    typer.Option("--rerun", help="Live view instead of a file: 'spawn', 'connect' or 'connect URL'."),
]
UpOpt = Annotated[
    str | None, typer.Option("--up", help="Up axis of the static session (+x..-z); default: inferred.")
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Machine-readable JSON on stdout instead of tables.")]
FullOpt = Annotated[
    bool,
    typer.Option(
        "--rrd-full",
        help="Log every sample to the recording (default: long series as min/max display envelopes).",
    ),
]


def _cals(paths: list[Path] | None, effects_file: Path | None) -> list:
    """The --cal files loaded (a model with user effects runs only the user's --effects-file)."""
    from accellog.calibrate.calfile.calibration import load_calibration

    return [load_calibration(p, effects_file) for p in paths or []]


def _print_result(res, title: str, json_out: bool) -> None:
    """Strict JSON (NaN -> null) on stdout, or the final-displacement table, notes and .rrd path."""
    from accellog.present.tables import replay_table

    if res.sink_report:
        _console.print(f"[yellow]{res.sink_report}[/]")
    if json_out:
        from accellog.core.jsonio import dumps

        typer.echo(dumps(res.to_dict(), indent=2))
        return
    _console.print(replay_table(res, title))
    for tr in res.tracks:
        for n in tr.notes:
            _console.print(f"[dim]{n}[/]")
    if res.rrd:
        _console.print(f"recording: {res.rrd}")


@app.command(rich_help_panel="4. Inspect")
def replay(
    session: Annotated[Path, typer.Argument(help="Recorded session (.mcap; importable CSVs also work).")],
    speed: Annotated[str, typer.Option(help="Sensor seconds per wall second: 1, 4, ... or 'max'.")] = "1",
    cal: CalOpt = None,
    label: Annotated[list[str] | None, typer.Option("--label", help="Track label per --cal.")] = None,
    rrd: RrdOpt = None,
    rerun: RerunOpt = None,
    up: UpOpt = None,
    raw: Annotated[bool, typer.Option("--raw/--no-raw", help="Also integrate the raw reading.")] = True,
    json_out: JsonOpt = False,
    rrd_full: FullOpt = False,
    effects_file: EffectsOpt = None,
) -> None:
    """Feed a session through online correction + integration in sensor time, logging raw and
    calibrated accel and displacement tracks to a live viewer or an .rrd.

    Example: `accellog replay robot.mcap --cal cal.json --rrd replay.rrd`.
    """
    from accellog.flows.inspect import run_replay, sink_option
    from accellog.flows.replay import parse_speed

    parse_speed(speed)  # fail early on a bad value
    sink = sink_option(rrd, rerun)
    res = run_replay(
        session,
        _cals(cal, effects_file),
        sink,
        speed=speed,
        up=up,
        raw=raw,
        label=label,
        compare_mode=False,
        full_rate=rrd_full,
    )
    title = f"{session.name}: {res.n} samples, {res.duration_s:.1f} s replayed in {res.wall_s:.1f} s"
    _print_result(res, title, json_out)


@app.command(rich_help_panel="4. Inspect")
def compare(
    test: Annotated[Path, typer.Argument(help="Static test session (.mcap or capstone CSV).")],
    cal: CalOpt = None,
    label: Annotated[list[str] | None, typer.Option("--label", help="Track label per --cal.")] = None,
    rrd: RrdOpt = None,
    up: UpOpt = None,
    raw: Annotated[bool, typer.Option("--raw/--no-raw", help="Include the uncalibrated track.")] = True,
    json_out: JsonOpt = False,
    rrd_full: FullOpt = False,
    effects_file: EffectsOpt = None,
) -> None:
    """Displacement tracks of several calibrations of one test session side by side, with their
    final drift (terminal table, --json, and a document in the .rrd).

    Example: `accellog compare robot.mcap --cal model2.json --cal model3.json --rrd compare.rrd`.
    """
    from accellog.flows.inspect import run_replay, sink_option

    if not cal:
        raise InputError("compare needs at least one --cal calibration.json")
    res = run_replay(
        test,
        _cals(cal, effects_file),
        sink_option(rrd, None),
        speed="max",
        up=up,
        raw=raw,
        label=label,
        compare_mode=True,
        full_rate=rrd_full,
    )
    _print_result(res, f"{test.name}: final displacement after {res.duration_s:.1f} s", json_out)


@app.command(rich_help_panel="4. Inspect")
def view(
    recording: Annotated[Path, typer.Argument(help="A Rerun recording (.rrd).")],
    web: Annotated[
        bool, typer.Option("--web", help="Serve to the web viewer on 127.0.0.1 (prints the URL).")
    ] = False,
    screenshot: Annotated[
        Path | None,
        typer.Option("--screenshot", help="Save a PNG of the web viewer (headless Chromium) and exit."),
    ] = None,
    width: Annotated[int, typer.Option(help="Screenshot width (px).", min=200)] = 1400,
    height: Annotated[int, typer.Option(help="Screenshot height (px).", min=200)] = 900,
    wait_s: Annotated[float, typer.Option(help="Longest wait for the viewer to render (s).", min=1.0)] = 90.0,
    tab: Annotated[
        str | None, typer.Option("--tab", help="Show this blueprint tab (its name, e.g. '3 workbench').")
    ] = None,
) -> None:
    """Open an .rrd: native viewer (default), web viewer on 127.0.0.1 (--web), or a PNG (--screenshot).

    Examples: `accellog view demo.rrd --tab '3 workbench'`; `accellog view demo.rrd --web`; `accellog
    view demo.rrd --screenshot wb.png --tab '3 workbench'`.
    """
    import tempfile

    from accellog.present import viewer
    from accellog.present.rrd.tabs import tab_view_files

    if not recording.is_file():
        raise InputError("no such .rrd file", where=str(recording))
    if screenshot is None and not web:
        viewer.require_display()
    if screenshot is not None:
        stats = viewer.screenshot_rrd(recording, screenshot, size=(width, height), wait_s=wait_s, tab=tab)
        _console.print(f"{screenshot}: {stats.colors} colours, {100 * stats.non_background:.0f}% drawn")
        if not stats.looks_rendered():
            raise InputError(
                "the viewer did not render within the wait (blank screenshot)", where=str(screenshot)
            )
        return
    # the tab's blueprint (.rbl) and the recording without its own blueprints go to a temporary
    # folder that stays: the viewer (native) reads them after this process has returned
    extra = []
    if tab is not None:
        recording, rbl = tab_view_files(recording, tab, tempfile.mkdtemp(prefix="accellog-tab-"))
        extra.append(rbl)
    if web:
        with viewer.serve_rrd(recording, extra=extra) as v:
            # one line whatever the terminal's width: a URL cut by a line break cannot be clicked or copied
            print(f"web viewer: {v.url}  (Ctrl-C to stop)", flush=True)
            try:
                while v.proc.poll() is None:
                    time.sleep(0.5)
            except KeyboardInterrupt:
                pass
        return
    import subprocess

    cmd = [
        viewer.rerun_binary(),
        "--bind",
        "127.0.0.1",
        str(recording),
        *map(str, extra),
    ]  # its viewer server: local only
    subprocess.Popen(cmd, env=viewer.rerun_env(), start_new_session=True)
