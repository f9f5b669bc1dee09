"""Where a recording goes: ``save:PATH`` (file, written to a temporary name and renamed on close),
``spawn`` (native viewer, started by accellog itself so it binds 127.0.0.1), ``connect`` / ``connect:URL``
(gRPC proxy, e.g. ``rerun+http://127.0.0.1:9876/proxy``). Live sinks are *guarded*: a failure is counted
and reported once, never raised into the caller (the MCAP recorder must keep recording).
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable

from accellog.core.errors import InputError
from accellog.present.rrd.entities import DEFAULT_GRPC_URL


class SinkWatch:
    """Background TCP probe of a live sink (host, port): marks it down once unreachable."""

    def __init__(self, host: str, port: int, on_down: Callable[[str], None], period_s: float = 0.25):
        self.host, self.port, self.on_down, self.period_s = host, port, on_down, period_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="accellog-rerun-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        misses = 0
        while not self._stop.wait(self.period_s):
            try:
                with socket.create_connection((self.host, self.port), timeout=0.5):
                    misses = 0
            except OSError as exc:
                misses += 1
                if misses >= 2:
                    self.on_down(f"viewer at {self.host}:{self.port} unreachable ({exc.strerror or exc})")
                    return

    def stop(self) -> None:
        self._stop.set()


def spawn_viewer(port: int, timeout_s: float = 20.0) -> None:
    """Start the native viewer listening on 127.0.0.1:port (``rr.spawn`` would bind 0.0.0.0), unless
    a viewer already listens there; wait until it accepts connections. Without a display (Linux:
    neither $DISPLAY nor $WAYLAND_DISPLAY) or when the viewer exits at once, one line says so at
    once; the viewer's own output (ANSI-coloured Rust log lines) never reaches the terminal."""
    import os
    import subprocess
    import sys

    from accellog.present.viewer import rerun_binary, rerun_env

    if wait_for_port("127.0.0.1", port, 0.0):
        return
    if sys.platform.startswith("linux") and not (
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    ):
        raise InputError("no display ($DISPLAY and $WAYLAND_DISPLAY are unset): the native viewer cannot "
                         "open; use --rerun save:FILE.rrd, then accellog view FILE.rrd --web")  # fmt: skip
    cmd = [rerun_binary(), "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=rerun_env(), start_new_session=True
    )
    end = time.monotonic() + timeout_s
    while not wait_for_port("127.0.0.1", port, min(0.5, timeout_s)):
        if proc.poll() is not None:
            raise InputError(
                f"the viewer exited at start (code {proc.returncode}): use --rerun save:FILE.rrd"
            )
        if time.monotonic() >= end:
            raise InputError(f"the spawned viewer does not listen on 127.0.0.1:{port} after {timeout_s:g} s")


def parse_sink(sink: str) -> tuple[str, str]:
    if sink.startswith("save:"):
        path = sink[5:]
        if not path:
            raise InputError("rerun sink 'save:' needs a file name, e.g. save:run.rrd")
        return "save", path
    if sink == "spawn":
        return "spawn", ""
    if sink == "connect":
        return "connect", DEFAULT_GRPC_URL
    if sink.startswith("connect:"):
        return "connect", sink[8:]
    raise InputError(f"unknown rerun sink {sink!r}: use save:FILE.rrd, spawn, connect or connect:URL")


def wait_for_port(host: str, port: int, timeout_s: float = 20.0) -> bool:
    """True once a TCP connection to host:port succeeds within timeout_s (s; 0: one attempt)."""
    end = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return True
        except OSError:
            if time.monotonic() >= end:
                return False
            time.sleep(0.1)
