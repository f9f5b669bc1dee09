"""Start-up of the command line (#9): the lazy group's table is what the command modules register,
its help is typer's help of the whole app byte for byte, a command loads only its own module."""

from __future__ import annotations

import importlib
import json
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer.main

from accellog import cli
from accellog.cli import app as cli_app
from accellog.cli import main

ROOT = Path(__file__).resolve().parents[2]

# typer's own build of the whole app: every command module imported first, so that typer builds every
# command itself (the lazy group then has nothing to load); errors through main()'s one-line handler.
TYPER_HELP = """
import importlib, sys, typer.main
from accellog.cli import _exit_code, app
for module in sorted(set(app.COMMANDS.values())):
    importlib.import_module(f"accellog.cli.{module}")
group = app.plain_flags(typer.main.get_command(app.app))
assert set(group.commands) == set(app.COMMANDS)
try:
    rc = group(args=sys.argv[1:], prog_name="accellog", standalone_mode=False)
except Exception as exc:
    rc = _exit_code(exc)
sys.exit(rc)
"""
CLI = "import sys; from accellog.cli import main; sys.exit(main(sys.argv[1:]))"
PANELS = ["Start here", "1. Record", "2. Calibrate", "3. Discover", "4. Inspect", "5. Move"]


def _python(code: str, args: list[str], **env: str) -> subprocess.CompletedProcess:
    full = {**os.environ, **env, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(
        [sys.executable, "-c", code, *args], env=full, capture_output=True, text=True, cwd=ROOT
    )


def test_table_is_what_the_command_modules_register():
    """COMMANDS names every command of every module of accellog.cli with its module, and lists the
    help's panels in the story's order (record, calibrate, discover, inspect, move)."""
    for mod in pkgutil.iter_modules(cli.__path__):
        importlib.import_module(f"accellog.cli.{mod.name}")
    app = cli_app.app
    got = {
        info.name or typer.main.get_command_name(info.callback.__name__): info.callback.__module__
        for info in app.registered_commands
    }
    got |= {
        g.name: g.typer_instance.registered_commands[0].callback.__module__ for g in app.registered_groups
    }
    assert got == {name: f"accellog.cli.{module}" for name, module in cli_app.COMMANDS.items()}
    panels = {
        info.name or typer.main.get_command_name(info.callback.__name__): info.rich_help_panel
        for info in [*app.registered_commands, *app.registered_groups]
    }
    assert list(dict.fromkeys(panels[name] for name in cli_app.COMMANDS)) == PANELS


def test_command_modules_do_not_postpone_annotations():
    """typer evaluates string annotations at each build (3.5x the CPU time of the help's builds)."""
    for module in set(cli_app.COMMANDS.values()):
        source = (ROOT / "accellog" / "cli" / f"{module}.py").read_text()
        assert "from __future__ import annotations" not in source, module


@pytest.mark.parametrize("args", [["--help"], []], ids=["--help", "no-args"])
@pytest.mark.parametrize("width,colour", [("80", ""), ("52", ""), ("131", "1")])
def test_top_help_is_typers_help(args, width, colour):
    """Same stdout (panels, wrapping, ANSI colours), stderr line and exit code as typer's build."""
    env = {"TERMINAL_WIDTH": width, "FORCE_COLOR": colour}
    lazy, ref = _python(CLI, args, **env), _python(TYPER_HELP, args, **env)
    assert (lazy.stdout, lazy.stderr, lazy.returncode) == (ref.stdout, ref.stderr, ref.returncode)
    assert all(p in lazy.stdout for p in PANELS) and ("\033[" in lazy.stdout) == bool(colour)
    assert lazy.returncode == (0 if args else 2)


def _loaded_after(args: list[str]) -> dict:
    code = (
        "import contextlib, io, json, sys\n"
        "from accellog.cli import main\n"
        f"with contextlib.redirect_stdout(io.StringIO()): rc = main({args!r})\n"
        "print(json.dumps({'rc': rc, 'modules': sorted(sys.modules)}))"
    )
    out = _python(code, [])
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_help_loads_no_library():
    """`accellog --help` imports the command modules (for their help) but none of the libraries the
    commands import when they run."""
    got = _loaded_after(["--help"])
    assert got["rc"] == 0
    heavy = {"numpy", "pydantic", "scipy", "rerun", "pyarrow", "mcap", "dask", "accellog.flows"}
    assert heavy & set(got["modules"]) == set()
    assert {f"accellog.cli.{m}" for m in cli_app.COMMANDS.values()} <= set(got["modules"])


def test_a_command_loads_only_its_module():
    got = _loaded_after(["effects", "--json"])
    loaded = {m for m in got["modules"] if m.startswith("accellog.cli.")}
    # early: part of accellog.cli itself (helper processes from the raw command line); option_checks
    # and path_checks: the door every command passes
    assert loaded == {
        "accellog.cli.app",
        "accellog.cli.early",
        "accellog.cli.option_checks",
        "accellog.cli.path_checks",
        "accellog.cli.workbench",
    }


def test_unknown_command_and_single_command_modules(capsys):
    """An unknown name still gets click's suggestion (full registration); a module with one command
    (magcal) still runs as a subcommand, not as the whole program."""
    assert main(["fitt"]) == 2
    err = capsys.readouterr().err
    assert err == "accellog: error: No such command 'fitt'. Did you mean 'fit'? (see accellog --help)\n"
    assert main(["magcal", "--help"]) == 0
    assert "Usage: accellog magcal [OPTIONS]" in capsys.readouterr().out
    assert main(["magcal"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("accellog: error: magcal: Missing argument") and err.count("accellog") == 2
