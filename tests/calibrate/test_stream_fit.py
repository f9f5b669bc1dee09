"""fit and segment on an MCAP file stream it (bounded memory) and give the whole-session results."""

from __future__ import annotations

import json

import numpy as np
import pytest

from accellog.calibrate.observe.segment import observations
from accellog.cli import main
from accellog.core.errors import InputError
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import run_fit
from accellog.store import source
from accellog.store.mcap import fastread
from accellog.store.reader import read_session


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    p = tmp_path_factory.mktemp("sfit") / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=500.0), p)
    return p


@pytest.fixture
def small_groups(monkeypatch):
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 32 << 10)  # many blocks: holds and windows span them


def _close(a, b, path="", tol=1e-12) -> None:
    """Nested JSON values equal, floats within tol (relative to max(1, |a|))."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a.keys() - {"created_utc"}:  # the time of writing
            _close(a[k], b[k], f"{path}.{k}", tol)
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{path}[{i}]", tol)
    elif isinstance(a, float) and isinstance(b, float):
        assert abs(a - b) <= tol * max(1.0, abs(a)), (path, a, b)
    else:
        assert a == b, path


def test_a_good_file_is_read_once(recorded, monkeypatch):
    """The time-stamp checks ride on the observation pass: one pass over the samples, and the same
    observations as with the checks in a pass of their own."""
    passes = []
    real = source.iter_imu
    monkeypatch.setattr(source, "iter_imu", lambda p: passes.append(p) or real(p))
    stats = []
    one = observations(source.open_source(recorded), stats_out=stats)
    assert len(passes) == 1
    src = source.open_source(recorded)
    src.check()
    two = observations(src)
    assert len(passes) == 3
    np.testing.assert_array_equal(one.meas_g, two.meas_g)
    assert len(stats) == len(src.poses) == 6


def test_fit_streams_and_matches_whole_session(recorded, small_groups, tmp_path):
    assert not source.open_source(recorded).in_memory
    whole = run_fit(read_session(recorded))  # a Session: one block in memory
    streamed = run_fit(recorded)  # a path: streamed
    assert type(streamed.obs) is type(whole.obs)
    _close(json.loads(whole.cal.to_json()), json.loads(streamed.cal.to_json()))
    assert streamed.cal.gyro is not None and streamed.cal.gyro.effects == whole.cal.gyro.effects
    out = tmp_path / "cal.json"
    assert main(["fit", str(recorded), "-o", str(out)]) in (0, None)
    _close(json.loads(whole.cal.to_json()), json.loads(out.read_text()))


@pytest.mark.parametrize("i", [700, 1, 2999, None])
def test_stream_time_checks_equal_whole_session(recorded, small_groups, tmp_path, i):
    from accellog.store.source import check_timestamps
    from accellog.store.stream import iter_imu
    from accellog.store.writer import write_session

    source.open_source(recorded).check()  # a good session passes
    s = read_session(recorded)
    if i is None:  # the first sample of the second block repeats the last of the first
        i = next(iter(iter_imu(write_session(tmp_path / "ok.mcap", s, chunk_size=8 * 1024)))).n
    s.t_s = s.t_s.copy()
    s.t_s[i] = s.t_s[i - 1]
    s.t_s[i + 200] = s.t_s[i + 100]  # one decreasing step as well
    bad = write_session(tmp_path / "bad.mcap", s, chunk_size=8 * 1024)
    with pytest.raises(InputError) as whole:
        check_timestamps(s, where=str(bad))
    with pytest.raises(InputError) as streamed:
        source.open_source(bad).check()
    assert f"duplicated time stamp at sample {i}" in str(whole.value)
    assert str(streamed.value) == str(whole.value)
    with pytest.raises(InputError) as opened:  # the checks taken in the observation pass
        observations(bad)
    assert str(opened.value) == str(whole.value)
    assert main(["fit", str(bad), "-o", str(tmp_path / "c.json")]) not in (0, None)
    assert not (tmp_path / "c.json").exists()


def test_segment_streams(recorded, small_groups):
    from accellog.flows.stages import run_segment

    res = run_segment(recorded)
    assert not res.session.in_memory
    assert len(res.stats) == 6 and res.obs.n == sum(1 for _ in res.obs.t_s) >= 6
    assert [st.name for st in res.stats] == res.obs.pose_names
    for st in res.stats:  # each hold's statistics agree with its rows (a 3 s hold, 2 s windows: one)
        rows = res.obs.pose_id == res.obs.pose_names.index(st.name)
        np.testing.assert_allclose(res.obs.meas_g[rows].mean(axis=0), st.mean_g, atol=2e-3)
        assert abs(np.linalg.norm(st.mean_g) - 1.0) < 0.1


def obs_dict(o):
    from accellog.calibrate.observe.obs_file import obs_to_dict

    return json.loads(json.dumps(obs_to_dict(o)))


def test_host_clock_points_equal_whole_session(recorded, small_groups):
    from accellog.calibrate.diagnosis.clock import clock_from_host_time
    from accellog.store.stream import read_host_clock

    s = read_session(recorded)
    assert s.host_time_s is not None
    pts = read_host_clock(recorded)
    assert pts[0].size < s.n / 5  # one point per read batch, not per sample
    assert clock_from_host_time(*pts) == clock_from_host_time(s.t_s, s.host_time_s)


def test_diagnose_streams_and_matches_whole_session(recorded, small_groups, monkeypatch, capsys):
    assert main(["diagnose", str(recorded), "--json"]) in (0, None)
    streamed = json.loads(capsys.readouterr().out)
    monkeypatch.setattr(source, "_streams", lambda p: False)  # read whole, one block
    assert main(["diagnose", str(recorded), "--json"]) in (0, None)
    whole = json.loads(capsys.readouterr().out)
    assert streamed["clock"] is not None
    _close(whole, streamed)
