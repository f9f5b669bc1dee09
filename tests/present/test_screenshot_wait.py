"""view --screenshot on a page that never draws: the wait is honoured end to end (a capture that
is slow to answer gets the time left, not a fixed timeout) and nothing is written on failure.

Needs the `chromium` apt package (skipped without it unless ACCELLOG_REQUIRE_BROWSER=1)."""

from __future__ import annotations

import os
import time
from pathlib import Path

import pytest

from accellog.core.errors import InputError
from accellog.present.viewer import Chromium, DevToolsTimeout, find_chromium, screenshot_url

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def chromium() -> str:
    exe = find_chromium()
    if exe is None:
        if os.environ.get("ACCELLOG_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium is required (ACCELLOG_REQUIRE_BROWSER=1): apt-get install chromium")
        pytest.skip("chromium not installed")
    pytest.importorskip("websockets")
    return exe


def test_blank_page_times_out_within_the_wait_and_writes_nothing(chromium: str, tmp_path: Path) -> None:
    png = tmp_path / "shot.png"
    t0 = time.monotonic()
    with pytest.raises(InputError, match=r"did not draw a stable picture within 5 s; nothing written") as err:
        screenshot_url("about:blank", png, size=(400, 300), wait_s=5.0, min_wait_s=1.0)
    # said as what it is: a page that stays blank, not one a longer wait would finish
    assert "it stayed blank" in str(err.value) and "draws nothing" in str(err.value), err.value
    elapsed = time.monotonic() - t0
    assert not png.exists() and list(tmp_path.iterdir()) == []  # no PNG, no temporary left
    assert 4.0 < elapsed < 5.0 + 10.0  # the wait, plus closing the browser


def test_a_command_waits_for_its_own_timeout(chromium: str) -> None:
    """A page busy for 3 s answers an evaluation late: a 1 s call gives up (DevToolsTimeout), a call
    given the time it needs gets the answer (the browser's default timeout does not cut it short)."""
    with Chromium(size=(400, 300), timeout_s=1.0) as ch:
        busy = "(() => { const e = Date.now() + 3000; while (Date.now() < e) {} return 7; })()"
        t0 = time.monotonic()
        with pytest.raises(DevToolsTimeout):
            ch.call("Runtime.evaluate", timeout_s=1.0, expression=busy, returnByValue=True)
        assert time.monotonic() - t0 < 2.5
        res = ch.call("Runtime.evaluate", timeout_s=20.0, expression=busy, returnByValue=True)
        assert res["result"]["value"] == 7
