"""`accellog` command line: one module per group of commands, all registered on one typer app."""

from __future__ import annotations

import importlib
import pkgutil
import sys

from ..errors import AccellogError
from .app import app

# Every module in this package registers its commands on `app` when imported.
for _mod in pkgutil.iter_modules(__path__):
    if _mod.name != "app":
        importlib.import_module(f"{__name__}.{_mod.name}")


def main(argv: list[str] | None = None) -> int:
    """Entry point: runs the app; input errors become one line on stderr and a non-zero exit."""
    try:
        rc = app(args=argv, prog_name="accellog", standalone_mode=False)
    except AccellogError as exc:
        print(f"accellog: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("accellog: interrupted", file=sys.stderr)
        return 130
    except SystemExit as exc:  # typer/click exits (help, usage errors)
        return int(exc.code or 0) if not isinstance(exc.code, str) else 1
    except Exception as exc:  # click usage errors carry their own formatting
        import click

        if isinstance(exc, click.exceptions.ClickException):
            exc.show()
            return exc.exit_code
        if isinstance(exc, click.exceptions.Abort):
            print("accellog: aborted", file=sys.stderr)
            return 1
        raise
    return rc if isinstance(rc, int) else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
