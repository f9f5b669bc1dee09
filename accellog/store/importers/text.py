"""Line-numbered CSV parsing shared by the importers: fast parse, exact line diagnosis only when something is wrong."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.protocol import pose_spec
from accellog.core.session import PoseLabel

# ---------------------------------------------------------------------------------------------
# CSV helpers: fast parse with pyarrow, exact line diagnosis in Python only when something is wrong


SNIFF_BYTES = 1024
MAX_WHOLE_TEXT_BYTES = 16 * 1024 * 1024
"""Largest text file read whole (capstone, imucal); any logger's CSV is streamed instead."""


def check_text_file(path: Path) -> None:
    """InputError within the first SNIFF_BYTES when `path` is not a text file at all: a NUL byte
    (binary, zero-filled) or bytes that are not UTF-8 (a character cut at the end is allowed)."""
    if not path.is_file():
        raise InputError("no such file", where=str(path))
    with open(path, "rb") as f:
        head = f.read(SNIFF_BYTES)
    nul = head.find(b"\0")
    if nul >= 0:
        raise InputError(
            f"not a CSV (text) file: a NUL byte at offset {nul} (binary or zero-filled)", where=str(path)
        )
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as exc:
        if exc.start < len(head) - 3:
            raise InputError(
                f"not a CSV (text) file: bytes that are not UTF-8 at offset {exc.start}", where=str(path)
            ) from None


def read_lines(path: Path) -> list[str]:
    check_text_file(path)
    size = path.stat().st_size
    if size > MAX_WHOLE_TEXT_BYTES:
        raise InputError(
            f"{size / 2**20:,.0f} MiB is too large for this importer (at most {MAX_WHOLE_TEXT_BYTES >> 20} MiB); "
            "`accellog import csv` streams any size",
            where=str(path),
        )
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError:
        raise InputError("not a text (UTF-8) CSV file", where=str(path)) from None


def diagnose(path: Path, lines: list[str], first: int, names: list[str], strings=(), optional=()) -> None:
    """Raise InputError at the first bad data line (1-based numbering; data starts at line ``first``)."""
    for no, line in enumerate(lines[first - 1 :], start=first):
        if not line.strip():
            continue
        parts = line.split(",")
        if len(parts) != len(names):
            raise InputError(
                f"expected {len(names)} columns ({','.join(names)}), found {len(parts)}", where=f"{path}:{no}"
            )
        for name, v in zip(names, parts, strict=True):
            v = v.strip()
            if name in strings:
                continue
            if v == "":
                if name in optional:
                    continue
                raise InputError(f"empty value in column {name!r}", where=f"{path}:{no}")
            try:
                x = float(v)
            except ValueError:
                raise InputError(f"column {name!r}: {v!r} is not a number", where=f"{path}:{no}") from None
            if not math.isfinite(x):
                raise InputError(f"column {name!r}: {v!r} is not a finite number", where=f"{path}:{no}")


def line_of_row(lines: list[str], first: int, row: int) -> int:
    """1-based line number of data row ``row`` (blank lines are skipped by the parser)."""
    k = -1
    for no, line in enumerate(lines[first - 1 :], start=first):
        if line.strip():
            k += 1
            if k == row:
                return no
    return len(lines)


def read_table(
    path: Path, lines: list[str], first: int, names: list[str], strings=(), optional=()
) -> dict[str, np.ndarray]:
    """Columns of the data lines from ``first`` on: float64 (NaN where an optional value is empty), str."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    if not any(line.strip() for line in lines[first - 1 :]):
        raise InputError("no data rows", where=str(path))
    types = {n: (pa.string() if n in strings else pa.float64()) for n in names}
    try:
        table = pacsv.read_csv(
            path,
            read_options=pacsv.ReadOptions(skip_rows=first - 1, column_names=names, encoding="utf8"),
            convert_options=pacsv.ConvertOptions(
                column_types=types, strings_can_be_null=False, null_values=[""]
            ),
        )
    except (pa.ArrowInvalid, UnicodeDecodeError) as exc:
        diagnose(path, lines, first, names, strings, optional)
        raise InputError(f"cannot parse CSV: {str(exc).splitlines()[0]}", where=str(path)) from None
    out: dict[str, np.ndarray] = {}
    bad = False
    for n in names:
        col = table.column(n)
        if n in strings:
            out[n] = np.asarray(col.to_pylist(), dtype=object)
            continue
        arr = col.to_numpy(zero_copy_only=False).astype(np.float64, copy=False)
        null = np.asarray(col.is_null().to_numpy(zero_copy_only=False), dtype=bool)
        if (null.any() and n not in optional) or (~np.isfinite(arr) & ~null).any():
            bad = True
        out[n] = np.where(null, np.nan, arr)
    if bad:
        diagnose(path, lines, first, names, strings, optional)
    return out


def check_time(path: Path, lines: list[str], first: int, t: np.ndarray) -> None:
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        no = line_of_row(lines, first, i)
        raise InputError(f"time goes backwards ({t[i - 1]:.9g} s -> {t[i]:.9g} s)", where=f"{path}:{no}")


def hold_end(t: np.ndarray, end_row: int) -> float:
    """End (exclusive) of a hold ending before row end_row: that row's time, or one median dt past the end."""
    if end_row < t.shape[0]:
        return float(t[end_row])
    dt = float(np.median(np.diff(t))) if t.shape[0] > 1 else 0.0
    return float(t[-1]) + dt


def rate_hz(t: np.ndarray) -> float:
    if t.shape[0] < 2:
        return 0.0
    dt = float(np.median(np.diff(t)))
    return 1.0 / dt if dt > 0 else 0.0


def face_label(name: str, start_s: float, end_s: float, hold_index: int) -> PoseLabel:
    spec = pose_spec(name, end_s - start_s)
    return PoseLabel(name, start_s, end_s, spec.up_sensor, spec.q_sensor_to_world, hold_index)
