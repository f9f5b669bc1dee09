"""Helper processes started from the raw command line (accellog.cli.early): which command lines start
which helper, before typer is imported; the helpers themselves are tested with real processes in
tests/flows/test_replay_offload.py and tests/flows/test_fleet_workers.py."""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import typer.main

from accellog.cli import app as cli_app
from accellog.cli import early
from accellog.flows import fleet_dask
from accellog.present.rrd import offload_process

ROOT = Path(__file__).resolve().parents[2]


def test_option_values_as_click_reads_them():
    args = ["fleet", "run", "p.toml", "s/*.mcap", "-o", "A", "--workers=3", "--out", "B", "--rrd"]
    assert early.option(args, "-o", "--out") == "B"  # the last one counts
    assert early.option(args, "--workers") == "3"
    assert early.option(args, "--rrd") is None  # no value: click's usage error follows
    assert early.option(args, "--scheduler") is None


@pytest.fixture
def started(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Which helper start_helpers asked for (the decision only; the starts are tested elsewhere)."""
    calls: list[str] = []
    monkeypatch.setattr(offload_process, "prestart", lambda: calls.append("rrd") or True)
    monkeypatch.setattr(fleet_dask, "prestart_workers", lambda: calls.append("fleet") or True)
    return calls


@pytest.mark.parametrize(
    ("args", "want"),
    [
        (["replay", "s.mcap", "--rrd", "o.rrd"], ["rrd"]),
        (["fit", "s.mcap", "-o", "c.json", "--rrd=o.rrd"], ["rrd"]),
        (["replay", "s.mcap"], []),
        (["replay", "s.mcap", "--rrd", "o.rrd", "--help"], []),
        (["diagnose", "s.mcap", "--rrd", "o.rrd"], []),  # writes its recording itself
        (["fleet", "run", "p.toml", "s/*.mcap", "-o", "NEW"], ["fleet"]),
        (["fleet", "run", "p.toml", "s/*.mcap", "-o", "NEW", "--workers", "0"], []),
        (["fleet", "run", "p.toml", "s/*.mcap", "-o", "NEW", "--scheduler", "tcp://h:8786"], []),
        (["fleet", "report", "NEW"], []),
        ([], []),
    ],
)
def test_which_command_lines_start_which_helper(args, want, started, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    early.start_helpers(args)
    assert started == want


def test_a_fleet_with_an_up_to_date_table_starts_no_workers_unless_forced(started, tmp_path):
    from accellog.flows.fleet_table import TABLE_NAME

    (tmp_path / TABLE_NAME).write_bytes(b"")
    base = ["fleet", "run", "p.toml", "s/*.mcap", "-o", str(tmp_path)]
    early.start_helpers(base)
    assert started == []
    early.start_helpers([*base, "--force"])
    assert started == ["fleet"]


def test_the_rrd_commands_are_commands_with_an_rrd_option():
    for name in early.RRD_CHILD_COMMANDS:  # typer builds the commands of the modules imported
        importlib.import_module(f"accellog.cli.{cli_app.COMMANDS[name]}")
    group = typer.main.get_command(cli_app.app)
    for name in early.RRD_CHILD_COMMANDS:
        opts = {o for p in group.commands[name].params for o in p.opts}
        assert "--rrd" in opts, name


def test_fleet_workers_fork_server_starts_before_typer_is_imported(tmp_path: Path):
    probe = (
        "import sys\n"
        "from accellog.flows import fleet_dask as fd\n"
        "start, seen = fd.prestart_workers, []\n"
        "fd.prestart_workers = lambda: seen.append('typer' in sys.modules) or start()\n"
        "from accellog.cli import main\n"
        "rc = main(sys.argv[1:])\n"
        "print(rc, seen)\n"
    )
    args = ["fleet", "run", str(tmp_path / "missing.toml"), f"{tmp_path}/*.mcap", "-o", str(tmp_path / "f")]
    res = subprocess.run(
        [sys.executable, "-c", probe, *args],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.stdout.split("\n")[0] == "2 [False]", (res.stdout, res.stderr)
    assert res.stderr.count("\n") == 1 and "missing.toml" in res.stderr
