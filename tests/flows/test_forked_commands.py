"""`diagnose` and `fit` read the session in a forked child while they import the solver
(core.forked): the same output, notes and one-line errors as in-process."""

from __future__ import annotations

import json
import os

import pytest

from accellog.calibrate.observe import segment
from accellog.cli import main
from accellog.core import forked
from accellog.flows import diagnose_run, stages
from accellog.flows.simulate import Scenario, simulate


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("forked")
    good, tilted = d / "six.mcap", d / "tilted.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=500.0), good)
    simulate(
        Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=500.0, fixture_tilt_deg=(60.0, 0.0)),
        tilted,
    )
    return good, tilted


def _readers(monkeypatch, tmp_path):
    """Record the pid of every process that streams a session (a file: the child's list is its own)."""
    log = tmp_path / "pids"
    for module, name in ((segment, "observe_riding"), (stages, "observe_riding")):
        real = getattr(module, name)

        def logged(*a, _real=real, **k):
            with open(log, "a") as f:
                f.write(f"{os.getpid()}\n")
            return _real(*a, **k)

        monkeypatch.setattr(module, name, logged)
    return log


def _imports_pending(monkeypatch):
    """As in a fresh command: scipy not imported yet, so the read is forked (other tests of this
    process imported it already: then nothing is forked, there is nothing to do meanwhile)."""
    monkeypatch.setattr(stages, "solver_loaded", lambda: False)
    monkeypatch.setattr(diagnose_run, "_diagnosis_loaded", lambda: False)


@pytest.mark.parametrize("command", ["diagnose", "fit"])
def test_the_same_output_read_by_a_child(sessions, command, monkeypatch, capsys, tmp_path):
    good, _ = sessions
    log = _readers(monkeypatch, tmp_path)
    _imports_pending(monkeypatch)
    out = {}
    for switch in ("1", "0"):
        monkeypatch.setenv(forked.ENV_SWITCH, switch)
        args = (
            [command, str(good), "--json"]
            if command == "diagnose"
            else [command, str(good), "-o", str(tmp_path / f"c{switch}.json")]
        )
        assert main(args) in (0, None)
        text = (
            capsys.readouterr().out if command == "diagnose" else (tmp_path / f"c{switch}.json").read_text()
        )
        out[switch] = {k: v for k, v in json.loads(text).items() if k != "created_utc"}
    assert out["1"] == out["0"]
    pids = [int(x) for x in log.read_text().split()]
    assert pids[0] != os.getpid() and pids[-1] == os.getpid()  # forked, then in-process


@pytest.mark.parametrize("command", ["diagnose", "fit"])
def test_an_error_in_the_child_is_the_same_one_line(sessions, command, monkeypatch, capsys, tmp_path):
    _, tilted = sessions
    _imports_pending(monkeypatch)
    lines = {}
    for switch in ("1", "0"):
        monkeypatch.setenv(forked.ENV_SWITCH, switch)
        args = [command, str(tilted)] + (["-o", str(tmp_path / "c.json")] if command == "fit" else [])
        assert main(args) == 2
        lines[switch] = capsys.readouterr().err
    assert lines["1"] == lines["0"]
    assert lines["1"].count("\n") == 1 and "measured gravity is 59 deg from the label" in lines["1"]
    assert not (tmp_path / "c.json").exists()
