"""The zstd level of the chunks accellog writes (mcap's Writer has no setting for it)."""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator

import mcap.writer
import zstandard

ZSTD_LEVEL = 2
"""zstd level of the chunks accellog writes: 0.75x the CPU of zstd's default level 3 on a recording
(counts; 1.2 % larger) and 0.64x on a CSV import (float64 values; 8 % larger) (python
benchmarks/bench_zstd_level.py): `import csv` of 4 h at 1 kHz takes 9.8-9.9 s instead of 11.0-11.5 s
(2 interleaved runs each, the file 466 MB instead of 425 MB)."""

_LEVEL: contextvars.ContextVar[int | None] = contextvars.ContextVar("accellog_zstd_level", default=None)


class _ChunkZstd:
    """Stands in for the zstandard module inside mcap.writer: its Writer (mcap 1.6) compresses every
    chunk with ``zstandard.compress(data)`` at zstd's default level and has no setting for the level.
    compress() uses the level a SessionWriter call set (``at_level``) and zstd's default for any
    other caller (an mcap Writer outside accellog writes what it wrote before); every other name is
    zstandard's."""

    def __getattr__(self, name: str):
        return getattr(zstandard, name)

    @staticmethod
    def compress(data, level: int | None = None) -> bytes:
        level = _LEVEL.get() if level is None else level
        return zstandard.compress(data) if level is None else zstandard.compress(data, level)


if getattr(mcap.writer, "zstandard", None) is zstandard:
    # a module-typed global replaced by an object that answers the same calls (class docstring)
    mcap.writer.zstandard = _ChunkZstd()  # type: ignore[assignment]


@contextlib.contextmanager
def at_level(level: int) -> Iterator[None]:
    """Chunks finished inside are compressed at zstd level ``level`` (see _ChunkZstd)."""
    token = _LEVEL.set(level)
    try:
        yield
    finally:
        _LEVEL.reset(token)
