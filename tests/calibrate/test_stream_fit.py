"""fit and segment on an MCAP file stream it (bounded memory) and give the whole-session results."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from accellog.calibrate.gyro.calibrate import calibrate_gyro
from accellog.calibrate.gyro.stream import stream_calibrate_gyro
from accellog.calibrate.observe.stream_segment import stream_check_timestamps
from accellog.cli import main
from accellog.core.errors import InputError
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import load_input, run_fit
from accellog.flows.stream_input import can_stream, open_streamed
from accellog.store import fastread
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


def test_stream_gyro_equals_whole_session(recorded, small_groups):
    s = read_session(recorded)
    whole = calibrate_gyro(s.t_s, s.gyro_dps, s.poses, s.temp_degC).to_dict()
    streamed = stream_calibrate_gyro(recorded, s.poses).to_dict()
    assert "scale" in whole["effects"]
    _close(whole, streamed)


def test_open_streamed_reads_a_good_file_once(recorded, monkeypatch):
    """The time-stamp checks ride on the observation pass: one pass over the samples, and the same
    observations as with the checks in a pass of their own."""
    from accellog.calibrate.observe import stream_segment
    from accellog.flows import stream_input

    passes = []
    real = stream_segment.iter_imu
    monkeypatch.setattr(stream_segment, "iter_imu", lambda p: passes.append(p) or real(p))
    one = open_streamed(recorded, stats=True)
    assert len(passes) == 1
    two = stream_input._open_two_passes(Path(recorded), 2.0, 0.5, True, [], True)
    assert len(passes) == 3
    np.testing.assert_array_equal(one.obs.meas_g, two.obs.meas_g)
    assert len(one.stats) == len(two.stats) == len(one.poses)


def test_stream_gyro_hold_labelled_past_the_end(recorded, small_groups):
    """Bias windows whose edges lie past the last sample (a hold labelled beyond the end of the
    recording: their ranges are found only at the end of the pass): the whole-session result."""
    from dataclasses import replace

    s = read_session(recorded)
    poses = [*s.poses[:-1], replace(s.poses[-1], end_s=float(s.t_s[-1]) + 5.0)]
    whole = calibrate_gyro(s.t_s, s.gyro_dps, poses, s.temp_degC).to_dict()
    _close(whole, stream_calibrate_gyro(recorded, poses).to_dict())


def test_fit_streams_and_matches_whole_session(recorded, small_groups, tmp_path):
    assert can_stream(recorded)
    whole = run_fit(load_input(recorded))  # a Session: the whole-session path
    streamed = run_fit(recorded)  # a path: streamed
    assert type(streamed.obs) is type(whole.obs)
    _close(json.loads(whole.cal.to_json()), json.loads(streamed.cal.to_json()))
    assert streamed.cal.gyro is not None and streamed.cal.gyro.effects == whole.cal.gyro.effects
    out = tmp_path / "cal.json"
    assert main(["fit", str(recorded), "-o", str(out)]) in (0, None)
    _close(json.loads(whole.cal.to_json()), json.loads(out.read_text()))


@pytest.mark.parametrize("i", [700, 1, 2999, None])
def test_stream_time_checks_equal_whole_session(recorded, small_groups, tmp_path, i):
    from accellog.calibrate.observe.label_check import check_timestamps
    from accellog.store.stream import iter_imu
    from accellog.store.writer import write_session

    stream_check_timestamps(recorded)  # a good session passes
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
        stream_check_timestamps(bad)
    assert f"duplicated time stamp at sample {i}" in str(whole.value)
    assert str(streamed.value) == str(whole.value)
    with pytest.raises(InputError) as opened:  # the checks taken in the observation pass
        open_streamed(bad)
    assert str(opened.value) == str(whole.value)
    assert main(["fit", str(bad), "-o", str(tmp_path / "c.json")]) not in (0, None)
    assert not (tmp_path / "c.json").exists()


def test_segment_streams(recorded, small_groups):
    from accellog.flows.static_stages import run_segment
    from accellog.flows.stream_input import StreamedSession

    res = run_segment(recorded)
    assert isinstance(res.session, StreamedSession)
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
    from accellog.flows import stream_input

    assert main(["diagnose", str(recorded), "--json"]) in (0, None)
    streamed = json.loads(capsys.readouterr().out)
    monkeypatch.setattr(stream_input, "can_stream", lambda p: False)  # the whole-session path
    assert main(["diagnose", str(recorded), "--json"]) in (0, None)
    whole = json.loads(capsys.readouterr().out)
    assert streamed["clock"] is not None
    _close(whole, streamed)


@pytest.mark.parametrize("batch", [1, 7, 1000])
def test_coarse_blocks_fed_in_batches_equal_whole_array_increments(batch):
    """_CoarseBlocks (the streamed reduction to coarse blocks, temperature term on) gives
    gyro._increments' phi and c whatever the batches; coarse blocks span batches."""
    import numpy as np

    from accellog.calibrate.gyro.calibrate import GyroCalibration
    from accellog.calibrate.gyro.rotation import _increments
    from accellog.calibrate.gyro.stream import _CoarseBlocks

    rng = np.random.default_rng(5)
    fine = np.cumsum(rng.integers(4, 7, 400))
    coarse = np.concatenate([fine[:50:49], fine[50:120], fine[120:300:179], fine[300:]])
    w_int, temp_int = rng.normal(0, 0.3, (399, 3)), 30.0 + rng.normal(0, 0.1, 399)
    span = rng.uniform(0.009, 0.011, 399)
    base = GyroCalibration(
        bias_dps=np.array([0.5, -1.2, 0.8]),
        bias_sigma_dps=np.full(3, 0.01),
        temp_bias_dps_per_degC=np.array([0.01, -0.02, 0.03]),
    )
    phi, c, _ = _increments(w_int, temp_int, span, base, fine, coarse, fine[:1])
    blocks = _CoarseBlocks(np.searchsorted(fine, coarse[:-1]), fine.size, base, use_temp=True)
    for i in range(0, 399, batch):
        blocks.add(w_int[i : i + batch], temp_int[i : i + batch], span[i : i + batch])
    assert blocks.open is None and phi.shape == blocks.phi.shape == (coarse.size - 1, 3)
    np.testing.assert_allclose(blocks.phi, phi, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(blocks.c, c, rtol=1e-12, atol=1e-18)


def test_stream_gyro_with_temperature_slope_equals_whole_session(tmp_path, small_groups):
    """A warming sensor: the temperature term of the integration pass is on and matches. The
    block sums differ from the whole-array ones by ~1e-20 rad (long coarse blocks summed in two
    parts); this poorly conditioned matrix fit (scale 0.9, rms 0.6 deg) turns that into ~1e-10."""
    p = tmp_path / "warm.mcap"
    temp = {"kind": "ramp", "T0": 25.0, "rate_degC_per_s": 0.2}
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=500.0, temperature=temp), p)
    s = read_session(p)
    whole = calibrate_gyro(s.t_s, s.gyro_dps, s.poses, s.temp_degC)
    assert any(whole.temp_bias_dps_per_degC != 0)
    _close(whole.to_dict(), stream_calibrate_gyro(p, s.poses).to_dict(), tol=1e-9)


@pytest.mark.parametrize("rate_hz", [20.0, 99.0, 1000.0])
def test_pair_by_pair_block_edges_equal_the_whole_arrays(rate_hz):
    """fine_pieces / coarse_plan (one hold pair in memory at a time) give _block_edges' fine and
    coarse edges and the fine index of each coarse edge, also when the 10 ms blocks are shorter
    than a sample (rounded edges repeat) and when two holds share a middle."""
    import numpy as np

    from accellog.calibrate.gyro.rotation import _block_edges, coarse_plan, fine_pieces

    rng = np.random.default_rng(int(rate_hz))
    for trial in range(40):
        n = int(rng.integers(50, 3000))
        t = np.cumsum(rng.uniform(0.5, 1.5, n)) / rate_hz
        k = int(rng.integers(2, 6))
        starts = np.sort(rng.integers(0, n, k))
        ends = np.maximum(np.sort(np.minimum(starts + rng.integers(0, n // k + 1, k), n - 1)), starts)
        mids = np.sort((starts + ends) // 2)
        if trial % 5 == 0:
            mids[1] = mids[0]
        fine, coarse = _block_edges(t, mids, ends, starts, 0.01)
        np.testing.assert_array_equal(np.concatenate([mids[:1], *fine_pieces(t, mids, 0.01)]), fine)
        c2, at, n_fine = coarse_plan(t, mids, ends, starts, 0.01)
        np.testing.assert_array_equal(c2, coarse)
        np.testing.assert_array_equal(at, np.searchsorted(fine, coarse[:-1]))
        assert n_fine == fine.size
