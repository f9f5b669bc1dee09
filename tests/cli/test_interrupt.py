"""Ctrl-C (SIGINT) stops a command with one line, 'accellog: interrupted', and exit code 130; typer
>= 0.29 turns the KeyboardInterrupt into a silent Exit(130), which main() names."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from support.sessions import synth_session

from accellog.cli import main
from accellog.store.writer import write_session


def test_ctrl_c_is_one_line_and_exit_130(tmp_path):
    s = write_session(tmp_path / "s.mcap", synth_session(seed=3, hold_s=5.0, rate_hz=100.0))
    cal = tmp_path / "cal.json"
    assert main(["fit", str(s), "-o", str(cal)]) == 0
    # replay paced at real time: the session lasts ~40 s, the signal comes once it is running
    p = subprocess.Popen(
        [sys.executable, "-m", "accellog", "replay", str(s), "--cal", str(cal), "--speed", "1", "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "RERUN_ANALYTICS": "0"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a background job ignores it
    )
    time.sleep(4.0)
    p.send_signal(signal.SIGINT)
    _out, err = p.communicate(timeout=60)
    assert p.returncode == 130
    assert err.decode().strip().splitlines() == ["accellog: interrupted"]
