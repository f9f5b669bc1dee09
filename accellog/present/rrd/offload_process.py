"""The writer child of ``present.rrd.offload`` as a process: started, claimed, stopped.

Standard library only, so that the command line (``accellog.cli``) can start the child before it
imports typer and the command's modules: the child's ``import rerun`` (~0.35 s) then runs beside the
parent's own imports (~0.2 s, one core) instead of beside the computation. ``replay --rrd`` 1 h, the
child started once the command was parsed -> as the command line starts: the child starts 0.30-0.35 s
-> 0.10 s into the process, and the command takes 1.26-1.30x -> 1.17x the replay alone (interleaved
runs of both, 7-9 each; ``python benchmarks/run_all.py --rows replay --repeat 7``: 1.15-1.21x).

``prestart`` starts the child (with two cores or more, or ACCELLOG_RRD_CHILD=1); the first file
recording takes it (``claim``, in ``offload.open_recording``); one nobody claimed is stopped when the
command ends (``stop_unclaimed``: ``accellog.cli.main``, and at exit).
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from accellog.core.forked import switched, usable_cores
from accellog.present.rrd import offload_child as wire

ENV_SWITCH = "ACCELLOG_RRD_CHILD"
"""0: every recording in-process; 1: a child even on one core; unset: a child with two cores or more."""
PIPE_BYTES = 1 << 20
"""The call pipe's capacity (Linux F_SETPIPE_SZ; the default is 64 KiB): fewer wake-ups per batch."""
SEND_BYTES = 256 << 10
"""Calls are written to the child in batches of about this many bytes (one frame per call)."""
ROOT = str(Path(__file__).resolve().parents[3])
"""The folder holding this accellog package: the child imports the same code as the parent."""


def use_child() -> bool:
    """Whether a file recording may go to a child process (module docstring)."""
    on = switched(ENV_SWITCH)
    return usable_cores() > 1 if on is None else on


class Writer:
    """A started child process (``offload_child``): calls go to its stdin, replies come back on a pipe
    of their own (what the child or rerun might print on stdout never mixes in)."""

    def __init__(self) -> None:
        r, w = os.pipe()
        code = (
            f"import sys; sys.path[0] = {ROOT!r}; from accellog.present.rrd.offload_child import main; main()"
        )
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", code, str(w)],
                stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL,
                bufsize=0,
                pass_fds=(w,),
                start_new_session=True,  # no terminal: Ctrl-C reaches the parent only, which decides
            )
        except BaseException:
            os.close(r)
            raise
        finally:
            os.close(w)
        self.reply = r
        self._pending: list[bytes] = []
        self._pending_bytes = 0
        assert self.proc.stdin is not None
        self.fd = self.proc.stdin.fileno()
        with contextlib.suppress(AttributeError, OSError):
            fcntl.fcntl(self.fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)

    def send(self, msg: tuple, *, flush: bool = False) -> None:
        """Send msg: small frames are gathered (a copy; the caller may change its arrays once the
        call returns) and written by SEND_BYTES, one wake-up of the child each; a large one goes at
        once from the caller's arrays; flush: now, with all before it."""
        parts = wire.frame(msg)
        size = sum(p.nbytes for p in parts)
        if size < SEND_BYTES:
            self._pending.append(b"".join(parts))
            self._pending_bytes += size
            parts = []
        if parts or flush or self._pending_bytes >= SEND_BYTES:
            pending = [memoryview(b) for b in self._pending]
            self._pending, self._pending_bytes = [], 0
            wire.write_all(self.fd, pending + parts)

    def recv(self) -> Any:
        """The child's next reply; EOFError when it exited without one."""
        return wire.recv(self.reply)

    def stop(self, timeout_s: float | None = None) -> None:
        """Wait for the child to exit (up to timeout_s), kill it if it does not (at once: None), close
        the pipes."""
        with contextlib.suppress(OSError, ValueError):
            self.proc.stdin.close()  # type: ignore[union-attr]
        try:
            if timeout_s is None:
                raise subprocess.TimeoutExpired(self.proc.args, 0)
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(OSError):
                self.proc.kill()
            self.proc.wait()
        if self.reply >= 0:
            os.close(self.reply)
            self.reply = -1

    def how_it_ended(self) -> str:
        rc = self.proc.returncode
        if rc is None:
            return "stopped answering"
        if rc < 0:
            with contextlib.suppress(ValueError):
                return f"was killed by {signal.Signals(-rc).name}"
            return f"was killed by signal {-rc}"
        return f"exited with code {rc}"


_started: Writer | None = None


def prestart() -> bool:
    """Start the writer child now, when recordings may go to one (``use_child``): it imports rerun
    while the command goes on; the first ``open_recording`` of a file takes it. True when a child
    runs."""
    global _started
    if _started is not None and _started.proc.poll() is not None:  # died unclaimed
        stop_unclaimed()
    if _started is None and use_child():
        try:
            _started = Writer()
        except OSError:  # no process to spare: the recording stays in this process
            _started = None
    return _started is not None


def started() -> bool:
    """Whether a started child waits to be claimed."""
    return _started is not None


def claim() -> Writer | None:
    """The started child, now the caller's (None when there is none)."""
    global _started
    w, _started = _started, None
    return w


@atexit.register
def stop_unclaimed() -> None:
    """Stop a started child nobody has claimed (the command ended or failed before)."""
    w = claim()
    if w is not None:
        w.stop()
