"""A CLI that talks: --version, shell completion, one error prefix, progress bars only on a terminal."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
from pathlib import Path

import pytest

from accellog import __version__
from accellog.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _env(**extra: str) -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT), **extra}


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"accellog {__version__}\n"
    assert main(["fit", "--help"]) == 0  # the callback does not get in a command's way
    capsys.readouterr()


@pytest.mark.slow
def test_shell_completion_completes_commands_and_options():
    code = "import sys; from accellog.cli import main; sys.exit(main(sys.argv[1:]))"
    # the shell comes from the parent processes, or from $SHELL where they do not tell (CI, no terminal)
    got = subprocess.run([sys.executable, "-c", code, "--show-completion"], env=_env(SHELL="/bin/bash"),
                         capture_output=True, text=True)  # fmt: skip
    assert got.returncode == 0 and "_accellog_completion" in got.stdout
    words = {"COMP_WORDS": "accellog fi", "COMP_CWORD": "1", "_ACCELLOG_COMPLETE": "complete_bash"}
    got = subprocess.run([sys.executable, "-c", code], env=_env(**words), capture_output=True, text=True)
    assert "fit" in got.stdout.split()
    words = {"COMP_WORDS": "accellog export x --ro", "COMP_CWORD": "3", "_ACCELLOG_COMPLETE": "complete_bash"}
    got = subprocess.run([sys.executable, "-c", code], env=_env(**words), capture_output=True, text=True)
    assert "--rotation" in got.stdout.split()


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["fitt"], "accellog: error: No such command 'fitt'. Did you mean 'fit'? (see accellog --help)"),
        (["fit", "x.mcap"], "accellog: error: fit: Missing option '-o' / '--output'. (see accellog fit --help)"),
        (["import", "ros2"], "accellog: error: import ros2: Missing argument 'BAG'. (see accellog import ros2 --help)"),
    ],
)  # fmt: skip
def test_one_error_prefix(argv, line, capsys):
    assert main(argv) == 2
    assert capsys.readouterr().err == line + "\n"


def _in_pty(argv: list[str], cwd: Path) -> tuple[int, str]:
    """Run `accellog ARGV` with stdout and stderr on a pseudo-terminal; (exit code, what was shown)."""
    code = "import sys; from accellog.cli import main; sys.exit(main(sys.argv[1:]))"
    leader, follower = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-c", code, *argv], stdout=follower, stderr=follower, cwd=cwd,
                            env=_env(COLUMNS="120", TERM="xterm"))  # fmt: skip
    os.close(follower)
    chunks = []
    while True:
        try:
            data = os.read(leader, 65536)
        except OSError:
            break
        if not data:
            break
        chunks.append(data)
    os.close(leader)
    return proc.wait(), b"".join(chunks).decode(errors="replace")


@pytest.mark.slow
def test_progress_bar_on_a_terminal_only(tmp_path):
    """apply --ros2 draws a bar (done/total, time left) on a terminal; piped, nothing of it is printed."""
    from accellog.flows.simulate import Scenario, simulate

    simulate(
        Scenario(protocol="six", hold_s=4.0, move_s=1.0, sample_rate_hz=200.0, seed=3), tmp_path / "s.mcap"
    )
    assert main(["fit", str(tmp_path / "s.mcap"), "-o", str(tmp_path / "cal.json")]) == 0
    argv = ["apply", "s.mcap", "--cal", "cal.json", "-o", "c1.mcap", "--ros2", "r1.mcap"]
    rc, shown = _in_pty(argv, tmp_path)
    assert rc == 0, shown
    assert "ROS 2 bag" in shown and "left" in shown
    assert any(f"/{n}" in shown for n in range(4000, 7000))  # done/total (samples) drawn
    argv = [*argv[:4], "-o", "c2.mcap", "--ros2", "r2.mcap"]
    piped = subprocess.run([sys.executable, "-m", "accellog", *argv], cwd=tmp_path, env=_env(),
                           capture_output=True, text=True)  # fmt: skip
    assert piped.returncode == 0, piped.stderr
    assert "ROS 2 bag" not in piped.stdout + piped.stderr and "left" not in piped.stdout + piped.stderr


@pytest.mark.slow
def test_fleet_progress_knows_its_total_before_the_first_task(tmp_path):
    """fleet run's bar reads 0/N from the start, never 0/? (run_fleet reports the total first)."""
    from accellog.flows.fleet import run_fleet
    from accellog.flows.simulate import Scenario, simulate

    files = []
    for k in range(2):
        files.append(tmp_path / f"s{k}.mcap")
        simulate(Scenario(protocol="six", hold_s=2.0, move_s=0.5, sample_rate_hz=100.0, seed=k), files[-1])
    calls = []
    run_fleet(ROOT / "pipelines" / "fleet.toml", [str(f) for f in files], tmp_path / "out", workers=0,
              on_progress=lambda done, total, r: calls.append((done, total)))  # fmt: skip
    assert calls == [(0, 2), (1, 2), (2, 2)]


def test_spawn_without_a_display_says_so_at_once(monkeypatch):
    """`--rerun spawn` on a headless Linux host: one line at once, not a 20 s wait or the viewer's log."""
    import socket
    import time

    from accellog.core.errors import InputError
    from accellog.present.rrd.sinks import spawn_viewer

    if not sys.platform.startswith("linux"):
        pytest.skip("the display check is for Linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # free once closed: nothing listens there
    t0 = time.monotonic()
    with pytest.raises(InputError, match="no display"):
        spawn_viewer(port)
    assert time.monotonic() - t0 < 2.0


def test_record_spawn_without_a_display_records_and_says_it_once(monkeypatch, tmp_path, capsys):
    """The live view that cannot start is reported once and then not fed (no dropped-calls line)."""
    if not sys.platform.startswith("linux"):
        pytest.skip("the display check is for Linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "r.mcap"
    argv = ["record", "--sim", "--fast", "--protocol", "+z", "--hold", "2", "--rate", "200", "-o", str(out)]
    assert main([*argv, "--rerun", "spawn"]) == 0
    err = capsys.readouterr().err
    assert err.count("no display") == 1 and "dropped" not in err and "\x1b[" not in err
    assert out.exists()


def test_step_bar_opens_on_first_update_and_closes_when_done(capsys):
    from accellog.cli.progress import StepBar

    bar = StepBar("simulate sessions", show=True)
    assert bar._ctx is None
    bar(0, 3)
    assert bar._ctx is not None
    bar(3, 3)
    assert bar._ctx is None  # gone before the flow prints its next lines
    capsys.readouterr()
    quiet = StepBar("x", show=False)
    quiet(1, 2)
    quiet.close()
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize(
    "cmd",
    [["fit"], ["apply"], ["export"], ["simulate"], ["record"], ["diagnose"], ["evaluate"], ["workbench"],
     ["import", "ros2"]],
    ids=lambda c: " ".join(c),
)  # fmt: skip
def test_main_commands_show_examples(cmd, capsys):
    assert main([*cmd, "--help"]) == 0
    out = capsys.readouterr().out
    assert "Example" in out and f"accellog {cmd[0]}" in out


def test_flags_show_no_bool_placeholder(capsys):
    for argv in (["--help"], ["fit", "--help"], ["import", "ros2", "--help"]):
        assert main(argv) == 0
        assert "<bool>" not in capsys.readouterr().out, argv


def test_fleet_workers_pin_blas_wherever_they_were_started():
    """A process started without accellog's one-thread environment (an external `dask worker`) runs
    its tasks with BLAS on one thread after pin_blas (called by warm_worker and by every task)."""
    code = (
        "import json, numpy\n"
        "from threadpoolctl import threadpool_info\n"
        "from accellog.flows.fleet import pin_blas\n"
        "before = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']\n"
        "pin_blas()\n"
        "after = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']\n"
        "print(json.dumps([before, after]))\n"
    )
    env = {
        k: v
        for k, v in _env().items()
        if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
    }
    env["OPENBLAS_NUM_THREADS"] = "2"
    got = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert got.returncode == 0, got.stderr
    import json

    before, after = json.loads(got.stdout)
    assert before and max(before) == 2 and set(after) == {1}


@pytest.mark.slow
def test_fleet_run_ends_without_worker_tracebacks(tmp_path):
    from accellog.flows.simulate import Scenario, simulate

    for k in range(3):
        simulate(Scenario(protocol="six", hold_s=2.0, move_s=0.5, sample_rate_hz=100.0, seed=k),
                 tmp_path / f"s{k}.mcap")  # fmt: skip
    argv = ["fleet", "run", str(ROOT / "pipelines" / "fleet.toml"), str(tmp_path / "*.mcap"), "-o",
            str(tmp_path / "out"), "--workers", "3"]  # fmt: skip
    got = subprocess.run(
        [sys.executable, "-m", "accellog", *argv], env=_env(), capture_output=True, text=True
    )
    assert got.returncode == 0, got.stderr
    assert "Traceback" not in got.stderr and "heartbeat" not in got.stderr, got.stderr[-2000:]


def test_busy_spinner_after_silence_and_gone_before_output(capsys):
    import time

    from accellog.cli.busy import Busy

    real_out = sys.stdout
    with Busy("accellog fit", delay_s=0.1) as busy:
        time.sleep(0.3)
        assert busy._status is not None  # silent for 0.1 s: the spinner is up
        print("table")  # the command prints: the spinner goes first, the wait starts again
        assert busy._status is None and busy._timer is not None
    assert sys.stdout is real_out and busy._status is None and busy._timer is None
    assert "table" in capsys.readouterr().out


def test_busy_spinner_keeps_stdout_on_stdout(capsys, monkeypatch):
    """On a terminal the spinner draws on stderr and the command's stdout stays stdout: rich's
    Console.status would redirect it into the console (stderr) while the spinner is up."""
    import time

    from accellog.cli.busy import Busy

    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # rich treats the captured stderr as a terminal
    with Busy("accellog fit", delay_s=0.05) as busy:
        time.sleep(0.3)
        assert busy._status is not None
        print("table")
        time.sleep(0.2)  # the spinner is back after 0.05 s of silence
        print("row")
    out, err = capsys.readouterr()
    assert out == "table\nrow\n" and "table" not in err and "accellog fit: working" in err


@pytest.mark.parametrize(
    ("argv", "busy"),
    [(["fit", "x.mcap", "-o", "c.json"], True), (["fit", "x.mcap", "--json"], False), (["record"], False),
     (["--version"], False), (["view", "x.rrd"], False), (["fit", "--help"], False)],
)  # fmt: skip
def test_busy_only_for_computing_commands_on_a_terminal(argv, busy, monkeypatch):
    from accellog.cli import _busy
    from accellog.cli.busy import Busy

    monkeypatch.setattr(sys.stdout, "isatty", lambda: True, raising=False)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    assert isinstance(_busy(argv), Busy) == busy
