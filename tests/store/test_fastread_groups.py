"""fastread._groups (vectorised, #11) cuts chunk runs exactly as the greedy rule in its docstring."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from accellog.store.mcap import fastread


def _greedy(sizes: list[int], whole: bool) -> list[tuple[int, int]]:
    """The rule one chunk at a time: a run ends before the chunk that takes it past the cap once
    it holds bytes; a whole read's cap is _WHOLE_GROUPS times larger, its first cap is 1/8 and the
    tail (<= 1/8) is split off; a whole read of at most 1/8 is one group."""
    big = fastread._GROUP_BYTES * (fastread._WHOLE_GROUPS if whole else 1)
    small = big // 8 if whole else big
    if whole and sizes and sum(sizes) <= small:
        return [(0, len(sizes))]
    bounds, total, cap = [0], 0, small
    for i, u in enumerate(sizes):
        if total and total + u > cap:
            bounds.append(i)
            total, cap = 0, big
        total += u
    last, total = len(sizes), 0
    while whole and last - 1 > bounds[-1] and total + sizes[last - 1] <= small:
        last -= 1
        total += sizes[last]
    if bounds[-1] < last < len(sizes):
        bounds.append(last)
    bounds.append(len(sizes))
    return list(itertools.pairwise(bounds))


@pytest.mark.parametrize("whole", [True, False])
def test_groups_equal_the_greedy_rule(whole):
    rng = np.random.default_rng(11)
    big = fastread._GROUP_BYTES
    for t in range(3000):
        n = int(rng.integers(0, 60))
        high = (big // 3, 2 * big, big, big // 40)[t % 4]  # large, oversized, gappy, recorder-like
        usize = rng.integers(0, high, n).astype(np.int64)
        if t % 4 == 2:
            usize[rng.random(n) < 0.5] = 0  # chunks left out of a read
        assert fastread._groups(usize, whole) == _greedy(usize.tolist(), whole), usize.tolist()
