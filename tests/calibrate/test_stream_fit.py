"""fit, segment and diagnose on an MCAP file stream it (bounded memory), read in many blocks, and
give what plain numpy computes from the whole sample arrays (read_session) on the same samples:
each hold's trimmed mean (the windows tile it), the model3 fit as the weighted least squares of
meas = S (g u) + b per axis, the time-stamp refusal naming the first non-increasing step, the host
clock points as the last sample of each run of equal host times."""

from __future__ import annotations

import json

import numpy as np
import pytest

from accellog.calibrate.calfile.calibration import load_calibration
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


def _numpy_hold_means(path, trim_s: float = 0.5) -> np.ndarray:
    """(poses, 3) mean reading (g) of each labelled hold, trim_s cut at both ends, in plain numpy."""
    s = read_session(path)
    keep = [(s.t_s >= p.start_s + trim_s) & (s.t_s < p.end_s - trim_s) for p in s.poses]
    return np.array([s.accel_g[k].mean(axis=0) for k in keep])


def _table_hold_means(obs) -> np.ndarray:
    """Each hold's mean of the table's window means weighted by their samples (g)."""
    rows = [obs.pose_id == k for k in range(len(obs.pose_names))]
    return np.array([obs.n_samples[r] @ obs.meas_g[r] / obs.n_samples[r].sum() for r in rows])


def _numpy_affine(obs, gravity_g: float) -> tuple[np.ndarray, np.ndarray]:
    """(S, b) of meas = S (gravity_g u) + b by weighted least squares per axis (plain numpy)."""
    X = np.column_stack([obs.up_sensor * gravity_g, np.ones(obs.n)])
    coef = []
    for i in range(3):
        w = 1.0 / obs.sigma_g[:, i]
        coef.append(np.linalg.lstsq(X * w[:, None], obs.meas_g[:, i] * w, rcond=None)[0])
    c = np.array(coef)
    return c[:, :3], c[:, 3]


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


def test_streamed_fit_equals_numpy(recorded, small_groups, tmp_path):
    """A streamed model3 fit: its windows tile each trimmed hold (their sample-weighted mean is the
    numpy mean of the hold), and S, b are numpy's weighted least squares on its table; the CLI
    writes the same S, b."""
    assert sum(1 for _ in source.open_source(recorded).blocks()) > 10  # really many blocks
    out = run_fit(recorded)
    np.testing.assert_allclose(_table_hold_means(out.obs), _numpy_hold_means(recorded), rtol=0, atol=1e-12)
    S_np, b_np = _numpy_affine(out.obs, out.fit.gravity_g)
    S, b = out.cal.S_b()
    np.testing.assert_allclose(S, S_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b, b_np, rtol=0, atol=1e-12)
    assert out.cal.gyro is not None and "bias" in out.cal.gyro.effects
    cal = tmp_path / "cal.json"
    assert main(["fit", str(recorded), "-o", str(cal)]) in (0, None)
    S_cli, b_cli = load_calibration(cal).S_b()
    np.testing.assert_allclose(S_cli, S_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b_cli, b_np, rtol=0, atol=1e-12)


@pytest.mark.parametrize("i", [700, 1, 2999, None])
def test_stream_time_checks_name_numpys_first_bad_step(recorded, small_groups, tmp_path, i):
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
    t = read_session(bad).t_s  # the stamps as stored; numpy names the first non-increasing step
    k = int(np.argmax(np.diff(t) <= 0)) + 1
    want = (
        f"{bad}: duplicated time stamp at sample {k}: t = {t[k]:.6f} s after {t[k - 1]:.6f} s "
        f"({int(np.sum(np.diff(t) <= 0))} non-increasing steps)"
    )
    assert k == i
    for check in (lambda: source.open_source(bad).check(), lambda: observations(bad)):  # own pass, riding
        with pytest.raises(InputError) as streamed:
            check()
        assert str(streamed.value) == want
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


def test_host_clock_fit_equals_numpy(recorded, small_groups):
    """The streamed host clock is numpy's least-squares line of host time against sensor time at
    the last sample of each run of equal host times (one point per read batch, not per sample)."""
    from accellog.calibrate.diagnosis.clock import clock_from_host_time
    from accellog.store.stream import read_host_clock

    s = read_session(recorded)
    assert s.host_time_s is not None
    last = np.flatnonzero(np.append(np.diff(s.host_time_s) != 0, True))
    ts, th = s.t_s[last], s.host_time_s[last]
    line = read_host_clock(recorded)
    assert line is not None and line.count == last.size < s.n / 5
    A = np.stack([ts - ts.mean(), np.ones_like(ts)], axis=1)
    coef, rss, *_ = np.linalg.lstsq(A, th, rcond=None)
    got = clock_from_host_time(line)
    assert got["eps_clock"] == pytest.approx(coef[0] - 1.0, rel=1e-9, abs=1e-13)
    sigma = np.sqrt(rss[0] / (ts.size - 2) / np.sum((ts - ts.mean()) ** 2))
    assert got["sigma"] == pytest.approx(sigma, rel=1e-9)
    assert clock_from_host_time((s.t_s, s.host_time_s)) == pytest.approx(got, rel=1e-9, abs=1e-13)


def test_streamed_diagnose_base_fit_equals_numpy(recorded, small_groups, capsys):
    """diagnose of a streamed file: the base model3 fit is numpy's weighted least squares on the
    observation windows, its chi2 numpy's weighted residual sum of squares."""
    assert main(["diagnose", str(recorded), "--json"]) in (0, None)
    d = json.loads(capsys.readouterr().out)
    assert d["clock"] is not None
    obs = observations(recorded)
    np.testing.assert_allclose(_table_hold_means(obs), _numpy_hold_means(recorded), rtol=0, atol=1e-12)
    S_np, b_np = _numpy_affine(obs, d["fit"]["gravity_g"])
    np.testing.assert_allclose(d["fit"]["S"], S_np, rtol=0, atol=1e-12)
    np.testing.assert_allclose(d["fit"]["b_g"], b_np, rtol=0, atol=1e-12)
    r = (obs.meas_g - obs.up_sensor @ S_np.T * d["fit"]["gravity_g"] - b_np) / obs.sigma_g
    assert d["chi2"] == pytest.approx(float(np.sum(r**2)), rel=1e-9)
