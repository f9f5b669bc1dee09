"""`accellog --help` (and `accellog` alone) drawn from accellog.cli.commands_table with rich alone:
the same panels, styles and widths as typer's rich help (typer.rich_utils, rich markup mode), without
importing typer, rich.markdown or any command module, nor building a click command (#9).
tests/cli/test_cli_startup.py compares it with typer's own rendering, plain and in colour."""

from __future__ import annotations

import os

from rich.align import Align
from rich.columns import Columns
from rich.console import Console, Group
from rich.highlighter import RegexHighlighter
from rich.padding import Padding
from rich.panel import Panel
from rich.table import Table
from rich.text import Text
from rich.theme import Theme

from accellog.cli.commands_table import COMMANDS, HELP, OPTIONS, USAGE


class _Options(RegexHighlighter):
    highlights = [  # noqa: RUF012 (typer.rich_utils.OptionHighlighter)
        r"(^|\W)(?P<switch>\-\w+)(?![a-zA-Z0-9])",
        r"(^|\W)(?P<option>\-\-[\w\-]+)(?![a-zA-Z0-9])",
        r"(?P<types>\<[^\>]+\>)",
        r"(?P<usage>Usage: )",
    ]


class _Negative(RegexHighlighter):
    highlights = [  # noqa: RUF012 (typer.rich_utils.NegativeOptionHighlighter)
        r"(^|\W)(?P<negative_switch>\-\w+)(?![a-zA-Z0-9])",
        r"(^|\W)(?P<negative_option>\-\-[\w\-]+)(?![a-zA-Z0-9])",
    ]


class _Types(RegexHighlighter):
    highlights = [  # noqa: RUF012 (typer.rich_utils.TypesHighlighter)
        r"^(?P<types_sep>(\[|<))",
        r"(?P<types_sep>\|)",
        r"(?P<types_sep>(\]|>))(\.\.\.)?$",
    ]


_highlight, _negative, _types = _Options(), _Negative(), _Types()
_THEME = {
    "option": "bold cyan",
    "switch": "bold green",
    "negative_option": "bold magenta",
    "negative_switch": "bold red",
    "types": "bold yellow",
    "types_sep": "dim",
    "usage": "yellow",
}


def _console() -> Console:
    """typer's help console: the same theme and the same environment switches."""
    width = os.getenv("TERMINAL_WIDTH")
    force = (
        True if os.getenv("GITHUB_ACTIONS") or os.getenv("FORCE_COLOR") or os.getenv("PY_COLORS") else None
    )
    if os.getenv("_TYPER_FORCE_DISABLE_TERMINAL"):
        force = False
    return Console(
        theme=Theme(_THEME),
        highlighter=_highlight,
        color_system="auto",
        force_terminal=force,
        width=int(width) if width else None,
    )


def _text(markup: str, style: str = "") -> Text:
    text = Text.from_ansi(markup, style=style) if "\033[" in markup else Text.from_markup(markup, style=style)
    return _highlight(text)


def _table(**kw) -> Table:
    return Table(
        show_header=False,
        expand=True,
        box=None,
        show_lines=False,
        leading=0,
        pad_edge=False,
        padding=(0, 1),
        **kw,
    )


def _options_panel() -> Panel:
    table = _table(highlight=True)
    for long, short, sec_long, sec_short, type_str, help_text in OPTIONS:
        table.add_row(
            _highlight(long),
            _highlight(short),
            _negative(sec_long),
            _negative(sec_short),
            _types(Text(type_str, style="bold yellow", overflow="fold")),
            Columns([_text(help_text)] if help_text else []),
        )
    return Panel(table, border_style="dim", title="Options", title_align="left")


def _command_panels() -> list[Panel]:
    width = max((len(name) for name, *_ in COMMANDS), default=0)
    panels: dict[str, Table] = {}
    for name, _module, panel, help_text in COMMANDS:
        if panel not in panels:
            panels[panel] = _table(highlight=False)
            panels[panel].add_column(style="bold cyan", no_wrap=True, width=width)
            panels[panel].add_column("Description", justify="left", no_wrap=False, ratio=10)
        panels[panel].add_row(Text(name), _text(help_text))
    order = sorted(panels, key=lambda p: p != "Commands")  # typer draws the default panel first
    return [Panel(panels[p], border_style="dim", title=p, title_align="left") for p in order]


def print_help() -> None:
    """Print the top-level help on stdout, as typer would (`accellog --help` adds one blank line)."""
    console = _console()
    console.print(Padding(_highlight(USAGE), 1), style="bold")
    first, rest = HELP
    if first:
        parts = [_text(first)] + ([Text(""), _text(rest, style="dim")] if rest else [])
        console.print(Padding(Align(Group(*parts, fit=True), pad=False), (0, 1, 1, 1)))
    if OPTIONS:
        console.print(_options_panel())
    for panel in _command_panels():
        console.print(panel)
