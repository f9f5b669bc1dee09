"""segment_blocks reduces each hold on a worker thread while the next blocks are read: whatever the
block cuts, the table is what plain numpy computes on the whole arrays (each trimmed hold cut into
consecutive windows of the table's sample counts: their mean reading and mean time), and the first
error is the one a sequential pass meets first."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from accellog.calibrate.observe.stream_segment import segment_blocks
from accellog.core.errors import InputError
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    p = tmp_path_factory.mktemp("pipe") / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=500.0), p)
    return read_session(p)


def _blocks(s, n, accel=None, fail_after_s=None):
    """The session cut into blocks of n samples; InputError on the first block after fail_after_s."""
    acc = s.accel_g if accel is None else accel
    for i in range(0, s.n, n):
        sl = slice(i, i + n)
        if fail_after_s is not None and s.t_s[i] > fail_after_s:
            raise InputError("block broken", where="x.mcap")
        yield SimpleNamespace(t_s=s.t_s[sl], accel_g=acc[sl], temp_degC=s.temp_degC[sl])


def _numpy_windows(s, obs, trim_s: float = 0.5):
    """(mean reading (W, 3) g, mean time (W,) s) of the windows in plain numpy: each hold's samples
    in [start + trim_s, end - trim_s) split into consecutive runs of the table's n_samples."""
    means, times = [], []
    for k, p in enumerate(s.poses):
        idx = np.flatnonzero((s.t_s >= p.start_s + trim_s) & (s.t_s < p.end_s - trim_s))
        n = obs.n_samples[obs.pose_id == k]
        assert n.sum() == idx.size  # the windows tile the trimmed hold
        for part in np.split(idx, np.cumsum(n)[:-1]):
            means.append(s.accel_g[part].mean(axis=0))
            times.append(s.t_s[part].mean())
    return np.array(means), np.array(times)


@pytest.mark.parametrize("n", [97, 1000, 10**9])
def test_any_cut_gives_numpys_windows(session, n):
    cut = segment_blocks(
        session.meta, session.poses, _blocks(session, n), where="x.mcap", events=session.events
    )
    assert cut.n >= len(session.poses) and set(cut.pose_id) == set(range(len(session.poses)))
    means, times = _numpy_windows(session, cut)
    np.testing.assert_allclose(cut.meas_g, means, rtol=0, atol=1e-12)
    np.testing.assert_allclose(cut.t_s, times, rtol=1e-12, atol=0)
    assert np.all(cut.sigma_g > 0) and np.all(np.isfinite(cut.sigma_g))


def test_a_bad_hold_is_raised_before_a_later_read_error(session):
    acc = session.accel_g.copy()
    p = session.poses[1]
    i = int(np.searchsorted(session.t_s, (p.start_s + p.end_s) / 2))
    acc[i] = np.nan
    blocks = _blocks(session, 97, acc, fail_after_s=p.end_s)  # the read fails just after the hold ends
    with pytest.raises(InputError, match=rf"pose {p.name!r}: accel is NaN/inf"):
        segment_blocks(session.meta, session.poses, blocks, where="x.mcap", events=session.events)
