"""The door for numbers on the command line: checked once, for every command, before it runs.

Every float option must be finite (NaN and inf are refused: ``--hold inf`` would never end, ``--trim-s
nan`` means nothing), and the options in ``OPTION_RANGES`` must lie in their physical range, e.g.
``--seed`` >= 0, ``--local-gravity`` within 9.7-9.9 m/s^2 (a gravity on Earth: every calibration
loader refuses another one). The limits that depend on the data (a window of at least 10 samples) are
checked where the data is read. ``guard_options`` wraps each command of a click group so that a bad
value is one InputError naming the option, before any file is opened, and so that its paths pass
``accellog.cli.path_checks`` (outputs never over an input or a device) before it runs.
"""

from __future__ import annotations

import functools
from typing import Any

from accellog.core.ranges import OPTION_RANGES, check_option

__all__ = ["OPTION_RANGES", "check_option", "guard_options"]


def _option_names(cmd: Any) -> dict[str, str]:
    """Parameter name -> its longest spelling (--window-s) for the options of a click command."""
    out = {}
    for p in getattr(cmd, "params", []):
        opts = [o for o in getattr(p, "opts", []) if o.startswith("-")]
        if p.name and opts:
            out[p.name] = max(opts, key=len)
    return out


def _guard_command(cmd: Any) -> None:
    callback = getattr(cmd, "callback", None)
    if callback is None or getattr(callback, "_options_checked", False):
        return
    names = _option_names(cmd)
    command = f"{callback.__module__}.{callback.__name__}"

    @functools.wraps(callback)
    def checked(*args: Any, **kwargs: Any) -> Any:
        from accellog.cli.path_checks import check_paths
        from accellog.store.atomic import declared_inputs

        for name, value in kwargs.items():
            if name in names:
                check_option(names[name], value)
        with declared_inputs(check_paths(command, names, kwargs)):
            return callback(*args, **kwargs)

    checked._options_checked = True  # type: ignore[attr-defined]
    cmd.callback = checked


def guard_options(group: Any) -> Any:
    """Wrap every command of a click group (sub-groups too) with the option checks and the path
    checks (accellog.cli.path_checks); returns the group."""
    commands = getattr(group, "commands", None)
    if commands is None:
        _guard_command(group)
        return group
    for cmd in commands.values():
        guard_options(cmd)
    return group
