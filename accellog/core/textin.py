"""Small text inputs (JSON, TOML, Python) read with bounded time and memory, every failure one
InputError. ``read_bytes`` is the one door; ``read_text`` and ``read_json`` go through it.

- only a regular file is read: a FIFO, a device (/dev/zero, /dev/urandom), a socket or a directory
  is refused at once (opened without blocking, checked by fstat on the opened file, so a link or a
  swap between check and read changes nothing);
- the file's size is checked against its kind's limit before a byte is read (``MAX_BYTES``: a
  calibration, observation table or artifact is JSON of at most 32 MiB; a scenario or pipeline is
  TOML of at most 1 MiB, an effects file Python and a bag's metadata.yaml at most 1 MiB), so a 2 GB file is refused at
  once, and at most the limit is read even if the file grows meanwhile; JSON with more than MAX_CONTAINERS
  arrays and objects is refused before parsing (``[[],[],...]`` would take ~60 bytes of memory per
  2 bytes of text), so that the parsed value stays within a few hundred MB;
- JSON is strict: NaN and Infinity are not JSON (the writers of accellog never produce them);
- nesting deeper than ``MAX_DEPTH`` levels (no accellog file nests beyond ~6) is refused after
  parsing, and a parser's RecursionError on deeper input becomes the same one line.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any

import tomllib

from accellog.core.errors import InputError

MiB = 1024 * 1024
MAX_BYTES = {"JSON": 32 * MiB, "TOML": 1 * MiB, "Python": 1 * MiB, "YAML": 1 * MiB}
MAX_DEPTH = 64
MAX_CONTAINERS = 1_000_000
"""Arrays + objects in one JSON text (an observation table of 24 h in 2 s windows has ~0.2 M)."""


_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
)


BINARY_KINDS = (
    (b"\x89MCAP", "an MCAP file (a session or a ROS 2 bag)"),
    (b"RRF", "a Rerun recording (.rrd)"),
    (b"ULog", "a PX4 ULog"),
    (b"\xa3\x95", "an ArduPilot DataFlash log"),
    (b"\x89PNG", "a PNG image"),
    (b"PK\x03\x04", "a zip archive"),
    (b"\x1f\x8b", "a gzip file"),
    (b"\x28\xb5\x2f\xfd", "a zstd file"),
)
"""Leading bytes of binary files a user may pass where text is read (arguments swapped)."""

ACCELLOG_JSON = {
    "accellog.calibration": "an accellog calibration (written by `accellog fit -o`)",
    "accellog.observations": "an accellog observation table (written by `accellog segment -o`)",
}
"""What each accellog JSON file is, by its "format" field (named when the wrong one is passed)."""


def binary_kind(head: bytes) -> str | None:
    """What a binary file is by its leading bytes (BINARY_KINDS), None when unknown."""
    return next((name for magic, name in BINARY_KINDS if head.startswith(magic)), None)


def json_kind(value: Any) -> str | None:
    """What an accellog JSON document is by its "format" field (ACCELLOG_JSON), None otherwise."""
    fmt = value.get("format") if isinstance(value, dict) else None
    return ACCELLOG_JSON.get(fmt) if isinstance(fmt, str) else None


def file_kind(mode: int) -> str | None:
    """None for a regular file's st_mode, else what it is: 'a directory', 'a character device', ..."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def read_bytes(path: str | os.PathLike, what: str = "file", kind: str | None = None) -> bytes:
    """The bytes of a regular file (at most MAX_BYTES[kind] with `kind`), or InputError naming it
    when it is missing, not a regular file, too large or unreadable."""
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)  # a FIFO without a writer must not block the open
    except FileNotFoundError:
        raise InputError(f"no such {what}", where=str(p)) from None
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc.__class__.__name__}", where=str(p)) from None
    try:
        st = os.fstat(fd)
        found = file_kind(st.st_mode)
        if found is not None:
            raise InputError(f"{what} is {found}, not a regular file (not read)", where=str(p))
        limit = MAX_BYTES[kind] if kind is not None else None
        if limit is not None and st.st_size > limit:
            raise InputError(
                f"{what} is {st.st_size / MiB:,.1f} MiB; a {kind} input is at most {limit // MiB} MiB (not read)",
                where=str(p),
            )
        with os.fdopen(os.dup(fd), "rb") as f:
            data = f.read(-1 if limit is None else limit + 1)
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror or exc.__class__.__name__}", where=str(p)) from None
    finally:
        os.close(fd)
    if limit is not None and len(data) > limit:
        raise InputError(f"{what} grew beyond {limit // MiB} MiB while read (not read)", where=str(p))
    return data


def read_text(path: str | os.PathLike, what: str = "file", kind: str | None = None) -> str:
    """The UTF-8 text of a regular file (read_bytes: bounded by `kind`), or InputError naming it
    when it is missing, not a regular file, too large or not text."""
    data = read_bytes(path, what, kind)
    try:
        return data.decode()
    except UnicodeDecodeError:
        found = binary_kind(data)
        if found is not None:
            raise InputError(
                f"this is {found}, not a {what}: are the arguments swapped?",
                where=str(path),
            ) from None
        raise InputError(f"not UTF-8 text, so not a {what}", where=str(path)) from None


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
