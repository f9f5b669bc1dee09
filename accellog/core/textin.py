"""Small text inputs (JSON, TOML) read with bounded time and memory, every failure one InputError.

- the file's size is checked against its kind's limit before a byte is read (``MAX_BYTES``: a
  calibration, observation table or artifact is JSON of at most 32 MiB; a scenario or pipeline is
  TOML of at most 1 MiB), so a 2 GB file is refused at once; JSON with more than MAX_CONTAINERS
  arrays and objects is refused before parsing (``[[],[],...]`` would take ~60 bytes of memory per
  2 bytes of text), so that the parsed value stays within a few hundred MB;
- JSON is strict: NaN and Infinity are not JSON (the writers of accellog never produce them);
- nesting deeper than ``MAX_DEPTH`` levels (no accellog file nests beyond ~6) is refused after
  parsing, and a parser's RecursionError on deeper input becomes the same one line.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import tomllib

from accellog.core.errors import InputError

MiB = 1024 * 1024
MAX_BYTES = {"JSON": 32 * MiB, "TOML": 1 * MiB}
MAX_DEPTH = 64
MAX_CONTAINERS = 1_000_000
"""Arrays + objects in one JSON text (an observation table of 24 h in 2 s windows has ~0.2 M)."""


def check_size(path: str | os.PathLike, kind: str, what: str = "file") -> None:
    """InputError naming the file when it is larger than MAX_BYTES[kind] (checked without reading)."""
    p = Path(path)
    try:
        size = p.stat().st_size
    except FileNotFoundError:
        raise InputError(f"no such {what}", where=str(p)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc.__class__.__name__}", where=str(p)) from None
    limit = MAX_BYTES[kind]
    if size > limit:
        raise InputError(
            f"{what} is {size / MiB:,.1f} MiB; a {kind} input is at most {limit // MiB} MiB (not read)",
            where=str(p),
        )


def read_text(path: str | os.PathLike, what: str = "file", kind: str | None = None) -> str:
    """The text of a file (size-checked first when `kind` is given), or InputError naming it when
    it is missing, too large or not text."""
    p = Path(path)
    if kind is not None:
        check_size(p, kind, what)
    try:
        return p.read_text()
    except FileNotFoundError:
        raise InputError(f"no such {what}", where=str(p)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read as text: {exc.__class__.__name__}", where=str(p)) from None


def nesting_depth(value: Any, limit: int = MAX_DEPTH) -> int:
    """Depth of nested lists / dicts in value (iterative; stops counting past `limit`)."""
    if not isinstance(value, (dict, list)):
        return 0
    deepest, stack = 0, [(value, 1)]
    while stack:  # only containers are stacked: a list of 8 M numbers costs nothing here
        v, d = stack.pop()
        deepest = max(deepest, d)
        if d > limit:
            return d
        items = v.values() if isinstance(v, dict) else v
        stack.extend((e, d + 1) for e in items if isinstance(e, (dict, list)))
    return deepest


def _check_depth(value: Any, kind: str, where: str) -> Any:
    if nesting_depth(value) > MAX_DEPTH:
        raise InputError(f"{kind} nested deeper than {MAX_DEPTH} levels", where=where)
    return value


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON (strict JSON has no NaN or Infinity)")


def parse_json(text: str, where: str) -> Any:
    """Strict JSON (no NaN / Infinity, nesting <= MAX_DEPTH); InputError naming where (and line)."""
    containers = text.count("[") + text.count("{")
    if containers > MAX_CONTAINERS:
        raise InputError(f"JSON with {containers:,} arrays/objects (at most {MAX_CONTAINERS:,})", where=where)
    try:
        value = json.loads(text, parse_constant=_no_constant)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"not valid JSON: {exc.msg} (column {exc.colno})", where=f"{where}:{exc.lineno}"
        ) from None
    except ValueError as exc:
        raise InputError(f"not valid JSON: {exc}", where=where) from None
    except RecursionError:
        raise InputError(f"JSON nested deeper than {MAX_DEPTH} levels", where=where) from None
    return _check_depth(value, "JSON", where)


def read_json(path: str | os.PathLike, what: str = "file") -> Any:
    """Parsed JSON of a file of at most MAX_BYTES['JSON']; InputError naming the file (and line)."""
    return parse_json(read_text(path, what, kind="JSON"), str(path))


def toml_loads(text: str, where: str) -> dict:
    """tomllib.loads (its TOMLDecodeError passes through for the caller's message) with deep
    nesting as one InputError."""
    try:
        value = tomllib.loads(text)
    except RecursionError:
        raise InputError(f"TOML nested deeper than {MAX_DEPTH} levels", where=where) from None
    return _check_depth(value, "TOML", where)
