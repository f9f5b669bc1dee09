"""Give freed heap memory back to the OS during long streamed passes (and set glibc's thresholds).

A streamed pass allocates and frees arrays of varying sizes for every block (~1-3 MB each). glibc
keeps the freed pages in its arenas, which fragment, so the resident set creeps up with the
length of the session although the live data do not: +15-20 MB over a 24 h recorder-layout pass
(0.5 s chunks), while the traced Python memory stays flat. ``HeapTrim`` calls glibc's
``malloc_trim(0)``, which returns every whole free page of every arena (``MADV_DONTNEED``), but
only once the anonymous resident memory has grown by ``slack_mb`` past the mark it learned: a trim
costs page faults when the pages are used again (every block: 2x the system time of a pass; a
24 h pass: 15-70 trims, +0.3-1 s of 13 s CPU, peak 84-86 MB where it was 84-94). Without glibc or
/proc it does nothing.
"""

from __future__ import annotations

import ctypes
import os

_PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20 if hasattr(os, "sysconf") else 0.0


def _malloc_trim():
    """glibc's malloc_trim, or None."""
    try:
        trim = ctypes.CDLL(None).malloc_trim  # the process's own symbols (find_library runs ldconfig)
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


_TRIM = _malloc_trim()


def trim_heap() -> None:
    """malloc_trim(0) now (glibc; a no-op elsewhere), ~1 ms: between the stages of a long run. After
    a large block is freed glibc raises its mmap threshold, so later arrays come from the heap and
    its free pages stay resident: without a trim after a hold, a pass or a candidate fit, peak memory
    grew with the number of holds and candidates (24 h session: benchmarks/README.md)."""
    if _TRIM is not None:
        _TRIM(0)


def set_malloc_thresholds(trim_bytes: int, mmap_bytes: int) -> bool:
    """glibc's ``mallopt`` M_TRIM_THRESHOLD and M_MMAP_THRESHOLD for this process and the processes
    forked from it (what the MALLOC_TRIM_THRESHOLD_ / MALLOC_MMAP_THRESHOLD_ environment variables set
    at a process's start); False without glibc."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(-1, int(trim_bytes))) and bool(mallopt(-3, int(mmap_bytes)))  # M_TRIM_, M_MMAP_


def anon_rss_mb() -> float | None:
    """Resident anonymous memory of this process (MB: resident less file-backed pages), or None."""
    try:
        with open("/proc/self/statm", "rb") as f:
            fields = f.read().split()
    except OSError:
        return None
    return (int(fields[1]) - int(fields[2])) * _PAGE_MB


class HeapTrim:
    """Call once per block. The first ``warmup`` calls learn the pass's high-water mark of anon RSS;
    afterwards the heap is trimmed whenever RSS exceeds it by slack_mb. A trim that does not bring
    RSS back under the mark (live data grew) moves the mark up to the RSS it left."""

    def __init__(self, slack_mb: float = 8.0, warmup: int = 16):
        self.slack_mb = slack_mb
        self.warmup = warmup
        self.trims = 0
        self._calls = 0
        self._mark_mb = anon_rss_mb() if _TRIM is not None else None

    def __call__(self) -> None:
        if self._mark_mb is None:
            return
        rss = anon_rss_mb()
        if rss is None:
            return
        self._calls += 1
        if self._calls <= self.warmup:
            self._mark_mb = max(self._mark_mb, rss)
            return
        if rss <= self._mark_mb + self.slack_mb:
            return
        _TRIM(0)
        self.trims += 1
        self._mark_mb = max(self._mark_mb, anon_rss_mb() or rss)
