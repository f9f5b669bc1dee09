"""Give the C heap's free pages back to the system between the stages of a long run.

An array freed by numpy goes back to glibc's heap, not to the system; after a large block is
freed glibc raises its mmap threshold, so later arrays are served from the heap and its free pages
stay resident (counted in peak memory). ``trim_heap`` (glibc ``malloc_trim(0)``, every arena) after
a hold, a pass or a candidate fit keeps the resident size to what is in use: without it peak
memory grew with the number of holds and candidates (24 h session: see benchmarks/README.md).
"""

from __future__ import annotations

_LIBC = None


def trim_heap() -> None:
    """malloc_trim(0) on glibc (a no-op elsewhere); ~1 ms."""
    global _LIBC
    if _LIBC is None:
        import ctypes
        import ctypes.util

        name = ctypes.util.find_library("c")
        lib = ctypes.CDLL(name) if name else None
        _LIBC = lib if lib is not None and hasattr(lib, "malloc_trim") else False
    if _LIBC:
        _LIBC.malloc_trim(0)
