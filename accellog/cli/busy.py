"""No command is silent for more than ~2 s on a terminal: when a command has printed nothing for
``delay_s``, a spinner ("accellog fit: working") appears on stderr; the next thing the command
prints removes it first, and the wait starts again. Only when stdout and stderr are terminals and
--json was not given (accellog.cli.progress.wanted); commands with their own progress bar keep the
spinner away by drawing (every draw counts as output).

The spinner is rich's (``Spinner`` in a transient ``Live``, what ``Console.status`` builds) with the
redirection off: ``Console.status`` cannot turn it off and, on a terminal, would send the command's
stdout through the console onto stderr (tests/cli/test_cli_talks.py). rich has no "after a silence"
display, hence the timer and the write hook."""

from __future__ import annotations

import sys
import threading
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rich.live import Live


class _Stream:
    """A stream that tells ``on_write`` before each write (the command's own output)."""

    def __init__(self, stream: Any, on_write) -> None:
        self._stream, self._on_write = stream, on_write

    def write(self, text: str) -> int:
        if text:
            self._on_write()
        return self._stream.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


class Busy:
    """Context manager: the spinner after ``delay_s`` of silence (module docstring)."""

    def __init__(self, label: str, delay_s: float = 2.0, *, show: bool = True) -> None:
        self.label, self.delay_s, self.show = label, delay_s, show
        self._lock = threading.RLock()
        self._timer: threading.Timer | None = None
        self._status: Live | None = None
        self._saved: tuple[Any, Any] | None = None
        self._done = False

    def __enter__(self) -> Busy:
        if self.show:
            self._saved = (sys.stdout, sys.stderr)
            sys.stdout, sys.stderr = _Stream(sys.stdout, self._quiet), _Stream(sys.stderr, self._quiet)
            self._arm()
        return self

    def __exit__(self, *exc) -> None:
        with self._lock:
            self._done = True
            self._stop()
        if self._saved is not None:
            sys.stdout, sys.stderr = self._saved
            self._saved = None

    def _arm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = threading.Timer(self.delay_s, self._start)
        self._timer.daemon = True
        self._timer.start()

    def _start(self) -> None:
        with self._lock:
            if self._done or self._status is not None or self._saved is None:
                return
            from rich.console import Console
            from rich.live import Live
            from rich.spinner import Spinner

            self._status = Live(
                Spinner("dots", text=f"{self.label}: working"),
                console=Console(file=self._saved[1]),
                transient=True,
                redirect_stdout=False,  # the command's output goes through _Stream, which removes it first
                redirect_stderr=False,
                refresh_per_second=8,
            )
            self._status.start()

    def _stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        if self._status is not None:
            status, self._status = self._status, None
            status.stop()

    def _quiet(self) -> None:
        """The command writes: the spinner goes first, and the wait starts again."""
        with self._lock:
            if self._done:
                return
            self._stop()
            self._arm()
