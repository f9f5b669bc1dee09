"""The viewer's child processes (rerun server, chromium): each in its own process group, ended with
all its helpers on every exit path of this process (see the comment below)."""

from __future__ import annotations

import atexit
import contextlib
import os
import shutil
import signal
import subprocess
import threading
import time

# Children (rerun server, chromium) run in their own process group (start_new_session) so that one
# killpg ends them with all their helpers. They are ended on every exit path of this process:
# normal return and exceptions (context managers), SIGTERM/SIGHUP (handlers installed with the first
# child turn the signal into SystemExit after ending the children) and interpreter exit (atexit).
_CHILDREN: set[subprocess.Popen] = set()
_FOLDERS: dict[int, str] = {}  # child pid -> its throw-away folder, removed when the child is stopped
_HANDLED = (signal.SIGTERM, signal.SIGHUP)
_installed = False


def start_child(cmd: list[str], *, folder: str | None = None, **kw) -> subprocess.Popen:
    """Popen in a new process group (stdout/stderr discarded), ended on every exit path; folder
    (e.g. a browser profile) is removed whenever the child is stopped, signals included."""
    _install_exit_guards()
    try:
        proc = subprocess.Popen(
            cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True, **kw
        )
    except BaseException:
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
        raise
    _CHILDREN.add(proc)
    if folder is not None:
        _FOLDERS[proc.pid] = folder
    return proc


def end_children() -> None:
    """Stop every child still running (process groups: SIGTERM, then SIGKILL after 5 s)."""
    for proc in list(_CHILDREN):
        with contextlib.suppress(Exception):
            stop_process(proc)


def _on_signal(signum, _frame) -> None:
    end_children()
    raise SystemExit(128 + signum)


def _install_exit_guards() -> None:
    global _installed
    if _installed:
        return
    _installed = True
    atexit.register(end_children)
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in _HANDLED:
        if signal.getsignal(sig) in (signal.SIG_DFL, None):
            signal.signal(sig, _on_signal)


def stop_process(proc: subprocess.Popen, timeout_s: float = 5.0) -> None:
    """Terminate a process we started (its own process group), then kill it if it lingers; kill the
    helpers left in its group and remove its folder."""
    _CHILDREN.discard(proc)
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout_s)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # the process if it lingers, and helpers left in its group
    proc.wait()
    folder = _FOLDERS.pop(proc.pid, None)
    if folder is not None:
        _remove_folder(folder)


def _remove_folder(folder: str, timeout_s: float = 2.0) -> None:
    """rmtree, again while helpers that were just killed may still have been writing into it."""
    end = time.monotonic() + timeout_s
    shutil.rmtree(folder, ignore_errors=True)
    while os.path.exists(folder) and time.monotonic() < end:
        time.sleep(0.05)
        shutil.rmtree(folder, ignore_errors=True)
