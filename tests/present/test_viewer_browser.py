"""The web viewer in a real headless Chromium: the demo's .rrd renders (not blank, not an error page).

Needs the `chromium` apt package and the `websockets` pip package; skipped without Chromium unless
ACCELLOG_REQUIRE_BROWSER=1 (CI), where a missing browser fails the test.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.present.rrd.recording import RunRecording
from accellog.present.viewer import Chromium, find_chromium, pixel_stats, screenshot_rrd, serve_rrd

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SERIES_COLORS = {"x": (230, 80, 80), "y": (80, 190, 80), "z": (80, 130, 240)}


@pytest.fixture(scope="module")
def chromium() -> str:
    exe = find_chromium()
    if exe is None:
        if os.environ.get("ACCELLOG_REQUIRE_BROWSER") == "1":
            pytest.fail("chromium is required (ACCELLOG_REQUIRE_BROWSER=1): apt-get install chromium")
        pytest.skip("chromium not installed")
    pytest.importorskip("websockets")
    return exe


BAR_COLORS = [(240, 160, 40), (60, 170, 230)]
"""The ladder's first two steps' colours (its bars are drawn opaque in a 2D view)."""


def _demo_rrd(path: Path) -> None:
    """The recording `accellog demo --quick` writes (the same code path as the README's demo)."""
    from rich.console import Console

    from accellog.flows.demo import run_demo

    run_demo(path.parent / "demo-out", rrd=path, quick=True, console=Console(file=io.StringIO()))


def test_web_viewer_renders_demo_recording(chromium: str, tmp_path: Path) -> None:
    from PIL import Image

    rrd = tmp_path / "demo.rrd"
    _demo_rrd(rrd)
    before = rrd.read_bytes()

    # a blank page in the same browser, for comparison
    with Chromium(size=(1400, 900)) as ch:
        ch.navigate("about:blank")
        blank = pixel_stats(ch.screenshot_png())

    png = tmp_path / "demo.png"
    stats = screenshot_rrd(rrd, png, size=(1400, 900), wait_s=120.0)
    img = np.asarray(Image.open(io.BytesIO(png.read_bytes())).convert("RGB")).astype(int)
    assert img.shape == (900, 1400, 3)
    assert stats.looks_rendered(blank), f"viewer looks blank: {stats} vs blank page {blank}"
    # the plotted series themselves are drawn: pixels in each axis colour of the accel plots
    for axis, rgb in SERIES_COLORS.items():
        near = np.abs(img - np.array(rgb)).sum(axis=2) < 40
        assert near.sum() > 300, f"{axis} series colour {rgb}: only {near.sum()} pixels"
    assert rrd.read_bytes() == before  # the viewer only reads the recording

    # --tab picks the workbench tab: its log10 ladder bars (a colour per step) fill large areas
    png_tab = tmp_path / "workbench.png"
    assert (
        main(["view", str(rrd), "--screenshot", str(png_tab), "--tab", "3 workbench", "--wait-s", "240"]) == 0
    )
    tab = np.asarray(Image.open(io.BytesIO(png_tab.read_bytes())).convert("RGB")).astype(int)
    for rgb in BAR_COLORS:
        n_tab = (np.abs(tab - np.array(rgb)).sum(axis=2) < 30).sum()
        n_default = (np.abs(img - np.array(rgb)).sum(axis=2) < 30).sum()
        assert n_tab > 3000 and n_tab > 5 * n_default, (rgb, n_tab, n_default)
    assert rrd.read_bytes() == before


def test_web_viewer_binds_localhost_only(chromium: str, tmp_path: Path) -> None:
    import psutil

    rrd = tmp_path / "tiny.rrd"
    with RunRecording(f"save:{rrd}") as rec:
        rec.log_samples("raw", np.arange(10.0), None, np.zeros((10, 3)), "g")
    with serve_rrd(rrd) as v:
        assert v.url.startswith("http://127.0.0.1:")
        procs = [psutil.Process(v.proc.pid), *psutil.Process(v.proc.pid).children(recursive=True)]
        listening = [
            c for p in procs for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN
        ]
        assert {c.laddr.port for c in listening} >= {v.grpc_port, v.web_port}
        assert all(c.laddr.ip == "127.0.0.1" for c in listening), listening
