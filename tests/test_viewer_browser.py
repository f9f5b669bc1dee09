"""The web viewer in a real headless Chromium: a demo-like .rrd renders (not blank, not an error page).

Needs the `chromium` apt package and the `websockets` pip package; skipped without Chromium unless
ACCELLOG_REQUIRE_BROWSER=1 (CI), where a missing browser fails the test.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
import pytest

from accellog.online import integrate_batch
from accellog.rrd import RunRecording
from accellog.session import Event, PoseLabel
from accellog.viewer import Chromium, find_chromium, pixel_stats, screenshot_rrd, serve_rrd

pytestmark = pytest.mark.browser

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


def _demo_rrd(path: Path) -> None:
    """Six holds of a seeded session: raw + calibrated accel, poses, temperature, residuals, tracks."""
    rng = np.random.default_rng(7)
    ups = [(0, 0, 1), (0, 0, -1), (0, 1, 0), (0, -1, 0), (1, 0, 0), (-1, 0, 0)]
    rate, hold = 100.0, 5.0
    f = np.concatenate([np.tile(np.array(u, float), (int(rate * hold), 1)) for u in ups])
    t = np.arange(f.shape[0]) / rate
    raw = f @ np.diag([1.01, 0.99, 1.02]).T + [0.09, 0.05, -0.25] + rng.normal(0, 0.01, f.shape)
    cal = (raw - [0.09, 0.05, -0.25]) @ np.diag([1 / 1.01, 1 / 0.99, 1 / 1.02])
    poses = [
        PoseLabel(n, k * hold + 0.5, (k + 1) * hold - 0.5, u, None, k)
        for k, (n, u) in enumerate(zip(["+z", "-z", "+y", "-y", "+x", "-x"], ups, strict=True))
    ]
    means = np.array([raw[(t >= p.start_s) & (t < p.end_s)].mean(axis=0) for p in poses])
    with RunRecording(f"save:{path}", recording_id="browser-demo") as rec:
        rec.log_samples("raw", t, np.arange(t.size), raw, "g")
        rec.log_samples("calibrated", t, np.arange(t.size), cal, "g")
        rec.log_poses(poses)
        rec.log_temperature(t, 30.0 + 0.05 * t)
        rec.log_events([Event(12.0, "gap", "3 missing", 1200, 3)])
        rec.log_residuals("model2", [p.name for p in poses], means, means + rng.normal(0, 0.003, means.shape))
        st = t[: int(30 * rate)]
        for lab, bias_g in (("raw", [0.004, -0.002, 0.006]), ("model2", [-0.0004, 0.0007, 0.0002])):
            acc = np.tile([0.0, 0.0, 1.0], (st.size, 1)) + bias_g + rng.normal(0, 0.001, (st.size, 3))
            rec.log_track(lab, st, integrate_batch(st, acc).disp_m)
        rec.log_document("calibration/model2", "| param | value |\n|---|---|\n| b_x | +0.0900 +- 0.0001 g |")


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
