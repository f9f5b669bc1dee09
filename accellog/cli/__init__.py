"""`accellog` command line: one module per group of commands, all registered on one typer app."""

from __future__ import annotations

import contextlib
import importlib
import os
import pkgutil
import sys
import warnings

import typer

from accellog.cli.app import app
from accellog.core import notices
from accellog.core.errors import AccellogError, DataIntegrityWarning

# Every module in this package registers its commands on `app` when imported; the help lists the
# panels in this order (the story: record, calibrate, discover, inspect, move), then any others.
_ORDER = ["demo", "record", "imports", "calibrate", "report", "workbench", "inspect", "move"]
_names = [m.name for m in pkgutil.iter_modules(__path__) if m.name != "app"]
for _name in sorted(_names, key=lambda n: (_ORDER.index(n) if n in _ORDER else len(_ORDER), n)):
    importlib.import_module(f"{__name__}.{_name}")


def _integrity_line(message, category, filename, lineno, file=None, line=None) -> None:
    """Data-integrity warnings (damaged chunks skipped) as one line on stderr, others as usual."""
    if issubclass(category, DataIntegrityWarning):
        print(f"accellog: warning: {message}", file=sys.stderr)
    else:
        _show_warning(message, category, filename, lineno, file, line)


_show_warning = warnings.showwarning


_BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _one_blas_thread():
    """BLAS on one thread for the whole command: accellog's matrices are small (windows x tens of
    parameters), where threads cost more than they give, and on a shared, loaded machine far more
    (diagnose on a 1 h session: 5x faster wall time at load 12 on 2 cores).

    Before numpy is loaded (the command line: commands import it when they run) the BLAS libraries'
    own variables are set, unless the user set them, so BLAS starts on one thread and threadpoolctl is
    not imported; when numpy is already loaded (main() called in-process, e.g. from a notebook or the
    tests) threadpoolctl limits the loaded libraries for the duration of the command."""
    if "numpy" not in sys.modules:
        for var in _BLAS_THREAD_VARS:
            os.environ.setdefault(var, "1")
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(limits=1, user_api="blas")


def main(argv: list[str] | None = None) -> int:
    """Entry point: runs the app; input errors become one line on stderr and a non-zero exit;
    data-integrity warnings (a damaged chunk skipped) one 'accellog: warning:' line each, notes
    (e.g. what was recovered from a truncated file) one 'accellog: note:' line each."""
    notices.take()  # notes of an earlier in-process call are not this command's
    try:
        with warnings.catch_warnings(), _one_blas_thread():
            warnings.simplefilter("always", DataIntegrityWarning)
            warnings.showwarning = _integrity_line
            rc = app(args=argv, prog_name="accellog", standalone_mode=False)
        for text in notices.take():
            print(f"accellog: note: {text}", file=sys.stderr)
    except AccellogError as exc:
        print(f"accellog: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except (KeyboardInterrupt, typer.Abort):
        print("accellog: interrupted", file=sys.stderr)
        return 130
    except typer.Exit as exc:
        return int(exc.exit_code)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except OSError as exc:  # a file system problem the command did not foresee: still one line
        where = exc.filename if exc.filename is not None else "file system"
        print(f"accellog: error: {where}: {exc.strerror or exc.__class__.__name__}", file=sys.stderr)
        return 2
    except Exception as exc:
        # typer bundles its own click: usage errors carry format_message() and exit_code; they are
        # one line too (the command and the message; `--help` shows the usage).
        if hasattr(exc, "format_message") and isinstance(getattr(exc, "exit_code", None), int):
            ctx = getattr(exc, "ctx", None)
            cmd = f"{ctx.command_path}: " if ctx is not None else ""
            msg = " ".join(str(exc.format_message()).split())
            print(f"accellog: error: {cmd}{msg} (see --help)", file=sys.stderr)
            return exc.exit_code
        raise
    return rc if isinstance(rc, int) else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
