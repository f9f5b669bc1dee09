"""Vectorised reads of bytes at arbitrary offsets of a uint8 buffer (the fast MCAP read-back)."""

from __future__ import annotations

import numpy as np


def byte_window(buf: np.ndarray, width: int) -> np.ndarray:
    """Overlapping (len(buf) - width + 1, width) uint8 view of ``buf``: row i is buf[i : i + width].

    Fancy-indexing its rows with byte offsets gathers ``width``-byte records at arbitrary (unaligned)
    offsets in one C loop, without copying ``buf``.
    """
    return np.lib.stride_tricks.as_strided(buf, shape=(buf.shape[0] - width + 1, width), strides=(1, 1))


def void_window(buf: np.ndarray, width: int) -> np.ndarray:
    """``byte_window`` as ``width``-byte void items: fancy-indexing it copies each record with one
    memcpy (byte_window rows are copied byte by byte: ~1.7x slower for message-sized records)."""
    return np.ndarray((buf.shape[0] - width + 1,), np.dtype(f"V{width}"), buf, 0, (1,))


def read_le(buf: np.ndarray, offsets: np.ndarray, dtype: str | np.dtype) -> np.ndarray:
    """Little-endian values of ``dtype`` (e.g. '<u8') stored at the byte ``offsets`` of uint8 ``buf``."""
    dt = np.dtype(dtype)
    if offsets.shape[0] == 0:
        return np.empty(0, dt)
    return byte_window(buf, dt.itemsize)[offsets].view(dt)[:, 0]
