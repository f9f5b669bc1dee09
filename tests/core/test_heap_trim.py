"""core.heap.HeapTrim: freed heap pages are given back once RSS passes the learned mark (#11)."""

from __future__ import annotations

import numpy as np
import pytest

from accellog.core import heap

pytestmark = pytest.mark.skipif(
    heap._TRIM is None or heap.anon_rss_mb() is None, reason="needs glibc malloc_trim and /proc"
)


def _fragment(mb: int) -> list[np.ndarray]:
    """Allocate mb MB in 64 kB arrays (below glibc's mmap threshold: on the heap), free every other
    one: the freed half stays in the heap as holes between live arrays."""
    arrays = [np.ones(8192) for _ in range(mb * 16)]
    return arrays[::2]


def test_trims_fragmented_heap_once_past_the_mark():
    trim = heap.HeapTrim(slack_mb=4.0, warmup=1)
    trim()  # learns the mark
    keep = _fragment(160)
    before = heap.anon_rss_mb()
    trim()
    assert trim.trims == 1
    assert heap.anon_rss_mb() < before - 40  # ~80 MB of freed holes, most of them whole pages
    trim()  # back under mark + slack: no second trim
    assert trim.trims == 1
    del keep


def test_no_trim_within_slack_or_during_warmup():
    trim = heap.HeapTrim(slack_mb=1000.0, warmup=2)
    keep = _fragment(40)
    trim(), trim(), trim()
    assert trim.trims == 0
    del keep
