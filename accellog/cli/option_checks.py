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
import math
from typing import Any

from accellog.core.errors import InputError
from accellog.core.units import EARTH_GRAVITY_RANGE_MPS2

_DAY_S = 86400.0
_BIG = float(2**63 - 1)

OPTION_RANGES: dict[str, tuple[float, float, bool, str]] = {
    # option: (lo, hi, lo excluded, unit); hi always included
    "--seed": (0, _BIG, False, ""),
    "--chip-seed": (0, _BIG, False, ""),
    "--fleet": (1, 10_000, False, "devices"),
    "--fleet-sessions": (1, 1_000, False, "sessions"),
    "--jobs": (1, 256, False, "processes"),
    "--workers": (0, 256, False, "processes (0: the serial loop, no Dask)"),
    "--batch-size": (1, 1_000_000, False, "samples"),
    "--max-samples": (1, _BIG, False, "samples"),
    "--max-steps": (0, 100, False, "steps"),
    "--width": (100, 10_000, False, "px"),
    "--height": (100, 10_000, False, "px"),
    "--bus": (0, 1_024, False, ""),
    "--hold": (0, _DAY_S, True, "s"),
    "--window-s": (0, 3_600, True, "s"),
    "--detect-window-s": (0, 3_600, True, "s"),
    "--trim-s": (0, 3_600, False, "s"),
    "--until-s": (0, _BIG, True, "s"),
    "--at-s": (0, _BIG, True, "s"),
    "--wait-s": (0, _DAY_S, False, "s"),
    "--local-gravity": (*EARTH_GRAVITY_RANGE_MPS2, False, "m/s^2 (a gravity on Earth)"),
    "--gravity-g": (0.98, 1.02, False, "g"),
    "--field-uT": (0, 1_000, True, "uT"),
    "--lsb-per-g": (0, 1e6, True, "counts/g"),
    "--accel-scale": (0, 1e3, True, ""),
    "--gyro-lsb-per-dps": (0, 1e6, True, "counts/(deg/s)"),
    "--k-sigma": (0, 1_000, True, "sigma"),
    "--threshold": (0, _BIG, True, ""),
}


def check_option(opt: str, value: Any) -> None:
    """InputError naming `opt` when a numeric value is not finite or outside OPTION_RANGES[opt]."""
    if isinstance(value, (list, tuple)):
        for v in value:
            check_option(opt, v)
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if isinstance(value, float) and not math.isfinite(value):
        raise InputError(f"{value} is not a finite number", where=opt)
    if opt not in OPTION_RANGES:
        return
    lo, hi, lo_open, unit = OPTION_RANGES[opt]
    if value < lo or (lo_open and value == lo) or value > hi:
        low = f"> {lo:g}" if lo_open else f">= {lo:g}"
        high = f" and <= {hi:g}"
        raise InputError(f"{value:g} is out of range: must be {low}{high} {unit}".rstrip(), where=opt)


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
