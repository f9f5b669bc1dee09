"""Deprecated path of the effects-file API: use ``from accellog import Effect, per_axis``.

Effects files written from the first docs (``from accellog.effects import Effect, per_axis``) keep
loading; importing this module warns once (DeprecationWarning) and gives the same objects.
"""

from __future__ import annotations

import warnings

from accellog.calibrate.model.effects import Effect, Param, per_axis

__all__ = ["Effect", "Param", "per_axis"]

warnings.warn(
    "accellog.effects is deprecated: use `from accellog import Effect, per_axis`",
    DeprecationWarning,
    stacklevel=2,
)
