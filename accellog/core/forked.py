"""One call run in a forked child while the command goes on: the second core for one command.

``diagnose`` 1 h spends ~0.95 s reading and segmenting the session (numpy and the MCAP reader) and
~0.4 s importing what the diagnosis needs (scipy.optimize, scipy.linalg). A thread gives nothing
there: an import runs module bodies, which hold the GIL. ``started(fn, ...)`` forks: the child runs
``fn`` and sends its value back through a pipe (pickle protocol 5), the parent imports meanwhile and
takes the value with ``result()``. The child inherits the parent's modules, so it starts at once.

What the child raised reaches the parent as if the call had run in-process: its warnings are
re-issued (``warnings.warn_explicit``, through the parent's filters), its notes queued
(``core.notices``), its exception raised (an ``AccellogError`` as it is: one line). A child that dies
without a word (killed, out of memory) is a ``ChildDied`` line; Ctrl-C stops the child with the
parent (SIGINT keeps its default action there). The child only computes: it writes no file and
prints nothing, and ``os._exit`` ends it (no atexit handler, no flush of the parent's buffers).
Leaving the ``with`` block without the result (the parent failed first) kills and reaps the child.

Only a command of the CLI forks (``allowed()``: a short-lived process that runs one command);
a library caller (a Dask worker, a notebook) keeps every call in-process, as does a command with
one core, without ``os.fork`` (Windows) or with ACCELLOG_FORK=0: ``fn`` then runs when ``result()``
is called, so the order of the work, its notes and its errors is the same either way.

Measured with ``python benchmarks/run_all.py --rows diagnose fit --repeat 5`` run with and without
ACCELLOG_FORK=0, twice each (2 cores): ``diagnose`` 1 h 1.37-1.70 s instead of 1.70-1.81 s,
``fit`` 1 h 1.92-2.00 s instead of 2.17-2.33 s; CPU within noise; peak memory (the larger of
the two processes) 141 MB instead of 146-150 MB for ``diagnose``.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import warnings
from collections.abc import Callable, Iterator
from typing import Any, Generic, TypeVar

from accellog.core import notices
from accellog.core.errors import AccellogError

T = TypeVar("T")

ENV_SWITCH = "ACCELLOG_FORK"
"""0: every call in-process; 1: forked even on one core; unset: forked with two cores or more."""


class ChildDied(AccellogError):
    """The forked child ended without sending its result (killed, out of memory)."""


def usable_cores() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    cores = os.cpu_count() or 1
    with contextlib.suppress(AttributeError, OSError):
        cores = min(cores, len(os.sched_getaffinity(0)))
    return cores


def switched(name: str) -> bool | None:
    """Environment switch `name`: True (1/yes/true/on), False (0/no/false/off), None (unset/other)."""
    v = os.environ.get(name, "").strip().lower()
    if v in ("0", "no", "false", "off"):
        return False
    if v in ("1", "yes", "true", "on"):
        return True
    return None


_allowed = False


@contextlib.contextmanager
def allowed() -> Iterator[None]:
    """``started`` may fork inside this block (the CLI's command; module docstring)."""
    global _allowed
    before, _allowed = _allowed, True
    try:
        yield
    finally:
        _allowed = before


def use_fork() -> bool:
    """Whether ``started`` forks (module docstring)."""
    if not (_allowed and hasattr(os, "fork")):
        return False
    on = switched(ENV_SWITCH)
    return usable_cores() > 1 if on is None else on


class Pending(Generic[T]):
    """fn(*args, **kw) under way; ``result()`` waits for it (a context manager: see the module doc)."""

    def __init__(self, fn: Callable[..., T], args: tuple, kw: dict, what: str, fork: bool) -> None:
        self.what = what
        self._forked = fork
        self._pid: int | None = None
        self._fd: int | None = None
        self._call: tuple | None = None if fork else (fn, args, kw)
        if not fork:
            return
        r, w = os.pipe()
        with warnings.catch_warnings():  # Python >= 3.12 warns of the BLAS pool's threads: none runs Python
            warnings.filterwarnings("ignore", "This process .* is multi-threaded", DeprecationWarning)
            pid = os.fork()
        if pid == 0:  # the child: never returns
            code = 1
            try:
                os.close(r)
                signal.signal(signal.SIGINT, signal.SIG_DFL)
                code = _child(w, fn, args, kw)
            finally:
                os._exit(code)
        os.close(w)
        self._pid, self._fd = pid, r

    @property
    def forked(self) -> bool:
        """Whether a child runs fn (else result() runs it)."""
        return self._forked

    def result(self) -> T:
        """fn's value; its warnings and notes re-issued, its exception raised (module doc)."""
        if self._call is not None:
            fn, args, kw = self._call
            self._call = None
            return fn(*args, **kw)
        data = self._read()
        status = self._reap()
        try:
            ok, value, caught, notes = pickle.loads(data)
        except Exception:  # nothing, or a message cut short: the child died
            if os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGINT:
                raise KeyboardInterrupt from None
            how = (
                f"signal {signal.Signals(os.WTERMSIG(status)).name}"
                if os.WIFSIGNALED(status)
                else f"exit code {os.waitstatus_to_exitcode(status)}"
            )
            raise ChildDied(f"the process {self.what} ended without a result ({how})") from None
        for message, category, filename, lineno in caught:
            warnings.warn_explicit(message, category, filename, lineno)
        for text in notes:
            notices.note(text)
        if not ok:
            exc, text = value
            raise exc if exc is not None else ChildDied(f"the process {self.what} failed: {text}")
        return value

    def cancel(self) -> None:
        """Stop a child whose result is not wanted (nothing happens once the result was taken)."""
        if self._pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self._pid, signal.SIGKILL)
            self._reap()

    def _read(self) -> bytes:
        fd = self._fd
        if fd is None:
            raise RuntimeError("the child's result was already taken")
        chunks = []
        try:
            while chunk := os.read(fd, 1 << 20):
                chunks.append(chunk)
        finally:
            os.close(fd)
            self._fd = None
        return b"".join(chunks)

    def _reap(self) -> int:
        pid, self._pid = self._pid, None
        if pid is None:
            raise RuntimeError("the child was already reaped")
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
        return os.waitpid(pid, 0)[1]

    def __enter__(self) -> Pending[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.cancel()


def started(
    fn: Callable[..., T], *args: Any, what: str = "computing", meanwhile: bool = True, **kw: Any
) -> Pending[T]:
    """fn(*args, **kw) in a forked child from now on (module docstring), or in-process on result();
    what: names the work in a ChildDied line ("reading x.mcap"); meanwhile False: the caller has
    nothing to do in the meantime (e.g. its imports are done), so nothing is forked."""
    return Pending(fn, args, kw, what, meanwhile and use_fork())


def _child(fd: int, fn: Callable[..., Any], args: tuple, kw: dict) -> int:
    """Run fn, send (ok, value or (exception, text), warnings, notes) on fd; the exit code."""
    notices.take()  # the parent's notes are the parent's to print
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # the parent's filters decide, on warn_explicit
        try:
            ok, value = True, fn(*args, **kw)
        except BaseException as exc:  # reported to the parent, which raises it
            ok, value = False, (_portable(exc), f"{type(exc).__name__}: {exc}")
    seen = [(w.message, w.category, w.filename, w.lineno) for w in caught]
    msg = (ok, value, seen, notices.take())
    try:
        data = pickle.dumps(msg, protocol=5)
    except Exception as exc:  # an unpicklable value or warning: said
        text = value[1] if not ok else f"the result could not be sent: {exc}"
        data = pickle.dumps((False, (None, text), [], msg[3]), protocol=5)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    return 0


def _portable(exc: BaseException) -> BaseException | None:
    """exc if it survives pickling (the parent raises it as it is), else None (its text is sent)."""
    try:
        return pickle.loads(pickle.dumps(exc, protocol=5))
    except Exception:
        return None
