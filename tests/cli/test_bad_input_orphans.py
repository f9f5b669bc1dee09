"""Child processes (issue 12, item 6): `view --web` (rerun server) and headless Chromium run in their
own process group and are ended when accellog is stopped by SIGTERM, SIGHUP or `timeout`: after
the parent exits, no process of the child's group survives.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from accellog.present.viewer import find_chromium

ENV = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2]), "RERUN_ANALYTICS": "0"}


def _children(pid: int) -> list[int]:
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(d.name))
    return out


def _group_alive(pgid: int) -> list[int]:
    alive = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pgid and fields[0] != "Z":
                alive.append(int(d.name))
    return alive


def _wait_line(proc: subprocess.Popen, needle: str, timeout_s: float) -> str:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if needle in line:
            return line
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"{needle!r} not printed (exit {proc.poll()}): {proc.stderr.read()}")


def _stop_and_check(proc: subprocess.Popen, how: str, pgids: list[int]) -> None:
    if how != "timeout":
        proc.send_signal(getattr(signal, how))
    proc.wait(60)
    end = time.monotonic() + 15
    while time.monotonic() < end and any(_group_alive(g) for g in pgids):
        time.sleep(0.2)
    left = {g: _group_alive(g) for g in pgids}
    for g in pgids:  # clean up before failing, so a failure leaves no orphan either
        if left[g]:
            os.killpg(g, signal.SIGKILL)
    assert not any(left.values()), f"orphans after {how}: {left}"


@pytest.fixture(scope="module")
def small_rrd(tmp_path_factory) -> Path:
    from accellog.present.rrd.recording import RunRecording

    p = tmp_path_factory.mktemp("rrd") / "small.rrd"
    with RunRecording(f"save:{p}") as rec:
        rec.log_document("results/note", "orphan test")
    return p


@pytest.mark.slow
@pytest.mark.parametrize("how", ["SIGTERM", "SIGHUP", "timeout"])
def test_view_web_leaves_no_orphan(small_rrd, how):
    code = "import sys; from accellog.cli import main; sys.exit(main())"
    cmd = [sys.executable, "-c", code, "view", "--web", str(small_rrd)]
    if how == "timeout":
        cmd = ["timeout", "-s", "TERM", "12", *cmd]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=tempfile.gettempdir()
    )
    try:
        _wait_line(proc, "web viewer:", 25 if how != "timeout" else 10)
        py = proc.pid if how != "timeout" else _children(proc.pid)[0]
        end = time.monotonic() + 10  # /proc may lag on a loaded machine
        while not (kids := _children(py)) and time.monotonic() < end:
            time.sleep(0.2)
        assert kids, "the rerun server was not started as a child"
        _stop_and_check(proc, how, kids)
    finally:
        if proc.poll() is None:
            proc.kill()
        _kill_serving(small_rrd)  # a failed check must not leave its server running
        proc.stdout.close()
        proc.stderr.close()


def _kill_serving(rrd: Path) -> None:
    """SIGKILL every process whose command line names rrd (the test's rerun servers)."""
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                cmdline = (d / "cmdline").read_bytes()
            except OSError:
                continue
            if str(rrd).encode() in cmdline and int(d.name) != os.getpid():
                with contextlib.suppress(ProcessLookupError):
                    os.kill(int(d.name), signal.SIGKILL)


@pytest.mark.parametrize("how", ["SIGTERM", "SIGHUP"])
def test_chromium_leaves_no_orphan(how):
    if find_chromium() is None:
        if os.environ.get("ACCELLOG_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium is required (ACCELLOG_REQUIRE_BROWSER=1)")
        pytest.skip("chromium not installed")
    pytest.importorskip("websockets")
    code = (
        "import time; from accellog.present.viewer import Chromium\n"
        "c = Chromium(size=(400, 300))\nprint('chromium', c.proc.pid, c._profile, flush=True)\n"
        "time.sleep(120)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
        cwd=tempfile.gettempdir(),
    )
    try:
        _, pid, profile = _wait_line(proc, "chromium", 60).split()
        pid = int(pid)
        assert len(_group_alive(pid)) >= 2  # the browser and its helpers share its group
        assert Path(profile).is_dir()
        _stop_and_check(proc, how, [pid])
        assert not Path(profile).exists(), f"the browser profile was left after {how}"
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stdout.close()
        proc.stderr.close()
