"""`accellog report`: the last stage - tables from the JSON artifacts the other stages write.

Reads calibration files (`fit -o`, `drift -o`), `evaluate --json`, `integrate --json` and
`workbench --json` outputs, and prints their tables (rich), or markdown with --markdown to paste
into a lab notebook or an issue.
"""

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from accellog.cli.app import app


@app.command(rich_help_panel="2. Calibrate")
def report(
    files: Annotated[
        list[Path], typer.Argument(help="JSON artifacts: calibrations, evaluate/integrate/workbench --json.")
    ],
    markdown: Annotated[bool, typer.Option("--markdown", help="Markdown tables on stdout.")] = False,
) -> None:
    """Print the tables of stage artifacts (parameters ± 1σ, the seed's tables, the model ladder).

    Example: `accellog evaluate static.mcap --cal cal.json --json > eval.json; accellog report
    cal.json eval.json`.
    """
    from accellog.calibrate.calfile.calibration import read_json
    from accellog.present.artifacts import tables_for
    from accellog.present.views import table_markdown

    tables = []
    for f in files:
        tables += tables_for(read_json(f), f.name)
    if markdown:
        typer.echo("\n".join(table_markdown(t) for t in tables))
        return
    con = Console(width=140)
    for t in tables:
        con.print(t)
