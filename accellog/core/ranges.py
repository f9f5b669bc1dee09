"""The physical range of every numeric setting that has one, by its command-line spelling
(``OPTION_RANGES``), and the check (``check_option``): the command line's door
(``accellog.cli.option_checks``) and the pipeline file's (``accellog.flows.pipeline``, a key such as
``segment.window_s`` is held to ``--window-s``) use the same limits."""

from __future__ import annotations

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
    "--device-id": (-(2**31), 2**32 - 1, False, "(a 32-bit id: as PX4/ArduPilot store it, int32 or uint32)"),
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
