"""`accellog` command line: one module per group of commands, all registered on one typer app
(accellog.cli.app), run as a lazy click group: a command line imports only the module of its command
and builds only that command (#9)."""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import warnings

from accellog.cli import early
from accellog.core import forked, notices
from accellog.core.errors import AccellogError, DataIntegrityWarning


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


def _usage_error_line(command_path: str | None, message: str) -> str:
    """A click usage error on one line with the one prefix: 'accellog: error: fit: MESSAGE (see
    accellog fit --help)'; the program name is not repeated."""
    path = (command_path or "accellog").split()
    sub = " ".join(path[1:]) if path[:1] == ["accellog"] else " ".join(path)
    where = f"{sub}: " if sub else ""
    text = " ".join(message.split()) or "no command given"
    return f"accellog: error: {where}{text} (see {' '.join(['accellog', sub]).strip()} --help)"


_WAITS = ("record", "view")  # they wait for a person or a viewer, not for a computation


def _busy(args: list[str]):
    """A spinner after 2 s of silence on a terminal (accellog.cli.busy); not for --json, help,
    options alone (--version, completion), nor the commands that wait for a person or a viewer."""
    words = [a for a in args if not a.startswith("-")]
    if not words or words[0] in _WAITS or "--json" in args or "--help" in args or args[0].startswith("-"):
        return contextlib.nullcontext()
    if not (sys.stdout.isatty() and sys.stderr.isatty()):
        return contextlib.nullcontext()
    from accellog.cli.busy import Busy

    label = "accellog " + " ".join(words[:2] if words[0] in ("import", "fleet") else words[:1])
    return Busy(label)


INTERRUPTED = 130
"""Exit code of a command stopped by Ctrl-C (SIGINT), as shells report it (128 + 2)."""


def _run(args: list[str]) -> int:
    """Parse and run one command line (`--version` without typer)."""
    if args == ["--version"]:
        from accellog.core.version import __version__

        print(f"accellog {__version__}")
        return 0
    early.start_helpers(args)  # before typer and the command's imports: theirs run beside them
    from accellog.cli.app import command_group

    if "--show-completion" in args or "--install-completion" in args:
        _shell_from_env_when_undetected()
    if os.environ.get("ACCELLOG_RRD_FULL", "").strip().lower() in ("1", "true", "yes"):
        from accellog.present.rrd.recording import RunRecording  # every .rrd at the full rate

        RunRecording.DEFAULT_FULL_RATE = True
    rc = command_group()(args=args, prog_name="accellog", standalone_mode=False)
    if rc == INTERRUPTED:  # typer >= 0.29 turns Ctrl-C into a silent Exit(130)
        print("accellog: interrupted", file=sys.stderr)
    return rc if isinstance(rc, int) else 0


def _shell_from_env_when_undetected() -> None:
    """typer finds the shell from the parent processes (shellingham); where they do not tell (no
    terminal, a job runner), the login shell in $SHELL is used instead of failing."""
    from typer import _completion_shared, completion

    found = _completion_shared._get_shell_name

    def shell_name() -> str | None:
        name = found()
        env = os.path.basename(os.environ.get("SHELL", ""))
        return name or (env if env in {s.value for s in _completion_shared.Shells} else None)

    _completion_shared._get_shell_name = completion._get_shell_name = shell_name


def _exit_code(exc: Exception) -> int | None:
    """One stderr line and the exit code for an exception a command let through, None to re-raise."""
    typer = sys.modules.get("typer")  # not loaded: the exception is not one of typer's
    if isinstance(exc, AccellogError):
        print(f"accellog: error: {exc}", file=sys.stderr)
        return exc.exit_code
    if typer is not None and isinstance(exc, typer.Abort):
        print("accellog: interrupted", file=sys.stderr)
        return INTERRUPTED
    if typer is not None and isinstance(exc, typer.Exit):
        return int(exc.exit_code)
    if isinstance(exc, OSError):  # a file system problem the command did not foresee: still one line
        where = exc.filename if exc.filename is not None else "file system"
        print(f"accellog: error: {where}: {exc.strerror or exc.__class__.__name__}", file=sys.stderr)
        return 2
    # typer bundles its own click: usage errors carry format_message() and exit_code; they are
    # one line too (the command and the message; `--help` shows the usage).
    code = getattr(exc, "exit_code", None)
    if hasattr(exc, "format_message") and isinstance(code, int):
        ctx = getattr(exc, "ctx", None)
        path = ctx.command_path if ctx is not None else None
        print(_usage_error_line(path, str(exc.format_message())), file=sys.stderr)
        return code
    return None


def main(argv: list[str] | None = None) -> int:
    """Entry point: runs the app; input errors become one line on stderr and a non-zero exit;
    data-integrity warnings (a damaged chunk skipped) one 'accellog: warning:' line each, notes
    (e.g. what was recovered from a truncated file) one 'accellog: note:' line each."""
    notices.take()  # notes of an earlier in-process call are not this command's
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        with warnings.catch_warnings(), _one_blas_thread(), _busy(args), forked.allowed():
            warnings.simplefilter("always", DataIntegrityWarning)
            warnings.showwarning = _integrity_line
            rc = _run(args)
        for text in notices.take():
            print(f"accellog: note: {text}", file=sys.stderr)
    except KeyboardInterrupt:
        print("accellog: interrupted", file=sys.stderr)
        return INTERRUPTED
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except Exception as exc:
        code = _exit_code(exc)
        if code is None:
            raise
        return code
    finally:
        _stop_unclaimed_writer()
    return rc


def _stop_unclaimed_writer() -> None:
    """A .rrd writer child the command started but did not use (it failed first) ends with it."""
    process = sys.modules.get("accellog.present.rrd.offload_process")
    if process is not None:
        process.stop_unclaimed()


def console() -> None:
    """The `accellog` script: main() for this process's command line, then exit. The objects alive
    are frozen out of the cyclic collector (gc.freeze) after `import rerun` and before exiting:
    interpreter shutdown then skips scanning the modules' objects (0.2 s of CPU after a 1 h
    `replay --rrd`: rerun's ~60,000 objects); the process ends with the command, so nothing leaks."""
    from accellog.present.rrd import sdk

    sdk.FREEZE_AFTER_IMPORT = True  # this process ends with the command
    rc = main()
    gc.freeze()
    sys.exit(rc)


if __name__ == "__main__":  # pragma: no cover
    console()
