"""Chunk-by-chunk reading gives exactly read_session's samples, block by block."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from accellog.core.errors import DataIntegrityWarning
from accellog.flows.simulate import Scenario, simulate
from accellog.store.mcap import fastread
from accellog.store.reader import read_session
from accellog.store.stream import iter_imu, read_labels

FIELDS = ("t_s", "sample_index", "accel_g", "gyro_dps", "temp_degC")


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    p = tmp_path_factory.mktemp("stream") / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=2.0, move_s=1.0, sample_rate_hz=500.0), p)
    return p


def _joined(blocks, name):
    return np.concatenate([getattr(b, name) for b in blocks])


def _same_samples(blocks, s):
    for k in FIELDS:
        np.testing.assert_array_equal(_joined(blocks, k), getattr(s, k))


def test_blocks_are_read_session_split(recorded, monkeypatch):
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 32 << 10)  # small groups: many blocks
    blocks = list(iter_imu(recorded))
    assert len(blocks) > 5
    assert max(b.n for b in blocks) < 3 * min(b.n for b in blocks[:-1])  # bounded, even sizes
    s = read_session(recorded)
    _same_samples(blocks, s)
    meta, poses, events = read_labels(recorded)
    assert meta == s.meta and poses == s.poses and events == s.events


def test_damaged_chunk_is_skipped_with_a_warning(recorded, tmp_path):
    from mcap.reader import make_reader

    with open(recorded, "rb") as f:
        mid = make_reader(f).get_summary().chunk_indexes[5]
    b = bytearray(recorded.read_bytes())
    b[mid.chunk_start_offset + mid.chunk_length // 2] ^= 0x04
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b)
    with pytest.warns(DataIntegrityWarning, match="damaged chunk at byte"):
        blocks = list(iter_imu(bad))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataIntegrityWarning)
        s = read_session(bad)
    _same_samples(blocks, s)


def test_unfinished_file_falls_back_to_read_session(recorded, tmp_path):
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded.read_bytes()[: recorded.stat().st_size * 2 // 3])
    blocks = list(iter_imu(cut))
    _same_samples(blocks, read_session(cut))


def test_stream_observations_refuse_as_observations(recorded):
    from accellog.calibrate.observe.segment import observations
    from accellog.core.errors import InputError

    with pytest.raises(InputError, match=r"has \d+ samples after trimming 1.5 s"):
        observations(recorded, trim_s=1.5)


def test_labels_read_only_the_chunks_that_hold_them(recorded, tmp_path):
    """read_labels decompresses only the chunks whose message index lists a pose or event channel:
    a damaged IMU chunk is never touched (no damage named), the labels equal the clean file's, and
    a read of every topic still names that chunk."""
    from mcap.reader import make_reader

    from accellog.core.session import PoseLabel
    from accellog.store.layout import TOPIC_EVENTS, TOPIC_POSES
    from accellog.store.mcap.fastread import fast_collect

    with open(recorded, "rb") as f:
        summary = make_reader(f).get_summary()
    label_ids = {c.id for c in summary.channels.values() if c.topic in (TOPIC_POSES, TOPIC_EVENTS)}
    imu_only = [ix for ix in summary.chunk_indexes if not label_ids & set(ix.message_index_offsets)]
    assert imu_only and len(imu_only) < len(summary.chunk_indexes)
    mid = imu_only[len(imu_only) // 2]
    b = bytearray(recorded.read_bytes())
    b[mid.chunk_start_offset + mid.chunk_length // 2] ^= 0x04
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b)
    labels = fast_collect(bad, [TOPIC_POSES, TOPIC_EVENTS])
    assert labels is not None and labels.damaged == []
    with warnings.catch_warnings():
        warnings.simplefilter("error", DataIntegrityWarning)
        meta, poses, events = read_labels(bad)
    assert (meta, poses, events) == read_labels(recorded)
    assert len(poses) == 6 and all(isinstance(p, PoseLabel) for p in poses)
    whole = fast_collect(bad)
    assert [d.offset for d in whole.damaged] == [mid.chunk_start_offset]


def test_stream_observations_refuse_a_moving_hold(recorded):
    """A hold whose label runs into the next rotation: the streamed motion check (window shifts
    taken as each hold passes, one window table) names the pose, the time and the reason."""
    import dataclasses
    import re

    from accellog.calibrate.observe.segment import observations
    from accellog.core.errors import InputError
    from accellog.store.source import open_source

    src = open_source(recorded)
    poses = src.poses
    poses = sorted(poses, key=lambda p: p.start_s)
    poses[2] = dataclasses.replace(poses[2], end_s=poses[3].start_s - 0.05)  # into the move
    with pytest.raises(
        InputError, match=rf"pose {re.escape(repr(poses[2].name))} is labelled static but moves at t = \d"
    ):
        src.poses = poses
        observations(src, check_units=False)


def test_rows_grow_past_their_capacity():
    from accellog.calibrate.observe.stream_segment import _Rows

    rows, parts = _Rows(3), [np.arange(k * 2.0).reshape(k, 2) for k in (2, 4, 1)]
    for x in parts:
        rows.add({"x": x, "i": np.arange(len(x))})
    assert rows.cap >= 7 and np.array_equal(rows.col("x"), np.concatenate(parts))
    assert np.array_equal(rows.col("i"), np.concatenate([np.arange(len(x)) for x in parts]))


def test_reads_in_a_memory_locked_process(recorded):
    """A real-time process locks its memory (mlockall) before recording or replaying; the kernel
    then refuses the readers' MADV_DONTNEED (EINVAL), which is advice: the session is read all the
    same (it failed with 'Invalid argument' and a BufferError)."""
    import subprocess
    import sys

    code = f"""
import ctypes, sys
libc = ctypes.CDLL("libc.so.6", use_errno=True)
if libc.mlockall(3) != 0:  # MCL_CURRENT | MCL_FUTURE
    sys.exit(77)
from accellog.store.reader import read_session
from accellog.store.stream import iter_imu
n = read_session({str(recorded)!r}).n
assert n == sum(b.n for b in iter_imu({str(recorded)!r})), n
print(n)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    if r.returncode == 77:
        pytest.skip("mlockall not permitted here")
    assert r.returncode == 0, r.stderr[-2000:]
    assert int(r.stdout) > 1000
