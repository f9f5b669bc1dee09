"""Start-up of the command line (#9): the command table agrees with full registration, the fast
top-level help is typer's help byte for byte, a command loads only its own module."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from accellog.cli import commands_table, main, registry

ROOT = Path(__file__).resolve().parents[2]

# typer's own rendering of the fully registered app, errors through main()'s one-line handler.
TYPER_HELP = """
import sys, typer.main
from accellog.cli import registry, _exit_code
group = registry.plain_flags(typer.main.get_command(registry.register_all()))
try:
    rc = group(args=sys.argv[1:], prog_name="accellog", standalone_mode=False)
except Exception as exc:
    rc = _exit_code(exc)
sys.exit(rc)
"""
FAST_HELP = "import sys; from accellog.cli import main; sys.exit(main(sys.argv[1:]))"


def _python(code: str, args: list[str], **env: str) -> subprocess.CompletedProcess:
    full = {**os.environ, **env, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run(
        [sys.executable, "-c", code, *args], env=full, capture_output=True, text=True, cwd=ROOT
    )


def test_table_is_full_registration_even_after_one_command_ran(capsys):
    """commands_table (regenerate: `python -m accellog.cli.registry`) == what full registration
    gives, also when one module was imported first for its command (main() twice in a process)."""
    assert main(["effects", "--json"]) == 0
    capsys.readouterr()
    got = registry.extract()
    assert got["COMMANDS"] == commands_table.COMMANDS, "run `python -m accellog.cli.registry`"
    assert got["OPTIONS"] == commands_table.OPTIONS
    assert got["HELP"] == commands_table.HELP
    assert got["USAGE"] == commands_table.USAGE
    assert {m for _n, m, _p, _h in commands_table.COMMANDS} == set(registry.command_modules())


@pytest.mark.parametrize("args", [["--help"], []], ids=["--help", "no-args"])
@pytest.mark.parametrize("width,colour", [("80", ""), ("52", ""), ("131", "1")])
def test_top_help_is_typers_help(args, width, colour):
    """Same stdout (panels, wrapping, ANSI colours), stderr line and exit code as typer's rendering."""
    env = {"TERMINAL_WIDTH": width, "FORCE_COLOR": colour}
    fast, ref = _python(FAST_HELP, args, **env), _python(TYPER_HELP, args, **env)
    assert (fast.stdout, fast.stderr, fast.returncode) == (ref.stdout, ref.stderr, ref.returncode)
    assert "3. Discover" in fast.stdout and ("\033[" in fast.stdout) == bool(colour)
    assert fast.returncode == (0 if args else 2)


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


def test_help_loads_neither_typer_nor_a_command_module():
    got = _loaded_after(["--help"])
    assert got["rc"] == 0
    heavy = {"typer", "rich.markdown", "numpy", "pydantic"}
    commands = {f"accellog.cli.{m}" for m in registry.command_modules()}
    assert (heavy | commands) & set(got["modules"]) == set()


def test_a_command_loads_only_its_module():
    got = _loaded_after(["effects", "--json"])
    cli = {m for m in got["modules"] if m.startswith("accellog.cli.")}
    assert cli == {
        "accellog.cli.app",
        "accellog.cli.commands_table",
        "accellog.cli.option_checks",
        "accellog.cli.registry",
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
