"""Serve an .rrd to Rerun's web viewer on 127.0.0.1 and screenshot it in headless Chromium.

``serve_rrd`` runs ``rerun --serve-web --bind 127.0.0.1`` (the viewer bundled in the rerun-sdk
wheel) on free ports; ``Chromium`` drives a headless browser over the DevTools protocol
(websocket, 127.0.0.1 only, fresh profile, no background networking); ``screenshot_rrd`` waits in
real time until the viewer has drawn the recording and saves a PNG. Nothing here writes to the
.rrd: the server only reads it.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.parse
import urllib.request
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from accellog.core.errors import InputError
from accellog.present.rrd.tabs import tab_view_files
from accellog.present.viewer_children import start_child, stop_process
from accellog.store.atomic import write_bytes_atomic

if TYPE_CHECKING:
    from websockets.sync.client import ClientConnection

CHROMIUM_CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "chrome")


def rerun_binary() -> str:
    """Path of the rerun executable bundled with rerun-sdk (not the Python wrapper script)."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / "rerun"
        if exe.exists():
            return str(exe)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if not found:
        raise InputError("the rerun executable was not found (pip install rerun-sdk)")
    return found


def _require(module: str, pip_name: str) -> None:
    """InputError (one line, not a traceback) when an optional screenshot dependency is missing."""
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise InputError(f"screenshots need the {pip_name} package: pip install {pip_name}")


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable ($ACCELLOG_CHROMIUM first), or None."""
    env = os.environ.get("ACCELLOG_CHROMIUM")
    if env:
        return env
    for name in CHROMIUM_CANDIDATES:
        p = shutil.which(name)
        if p:
            return p
    return None


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_port(port: int, timeout_s: float, proc: subprocess.Popen | None = None) -> None:
    """Wait until 127.0.0.1:port accepts connections (or the process died / time is up)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc is not None and proc.poll() is not None:
            args = proc.args
            exe = args[0] if isinstance(args, (list, tuple)) else args
            raise InputError(f"{Path(str(exe)).name} exited with code {proc.returncode}")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return
        time.sleep(0.1)
    raise InputError(f"nothing listens on 127.0.0.1:{port} after {timeout_s:g} s")


def require_display() -> None:
    """InputError (one line) when the native viewer has no display to open on (Linux without
    $DISPLAY or $WAYLAND_DISPLAY): it would start, fail and leave the command silent."""
    import sys

    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise InputError(
            "no display for the native viewer (DISPLAY is not set): use --web (prints a URL to open) "
            "or --screenshot PNG"
        )


def rerun_env() -> dict[str, str]:
    """Environment for rerun processes: analytics off."""
    return dict(os.environ, RERUN_ANALYTICS="0")


@dataclass
class WebViewer:
    """A running ``rerun --serve-web`` for one .rrd: open ``url`` in a browser."""

    proc: subprocess.Popen
    grpc_port: int
    web_port: int

    @property
    def url(self) -> str:
        data = urllib.parse.quote(f"rerun+http://127.0.0.1:{self.grpc_port}/proxy", safe="")
        return f"http://127.0.0.1:{self.web_port}/?url={data}&renderer=webgl"


@contextlib.contextmanager
def serve_rrd(
    rrd_path: str | Path, *, timeout_s: float = 30.0, extra: Sequence[str | Path] = ()
) -> Iterator[WebViewer]:
    """Serve rrd_path (and extra files, e.g. a .rbl blueprint) to the web viewer on 127.0.0.1 (free
    ports); stopped on exit."""
    p = Path(rrd_path)
    if not p.is_file():
        raise InputError("no such .rrd file", where=str(p))
    grpc_port, web_port = free_port(), free_port()
    while web_port == grpc_port:
        web_port = free_port()
    cmd = [
        rerun_binary(),
        "--serve-web",
        "--bind",
        "127.0.0.1",
        "--port",
        str(grpc_port),
        "--web-viewer-port",
        str(web_port),
        str(p),
        *map(str, extra),
    ]
    proc = start_child(cmd, env=rerun_env())
    try:
        wait_port(web_port, timeout_s, proc)
        wait_port(grpc_port, timeout_s, proc)
        yield WebViewer(proc, grpc_port, web_port)
    finally:
        stop_process(proc)


class DevToolsTimeout(InputError):
    """Chromium did not answer a DevTools command in time (the page may still be busy drawing)."""


@contextlib.contextmanager
def _one_line(what: str) -> Iterator[None]:
    """A broken DevTools connection (chromium crashed, or closed the socket) as one InputError line."""
    from websockets.exceptions import WebSocketException

    try:
        yield
    except (WebSocketException, ConnectionError) as exc:
        raise InputError(
            f"chromium closed the DevTools connection while waiting for {what} ({exc})"
        ) from None


class Chromium:
    """Headless Chromium driven over the DevTools protocol (127.0.0.1, throw-away profile);
    timeout_s bounds the start and each command unless the command gives its own."""

    def __init__(
        self,
        *,
        size: tuple[int, int] = (1400, 900),
        exe: str | None = None,
        timeout_s: float = 30.0,
        args: Sequence[str] = (),
    ):
        _require("websockets", "websockets")
        self.exe = exe or find_chromium()
        if not self.exe:
            raise InputError("chromium not found: apt-get install chromium (or set ACCELLOG_CHROMIUM)")
        self.size = size
        self.timeout_s = timeout_s
        self._profile = tempfile.mkdtemp(prefix="accellog-chromium-")  # removed by stop_process
        self.port = free_port()
        cmd = [
            self.exe,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--disable-extensions",
            "--disable-default-apps",
            "--metrics-recording-only",
            "--mute-audio",
            "--remote-debugging-address=127.0.0.1",
            f"--remote-debugging-port={self.port}",
            f"--user-data-dir={self._profile}",
            f"--window-size={size[0]},{size[1]}",
            *args,
            "about:blank",
        ]
        # Chromium's own temporary files go to the profile folder, removed on close.
        env = {**os.environ, "TMPDIR": self._profile}
        self.proc = start_child(cmd, folder=self._profile, env=env)
        self._ws: ClientConnection | None = None
        self._id = 0
        self._events: set[str] = set()
        self._stack = contextlib.ExitStack()
        try:
            wait_port(self.port, timeout_s, self.proc)
            self._attach()
        except BaseException:
            self.close()
            raise

    def _attach(self) -> None:
        from websockets.sync.client import connect

        end = time.monotonic() + self.timeout_s
        ws_url = None
        while ws_url is None and time.monotonic() < end:
            with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/list", timeout=5) as r:
                pages = [t for t in json.load(r) if t.get("type") == "page"]
            if pages:
                ws_url = pages[0]["webSocketDebuggerUrl"]
            else:
                time.sleep(0.1)
        if ws_url is None:
            raise InputError("chromium opened no page")
        # no keepalive pings: a software-rendered page keeps chromium's DevTools thread busy for
        # longer than websockets' default 20 s ping timeout, which would end the connection
        self._ws = self._stack.enter_context(
            connect(ws_url, max_size=None, open_timeout=self.timeout_s, ping_interval=None, close_timeout=2)
        )
        w, h = self.size
        self.call("Emulation.setDeviceMetricsOverride", width=w, height=h, deviceScaleFactor=1, mobile=False)
        self.call("Page.enable")
        self.call("Runtime.enable")

    def call(self, method: str, *, timeout_s: float | None = None, **params) -> dict:
        """Send one DevTools command and return its result (events in between are skipped); waits
        at most timeout_s (default: the browser's timeout_s), else DevToolsTimeout. A late answer
        to a command given up on is skipped by the next call (answers carry their command's id)."""
        assert self._ws is not None
        self._id += 1
        my_id = self._id
        wait = self.timeout_s if timeout_s is None else max(float(timeout_s), 0.01)
        with _one_line(method):
            self._ws.send(json.dumps({"id": my_id, "method": method, "params": params}))
        end = time.monotonic() + wait
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise DevToolsTimeout(f"chromium did not answer {method} within {wait:g} s")
            try:
                msg = self._recv(left, f"the answer to {method}")
            except TimeoutError:
                raise DevToolsTimeout(f"chromium did not answer {method} within {wait:g} s") from None
            self._handle(msg)
            if msg.get("id") == my_id:
                if "error" in msg:
                    raise InputError(f"chromium: {method}: {msg['error'].get('message')}")
                return msg.get("result", {})

    def navigate(self, url: str, *, load_timeout_s: float = 20.0) -> None:
        """Open url and wait (at most load_timeout_s) for its load event."""
        self._events.clear()
        self.call("Page.navigate", url=url)
        end = time.monotonic() + load_timeout_s
        while "Page.loadEventFired" not in self._events and time.monotonic() < end:
            with contextlib.suppress(TimeoutError):
                self._handle(self._recv(max(0.01, end - time.monotonic())))

    def _recv(self, timeout_s: float, what: str = "the page to load") -> dict:
        """The next DevTools message (TimeoutError after timeout_s; InputError when chromium has
        closed the connection)."""
        assert self._ws is not None
        with _one_line(what):
            return json.loads(self._ws.recv(timeout=timeout_s))

    def _handle(self, msg: dict) -> None:
        if "method" in msg:
            self._events.add(msg["method"])

    def screenshot_png(self, timeout_s: float | None = None) -> bytes:
        """PNG of the current viewport (bytes); waits at most timeout_s (default: the browser's)."""
        res = self.call("Page.captureScreenshot", timeout_s=timeout_s, format="png", fromSurface=True)
        return base64.b64decode(res["data"])

    def evaluate(self, expression: str):
        res = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return res.get("result", {}).get("value")

    def close(self) -> None:
        if self._ws is not None:
            with contextlib.suppress(Exception):
                self._stack.close()
            self._ws = None
        stop_process(self.proc)

    def __enter__(self) -> Chromium:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass
class PixelStats:
    """How much a screenshot shows: distinct colours (6-bit quantised), fraction of pixels that
    differ from the dominant (background) colour, and the grey-level standard deviation."""

    colors: int
    non_background: float
    std: float

    def looks_rendered(self, blank: PixelStats | None = None) -> bool:
        """Heuristic: many colours (a loading screen has ~300, a drawn recording 450 (the demo's
        workbench tab: flat bars and a table) to 1000 or more) and a share of non-background pixels,
        both well above a blank page's when one is given."""
        ok = self.colors >= 450 and self.non_background >= 0.05
        if blank is not None:
            ok = ok and self.colors >= 20 * max(blank.colors, 1)
            ok = ok and self.non_background > blank.non_background + 0.03
        return ok


def pixel_stats(png: bytes) -> PixelStats:
    """PixelStats of a PNG image."""
    _require("PIL", "pillow")
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.uint8)
    q = (img >> 2).astype(np.int32)
    code = (q[..., 0] << 12) | (q[..., 1] << 6) | q[..., 2]
    vals, counts = np.unique(code.ravel(), return_counts=True)
    bg = counts.max() / code.size
    grey = img.astype(np.float64).mean(axis=2)
    return PixelStats(int(vals.size), float(1.0 - bg), float(grey.std()))


def screenshot_url(
    url: str,
    png_path: str | Path,
    *,
    size: tuple[int, int] = (1400, 900),
    wait_s: float = 60.0,
    min_wait_s: float = 6.0,
    settle_s: float = 2.0,
    deadline: float | None = None,
) -> PixelStats:
    """Open url in headless Chromium, wait (real time) until the page looks rendered and stable for
    settle_s (at least min_wait_s after loading), save the PNG atomically; returns its PixelStats.

    wait_s bounds everything end to end: the browser's start, the page load and every capture (a
    capture answered late on a loaded machine may take the time left, not a fixed timeout); deadline
    (time.monotonic()) replaces now + wait_s when the caller's wait began earlier. Nothing is
    written unless a rendered, stable picture was taken: InputError otherwise (no partial PNG)."""
    deadline = time.monotonic() + wait_s if deadline is None else deadline
    out = Path(png_path)
    if not out.parent.is_dir():
        raise InputError("folder does not exist", where=str(out.parent))
    _require("PIL", "pillow")
    try:
        with Chromium(size=size, timeout_s=max(deadline - time.monotonic(), 1.0)) as ch:
            ch.navigate(url, load_timeout_s=max(min(20.0, deadline - time.monotonic()), 0.1))
            seen: list[tuple[float, PixelStats]] = []
            shot = _settled_capture(ch, deadline, min_wait_s, settle_s, seen=seen)
    except OSError as exc:  # the browser's DevTools port refused or reset: one line, not a traceback
        raise InputError(f"chromium's DevTools port failed: {exc}; nothing written", where=str(out)) from None
    if shot is None:
        raise InputError(
            f"the viewer did not draw a stable picture within {wait_s:.0f} s; nothing written "
            f"({_why_not_drawn(seen)})",
            where=str(out),
        )
    write_bytes_atomic(out, shot[0])
    return shot[1]


def _why_not_drawn(seen: list[tuple[float, PixelStats]]) -> str:
    """Why no picture was taken, from the captures (time s, stats): a page that stayed blank and
    alike over its last three or more captures draws nothing there (or is far too slow), else it
    was still changing."""
    tail = seen[-3:]
    if len(tail) == 3 and not any(st.looks_rendered() for _, st in tail):
        lo, hi = min(st.colors for _, st in tail), max(st.colors for _, st in tail)
        if hi <= 1.1 * max(lo, 1):
            last = tail[-1][1]
            return (
                f"it stayed blank, {last.colors} colours and {100 * last.non_background:.0f}% drawn, over its "
                f"last {tail[-1][0] - tail[0][0]:.0f} s: that view or tab draws nothing, or the machine is far "
                "too busy for it"
            )
    return "it was still changing: a longer --wait-s helps on a loaded machine"


def _settled_capture(
    ch: Chromium,
    deadline: float,
    min_wait_s: float,
    settle_s: float,
    poll_s: float = 1.0,
    seen: list[tuple[float, PixelStats]] | None = None,
) -> tuple[bytes, PixelStats] | None:
    """Capture until two successive pictures look rendered and alike (colour counts within 10 %)
    for settle_s, at least min_wait_s after the start; at the deadline the last such picture, if the
    last two captures were alike, else None. Captures are spaced by at least the time the last one
    took, so a slow browser is not kept busy by them. seen: gets (time s, stats) of every capture."""
    start = time.monotonic()
    prev: PixelStats | None = None
    good: tuple[bytes, PixelStats] | None = None
    stable_since: float | None = None
    gap_s = poll_s
    while True:
        time.sleep(max(0.0, min(gap_s, deadline - time.monotonic())))
        t0 = time.monotonic()
        if t0 >= deadline:
            return good
        try:
            png = ch.screenshot_png(timeout_s=deadline - t0)
        except DevToolsTimeout:
            return good
        now = time.monotonic()
        gap_s = max(poll_s, now - t0)
        new = pixel_stats(png)
        if seen is not None:
            seen.append((now, new))
        if prev is not None and new.looks_rendered() and abs(new.colors - prev.colors) <= 0.1 * prev.colors:
            stable_since = now if stable_since is None else stable_since
            good = (png, new)
        else:
            stable_since, good = None, None
        prev = new
        stable = stable_since is not None and now - stable_since >= settle_s
        if good is not None and stable and now - start >= min_wait_s:
            return good


def screenshot_rrd(
    rrd_path: str | Path,
    png_path: str | Path,
    *,
    size: tuple[int, int] = (1400, 900),
    wait_s: float = 60.0,
    min_wait_s: float = 8.0,
    tab: str | None = None,
) -> PixelStats:
    """Serve rrd_path on 127.0.0.1, open it in the web viewer in headless Chromium, wait until it has
    rendered, save a PNG screenshot of size (width, height) pixels to png_path. tab: the display name
    of the blueprint tab to show (accellog.present.rrd.tabs). wait_s bounds the whole call (picking
    the tab, starting the server and the browser, drawing); see screenshot_url."""
    deadline = time.monotonic() + wait_s
    with tempfile.TemporaryDirectory(prefix="accellog-tab-") as tmp:
        extra: list[Path] = []
        if tab is not None:
            rrd_path, rbl = tab_view_files(rrd_path, tab, tmp)
            extra.append(rbl)
        with serve_rrd(rrd_path, extra=extra, timeout_s=max(deadline - time.monotonic(), 1.0)) as viewer:
            return screenshot_url(
                viewer.url, png_path, size=size, wait_s=wait_s, min_wait_s=min_wait_s, deadline=deadline
            )
