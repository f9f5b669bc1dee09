"""store.chunks: streamed /imu chunks equal read_session's samples on every path (index walk, mcap messages,
salvage of an unfinished file)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from accellog.core.errors import InputError
from accellog.flows.simulate import Scenario, simulate
from accellog.store import chunks
from accellog.store.reader import read_session

FIELDS = ("t_s", "sample_index", "accel_g", "accel_counts", "gyro_dps", "gyro_counts", "temp_degC")


@pytest.fixture(scope="module")
def session_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("chunks") / "s.mcap"
    simulate(Scenario(protocol="+z,-z", hold_s=20.0, move_s=2.0, sample_rate_hz=500.0, seed=2), p)
    return p


def _joined(parts):
    return {f: np.concatenate([getattr(c, f) for c in parts]) for f in FIELDS}


@pytest.mark.parametrize("path_kind", ["index", "messages"])
def test_chunks_equal_read_session(session_file, path_kind):
    s = read_session(session_file)
    if path_kind == "index":
        parts = list(chunks.iter_imu_chunks(session_file, chunk_bytes=50_000))
    else:
        parts = list(chunks._message_chunks(session_file, chunks.read_meta(session_file), 50_000))
    assert len(parts) > 3  # really chunked
    got = _joined(parts)
    for f in FIELDS:
        np.testing.assert_array_equal(got[f], getattr(s, f), err_msg=f)


def test_unfinished_file_is_salvaged_like_read_session(session_file, tmp_path):
    cut = tmp_path / "cut.mcap"
    shutil.copy(session_file, cut)
    with open(cut, "r+b") as f:
        f.truncate(cut.stat().st_size * 2 // 3)
    s = read_session(cut)
    got = _joined(list(chunks.iter_imu_chunks(cut)))
    np.testing.assert_array_equal(got["accel_counts"], s.accel_counts)
    np.testing.assert_array_equal(got["t_s"], s.t_s)


def test_not_an_mcap_file_is_one_line(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_text("hello")
    with pytest.raises(InputError, match="not an MCAP file"):
        next(chunks.iter_imu_chunks(p))
