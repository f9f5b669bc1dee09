"""Which module defines each `accellog` command, so that a command line imports only that module and
builds only that command, and the top-level help needs neither typer nor any command module (#9).

Full registration (every command module of this package imported, in the help's order) stays the
reference: accellog.cli.commands_table is generated from it (`python -m accellog.cli.registry`
rewrites the table) and tests/cli/test_cli_startup.py checks that the two agree, so they cannot drift.
"""

from __future__ import annotations

import copy
import importlib
import inspect
from pathlib import Path

from accellog.cli.commands_table import COMMANDS

# Command modules are imported in this order for full registration: the help lists the panels in
# this order (the story: record, calibrate, discover, inspect, move), then any others by name.
ORDER = ["demo", "record", "imports", "calibrate", "report", "workbench", "inspect", "move"]
NOT_COMMAND_MODULES = {"app", "busy", "commands_table", "option_checks", "progress", "registry", "tophelp"}
MODULE_OF = {name: module for name, module, _panel, _help in COMMANDS}


def _rank(module: str) -> tuple[int, str]:
    name = module.rpartition(".")[2]
    return (ORDER.index(name) if name in ORDER else len(ORDER), name)


def command_modules() -> list[str]:
    """Short names of the modules that register commands, in full-registration order."""
    import pkgutil

    here = [m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)])]
    return sorted((n for n in here if n not in NOT_COMMAND_MODULES), key=_rank)


def _group_module(group_info) -> str:
    """Module of a sub-app added with app.add_typer: the one defining its commands."""
    sub = group_info.typer_instance
    callbacks = [c.callback for c in sub.registered_commands]
    if sub.registered_callback is not None:
        callbacks.append(sub.registered_callback.callback)
    return callbacks[0].__module__


def register_all():
    """Import every command module and return the app, its commands in full-registration order even
    when a module was imported earlier for one command (main() called twice in one process)."""
    for name in command_modules():
        importlib.import_module(f"accellog.cli.{name}")
    from accellog.cli.app import app

    app.registered_commands.sort(key=lambda c: _rank(c.callback.__module__))
    app.registered_groups.sort(key=lambda g: _rank(_group_module(g)))
    return app


def plain_flags(cmd):
    """A click command (group: with its subcommands) whose on/off flags show no '<bool>' placeholder
    in the help (typer's rich help prints the metavar; an empty one prints nothing)."""
    from typer import _click

    help_opt = cmd.get_help_option(_click.Context(cmd))  # cached by click: the one --help will show
    for p in [*cmd.params, *([help_opt] if help_opt is not None else [])]:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""
    for sub in getattr(cmd, "commands", {}).values():
        plain_flags(sub)
    return cmd


def command_group(name: str | None):
    """The click group that runs `accellog NAME ...`: for a command in the table, only its module is
    imported and only it is built; for anything else (no name, an option, an unknown name) every
    command, so that click's messages ("No such command 'fitt'. Did you mean 'fit'?") are unchanged."""
    import typer.main

    from accellog.cli.option_checks import guard_options

    module = MODULE_OF.get(name or "")
    if module is not None:
        importlib.import_module(f"accellog.cli.{module}")
        from accellog.cli.app import app

        one = copy.copy(app)  # same settings; the shared app's lists are left whole
        one.registered_commands = [
            c
            for c in app.registered_commands
            if (c.name or typer.main.get_command_name(c.callback.__name__)) == name
        ]
        one.registered_groups = [g for g in app.registered_groups if g.name == name]
        if one.registered_commands or one.registered_groups:
            return guard_options(plain_flags(typer.main.get_group(one)))
    return guard_options(plain_flags(typer.main.get_command(register_all())))  # + --install/--show-completion


def _paragraphs(text: str) -> tuple[str, str]:
    """typer's rich help text of a group: the first paragraph on one line, the others as they are."""
    first, *rest = inspect.cleandoc(text).partition("\f")[0].split("\n\n")
    if not first.startswith("\b"):
        first = first.replace("\n", " ")
    return inspect.cleandoc(first.strip()), inspect.cleandoc("\n\n".join(rest))


def _command_help(text: str) -> str:
    """typer's rich-markup cell for a command in a group's help: the first paragraph, line breaks kept."""
    first = inspect.cleandoc(text).split("\n\n")[0]
    if first.startswith("\b"):
        first = first.replace("\b\n", "")
    return inspect.cleandoc(first.strip())


def _option_row(param, ctx) -> tuple:
    long = [o for o in param.opts if "--" in o]
    short = [o for o in param.opts if "--" not in o]
    sec_long = [o for o in param.secondary_opts if "--" in o]
    sec_short = [o for o in param.secondary_opts if "--" not in o]
    type_str = (param.display_type_rich(ctx=ctx) or "") + (
        f" [{r}]" if (r := param._get_number_range_help_str()) else ""
    )
    paragraphs = (param.help or "").split("\n\n")
    lines = [
        p.replace("\n", " ").strip() if not p.startswith("\b") else p.strip("\b\n") + "\n" for p in paragraphs
    ]
    help_text = inspect.cleandoc("\n".join(lines).strip())
    return (",".join(long), ",".join(short), ",".join(sec_long), ",".join(sec_short), type_str, help_text)


def extract() -> dict:
    """The top-level help's content and each command's module, from full registration."""
    import typer.main
    from typer import _click

    app = register_all()
    group = plain_flags(typer.main.get_command(app))  # with typer's --install-completion / --show-completion
    ctx = _click.Context(group, info_name="accellog")
    commands = []
    for name in group.list_commands(ctx):
        cmd = group.get_command(ctx, name)
        if cmd is None or cmd.hidden:
            continue
        if cmd.deprecated:
            raise NotImplementedError(f"{name}: the fast top-level help does not draw deprecated commands")
        sub = [g for g in app.registered_groups if g.name == name]
        module = _group_module(sub[0]) if sub else cmd.callback.__module__
        panel = getattr(cmd, "rich_help_panel", None) or "Commands"
        commands.append(
            (name, module.rpartition(".")[2], panel, _command_help(cmd.short_help or cmd.help or ""))
        )
    options = [_option_row(p, ctx) for p in group.get_params(ctx) if not getattr(p, "hidden", False)]
    return {
        "USAGE": group.get_usage(ctx),
        "HELP": _paragraphs(group.help or ""),
        "OPTIONS": tuple(options),
        "COMMANDS": tuple(commands),
    }


def write_table() -> None:
    """Rewrite accellog/cli/commands_table.py from full registration (then ruff-formatted)."""
    import subprocess
    import sys

    path = Path(__file__).with_name("commands_table.py")
    data = extract()
    lines = [
        '"""Generated by `python -m accellog.cli.registry` from full registration of the command modules:',
        "do not edit (tests/cli/test_cli_startup.py fails when it no longer matches). The top-level help is",
        "drawn from it (accellog.cli.tophelp) and a command line imports only MODULE (accellog.cli.MODULE).",
        '"""',
        "",
        f"USAGE = {data['USAGE']!r}",
        "# group help: first paragraph (one line), the other paragraphs",
        f"HELP = {data['HELP']!r}",
        "# long, short, secondary long, secondary short, type, help",
        f"OPTIONS = {data['OPTIONS']!r}",
        "# name, MODULE, help panel, help (first paragraph, rich markup)",
        "COMMANDS = (",
        *(f"    {row!r}," for row in data["COMMANDS"]),
        ")",
        "",
    ]
    path.write_text("\n".join(lines))
    subprocess.run([sys.executable, "-m", "ruff", "format", "-q", str(path)], check=False)


if __name__ == "__main__":  # pragma: no cover
    write_table()
