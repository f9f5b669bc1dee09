"""The viewer's failures are one line: no display for the native viewer, a DevTools connection that
chromium closed (e.g. a keepalive timeout on a loaded machine) — never a traceback, never a silent 0."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.present import viewer
from accellog.present.rrd.recording import RunRecording


def test_view_without_a_display_says_so_in_one_line(tmp_path: Path, monkeypatch, capsys) -> None:
    rrd = tmp_path / "tiny.rrd"
    with RunRecording(f"save:{rrd}") as rec:
        rec.log_samples("raw", np.arange(10.0), None, np.zeros((10, 3)), "g")
    monkeypatch.setattr("sys.platform", "linux")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(rrd)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("accellog: error: no display") and "--web" in err and "\n" not in err
    monkeypatch.setenv("DISPLAY", ":0")
    viewer.require_display()  # a display: nothing to say


class _ClosedSocket:
    """A DevTools socket that chromium has closed (what websockets raises after a ping timeout)."""

    def send(self, _text: str) -> None:
        pass

    def recv(self, timeout: float):
        from websockets.exceptions import ConnectionClosedError
        from websockets.frames import Close

        raise ConnectionClosedError(Close(1011, "keepalive ping timeout"), None)


def test_a_closed_devtools_connection_is_one_input_error_line() -> None:
    pytest.importorskip("websockets")
    ch = object.__new__(viewer.Chromium)  # no browser: only the socket matters here
    ch._ws, ch._id, ch._events, ch.timeout_s = _ClosedSocket(), 0, set(), 1.0
    with pytest.raises(InputError) as err:
        ch.call("Page.captureScreenshot")
    text = str(err.value)
    assert "closed the DevTools connection" in text and "Page.captureScreenshot" in text and "\n" not in text
    with pytest.raises(InputError, match="closed the DevTools connection"):
        ch.navigate("about:blank", load_timeout_s=0.5)


def test_view_web_prints_the_url_on_one_line_in_a_narrow_terminal(tmp_path: Path) -> None:
    import os
    import signal
    import subprocess
    import sys

    rrd = tmp_path / "tiny.rrd"
    with RunRecording(f"save:{rrd}") as rec:
        rec.log_samples("raw", np.arange(10.0), None, np.zeros((10, 3)), "g")
    env = dict(os.environ, COLUMNS="40", RERUN_ANALYTICS="0")
    code = "import sys; from accellog.cli import main; sys.exit(main())"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "view", "--web", str(rrd)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    try:
        line = proc.stdout.readline() if proc.stdout else ""
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
        if proc.stdout:
            proc.stdout.close()
        if proc.stderr:
            proc.stderr.close()
    assert line.startswith("web viewer: http://127.0.0.1:") and line.rstrip().endswith("(Ctrl-C to stop)"), (
        line
    )
    assert "proxy" in line


def test_a_failed_screenshot_says_whether_the_page_stayed_blank_or_kept_changing() -> None:
    blank = [(t, viewer.PixelStats(colors=200, non_background=0.02, std=1.0)) for t in (10.0, 30.0, 50.0)]
    said = viewer._why_not_drawn(blank)
    assert (
        said.startswith("it stayed blank, 200 colours and 2% drawn, over its last 40 s")
        and "--wait-s" not in said
    )
    drawing = [
        (t, viewer.PixelStats(colors=c, non_background=0.3, std=9.0))
        for t, c in ((1.0, 300), (2.0, 900), (3.0, 1500))
    ]
    assert "still changing" in viewer._why_not_drawn(drawing) and "--wait-s" in viewer._why_not_drawn(drawing)
    assert "still changing" in viewer._why_not_drawn(blank[:2])  # too few captures to tell
