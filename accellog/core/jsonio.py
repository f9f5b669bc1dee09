"""Strict JSON for every result and artifact: numpy arrays as lists, NaN/inf as null.

Every typed result has ``to_dict()`` (the documented --json keys); ``JsonResult.to_json()`` is that dict
as strict JSON text.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def dumps(data: Any, indent: int | None = 2) -> str:
    """JSON text; NaN/inf become null (strict JSON)."""

    def clean(x: Any) -> Any:
        if isinstance(x, float):
            return x if np.isfinite(x) else None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if isinstance(x, np.ndarray):
            return clean(x.tolist())
        if isinstance(x, np.generic):
            return clean(x.item())
        return x

    return json.dumps(clean(data), indent=indent, default=_json_default, allow_nan=False)


class JsonResult:
    """Mixin: ``to_json()`` = strict JSON of ``to_dict()``."""

    def to_dict(self) -> dict:  # pragma: no cover - every result defines it
        raise NotImplementedError

    def to_json(self, indent: int | None = 2) -> str:
        return dumps(self.to_dict(), indent=indent)
