"""Batches of sessions per Dask task (accellog.flows.fleet_dask.batches): every session once, in
order; no batch over the byte limit (unless one file is); batches shrink towards the end so the
workers finish together."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from accellog.flows.fleet_dask import MAX_BATCH_BYTES, batches


@given(st.lists(st.integers(0, 3 * MAX_BATCH_BYTES), max_size=300), st.integers(1, 64))
def test_batches_cover_every_session_once_in_order(sizes, workers):
    parts = batches(sizes, workers)
    assert [i for p in parts for i in p] == list(range(len(sizes)))
    assert all(len(p) >= 1 for p in parts)
    for p in parts:
        assert len(p) == 1 or sum(sizes[i] for i in p) <= MAX_BATCH_BYTES


@pytest.mark.parametrize("workers", [1, 2, 16, 64])
def test_short_sessions_are_batched_and_the_tail_is_fine(workers):
    sizes = [250_000] * 3000  # the simulated fleet's short sessions
    parts = batches(sizes, workers)
    lens = [len(p) for p in parts]
    assert max(lens) == MAX_BATCH_BYTES // 250_000  # 16 sessions per task while many are left
    assert lens == sorted(lens, reverse=True)  # larger first
    assert lens[-1] == 1  # the last tasks are single sessions: no worker waits on a long batch
    assert len(parts) <= 3000 / 4  # a Dask task per 4 sessions or more (200 tasks on 2 workers)


def test_a_few_sessions_on_many_workers_are_one_task_each():
    assert batches([250_000] * 3, 3) == [range(0, 1), range(1, 2), range(2, 3)]
    assert batches([], 2) == []
