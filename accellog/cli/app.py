"""The typer application object shared by every command module in accellog.cli, the click group
it runs as, and the options several commands share.

The group follows click's lazy-loading pattern ("Lazily Loading Subcommands" in click's docs) on
typer's group class: it lists the commands from COMMANDS and imports a command's module, and builds
only that command, when the command is asked for. A command line loads only its command's module;
`accellog --help` and shell completion load every command module (the libraries are imported inside
the commands, when they run). The command modules do not postpone their annotations (no `from
__future__ import annotations`): typer would compile and eval every string annotation twice per command,
44 ms instead of 12 ms of CPU to build the 24 commands of the help."""

from __future__ import annotations

import functools
import importlib
from pathlib import Path
from typing import Annotated, Any

import typer
import typer.main
from typer.core import TyperArgument, TyperGroup

try:  # typer >= 0.29 carries its own click (typer._click); earlier ones use the click package
    from typer import _click
except ImportError:  # pragma: no cover - the installed typer decides
    import click as _click  # type: ignore[no-redef]

from accellog.cli.option_checks import guard_options

# command -> the module of accellog.cli that defines it, in the order of the help (typer draws the
# commands panel by panel, each panel where its first command is; tests/cli/test_cli_startup.py checks
# that the command modules register exactly these commands).
COMMANDS = {
    "demo": "demo",
    "record": "record",
    "simulate": "record",
    "import": "imports",
    "segment": "calibrate",
    "fit": "calibrate",
    "evaluate": "calibrate",
    "drift": "calibrate",
    "apply": "calibrate",
    "run": "calibrate",
    "integrate": "calibrate",
    "report": "report",
    "export": "interop",
    "magcal": "magcal",
    "noise": "noise",
    "fleet": "fleet",
    "effects": "workbench",
    "diagnose": "workbench",
    "workbench": "workbench",
    "replay": "inspect",
    "compare": "inspect",
    "view": "inspect",
    "doctor": "doctor",
    "track": "move",
}


class LazyGroup(TyperGroup):
    """typer's group whose commands are imported and built when asked for (click's lazy group)."""

    def list_commands(self, ctx: _click.Context) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: _click.Context, cmd_name: str) -> _click.Command | None:
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            importlib.import_module(f"accellog.cli.{COMMANDS[cmd_name]}")
            self.commands[cmd_name] = _build(cmd_name)
        return self.commands.get(cmd_name)

    def resolve_command(self, ctx: _click.Context, args: list[str]) -> Any:
        """typer offers a close name for an unknown one ("Did you mean 'fit'?") among the commands
        built: all of them, then."""
        if args and args[0] not in COMMANDS:
            for name in COMMANDS:
                self.get_command(ctx, name)
        return super().resolve_command(ctx, args)


app = typer.Typer(
    cls=LazyGroup,
    name="accellog",
    help="Record, calibrate and inspect MEMS accelerometers (MPU-9250): MCAP logs, error models "
    "with uncertainties, a model workbench and Rerun recordings.",
    no_args_is_help=True,
    rich_markup_mode="markdown",
    pretty_exceptions_enable=False,
    add_completion=True,
)


def _print_version(value: bool) -> None:
    if value:
        from accellog.core.version import __version__

        typer.echo(f"accellog {__version__}")
        raise typer.Exit()


@app.callback()
def _top(
    version: Annotated[
        bool,
        typer.Option("--version", callback=_print_version, is_eager=True, help="Print the version and exit."),
    ] = False,
) -> None:
    pass


CompressionOpt = Annotated[
    str,
    typer.Option(
        "--compression",
        help="MCAP chunk compression: zstd (smaller files, faster from disk), lz4 (faster from the page "
        "cache) or none.",
    ),
]

ForceOpt = Annotated[bool, typer.Option("--force", help="Replace an existing -o file.")]

EffectsOpt = Annotated[
    Path | None,
    typer.Option(
        "--effects-file",
        help="Python file of user effects, run with your rights: needed for a calibration whose model has "
        "user effects (its sha256 must match the one the calibration recorded; nothing named inside a "
        "calibration is ever run).",
    ),
]


def _usage_name(p: Any) -> str:
    """An argument on the usage line as click writes it: SESSION, [SESSION], FILES... (typer 0.29
    writes a required one as {session})."""
    name = p.metavar + ("..." if p.nargs != 1 else "")
    return name if p.required else f"[{name}]"


def plain_flags(cmd: Any) -> Any:
    """A click command (group: with the subcommands built) whose on/off flags show no '<bool>'
    placeholder in the help (typer's rich help prints the metavar; an empty one prints nothing) and
    whose arguments are named in capitals (SESSION; usage: SESSION, [SESSION], FILES...)."""
    help_opt = cmd.get_help_option(_click.Context(cmd))  # cached by click: the one --help will show
    for p in [*cmd.params, *([help_opt] if help_opt is not None else [])]:
        if getattr(p, "is_flag", False) and p.metavar is None:
            p.metavar = ""
        if isinstance(p, TyperArgument):
            p.metavar = p.metavar or (p.name or "arg").upper()
            # click has no setting for an argument's usage name: its method is replaced on the instance
            p._usage_display_name = functools.partial(_usage_name, p)  # type: ignore[method-assign]
    for sub in getattr(cmd, "commands", {}).values():
        plain_flags(sub)
    return cmd


def _build(name: str) -> _click.Command:
    """The click command `name` from what its module registered on `app`, as typer builds it for a
    whole app; its flags plain and its numeric options checked (accellog.cli.option_checks)."""
    short, markup = app.pretty_exceptions_short, app.rich_markup_mode
    for info in app.registered_commands:
        fn_name = info.callback.__name__ if info.callback is not None else ""
        if (info.name or typer.main.get_command_name(fn_name)) == name:
            built = typer.main.get_command_from_info(
                info, pretty_exceptions_short=short, rich_markup_mode=markup
            )
            return guard_options(plain_flags(built))
    for group in app.registered_groups:
        if group.name == name:
            built = typer.main.get_group_from_info(
                group,
                pretty_exceptions_short=short,
                suggest_commands=app.suggest_commands,
                rich_markup_mode=markup,
            )
            return guard_options(plain_flags(built))
    raise LookupError(f"accellog.cli.{COMMANDS[name]} registers no command {name!r}")


def command_group() -> _click.Command:
    """The click group that runs an `accellog` command line (with typer's --install-completion and
    --show-completion)."""
    return guard_options(plain_flags(typer.main.get_command(app)))
