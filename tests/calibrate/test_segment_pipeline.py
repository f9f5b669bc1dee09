"""segment_blocks reduces each hold on a worker thread while the next blocks are read: the table is
the one of a sequential pass, whatever the block cuts, and the first error is the one a sequential
pass meets first."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from accellog.calibrate.observe.segment import observations
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


@pytest.mark.parametrize("n", [97, 1000, 10**9])
def test_any_cut_gives_the_table_of_the_whole_session(session, n):
    whole = observations(session)
    cut = segment_blocks(
        session.meta, session.poses, _blocks(session, n), where="x.mcap", events=session.events
    )
    for name in ("t_s", "meas_g", "sigma_g", "pose_id", "n_samples"):
        assert np.array_equal(getattr(cut, name), getattr(whole, name)), name


def test_a_bad_hold_is_raised_before_a_later_read_error(session):
    acc = session.accel_g.copy()
    p = session.poses[1]
    i = int(np.searchsorted(session.t_s, (p.start_s + p.end_s) / 2))
    acc[i] = np.nan
    blocks = _blocks(session, 97, acc, fail_after_s=p.end_s)  # the read fails just after the hold ends
    with pytest.raises(InputError, match=rf"pose {p.name!r}: accel is NaN/inf"):
        segment_blocks(session.meta, session.poses, blocks, where="x.mcap", events=session.events)
