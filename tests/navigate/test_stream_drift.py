"""drift over a session's blocks: an MCAP file in many blocks gives the drift polynomial and end
displacement plain numpy computes on the whole arrays (within 1e-9 relative) on sessions spanning
many chunk groups; the running sums against whole-series numpy; the checks' order (time stamps,
reader errors)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.sessions import RTOL, assert_json_close, synth_session
from support.sessions import random_blocks as _blocks

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.jsonio import dumps
from accellog.core.timeseries import cumtrapz
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import run_drift
from accellog.navigate.drift import DriftRefine, DriftSums, IntervalCount, _design
from accellog.store.stream import iter_imu
from accellog.store.writer import write_session


@pytest.fixture(autouse=True)
def small_groups(monkeypatch):
    """Chunk groups of 64 KiB instead of 4 MiB: a 40 s session streams in ~15 blocks."""
    from accellog.store.mcap import fastread

    monkeypatch.setattr(fastread, "_GROUP_BYTES", 1 << 16)


@pytest.mark.parametrize("n", [11, 12, 40_001])
def test_interval_median_in_pieces_is_exact(n):
    """Nanosecond time stamps of a jittered clock (odd and even interval counts)."""
    rng = np.random.default_rng(n)
    t = np.cumsum(rng.integers(900_000, 1_100_000, size=n)) / 1e9 + 7.0
    acc = IntervalCount()
    for sl in _blocks(n, rng, cuts=[1, 2] if n > 3 else []):
        acc.add(t[sl])
    assert acc.median() == np.median(np.diff(t))
    assert int(acc.counts.sum()) == n - 1


def test_drift_sums_in_pieces_equal_one_block_and_lstsq():
    rng = np.random.default_rng(1)
    n = 60_000
    t = 3.0 + np.cumsum(rng.uniform(0.0009, 0.0011, size=n))
    a = rng.normal(size=(n, 3)) * 0.02 + [1e-3, -2e-3, 5e-4]
    d = cumtrapz(t, cumtrapz(t, a))
    one = DriftSums()
    one.add(t, d)
    many = DriftSums()
    for sl in _blocks(n, rng):
        many.add(t[sl], d[sl])
    np.testing.assert_allclose(many.solve(), one.solve(), rtol=1e-10)  # before the refinement
    ref, *_ = np.linalg.lstsq(_design(t), d, rcond=None)
    np.testing.assert_allclose(one.solve(), ref, rtol=1e-7)  # normal equations on [0, 1]
    refine = DriftRefine(many.solve(), t[0], t[-1])
    for sl in _blocks(n, rng):
        refine.add(t[sl], d[sl])
    q, rms = refine.solve()
    np.testing.assert_allclose(q, ref, rtol=1e-11)  # after one refinement step
    np.testing.assert_allclose(rms, np.sqrt(np.mean((d - _design(t) @ ref) ** 2, axis=0)), rtol=1e-9)


def test_series_at_equals_the_series_read_while_adding():
    """Integrator.series_at(fn) after the pass gives what add(extra=fn) read: same bits."""
    from accellog.calibrate.calfile.drift_model import DriftModel
    from accellog.navigate.stream_sums import Integrator

    rng = np.random.default_rng(5)
    n = 20_000
    t = 3.0 + np.cumsum(rng.uniform(0.0009, 0.0011, n))
    a = rng.normal(0, 0.01, (n, 3)) + 0.002
    dm = DriftModel(q=rng.normal(0, 1e-3, (3, 3)), cov=np.zeros((3, 3, 3)), fit_duration_s=20.0)
    times = (0.0, 5.0, t[4000], 10.0, t[-1], t[-1] + 0.3, t[-1] + 2.0)  # before, on samples, late, too late
    live, later = Integrator(times), Integrator(times)
    for sl in _blocks(n, rng):
        live.add(t[sl], a[sl], lambda tb, d: {"dd": dm.apply(tb, d)})
        later.add(t[sl], a[sl])
    _used, at, ends = live.finish()
    later.finish()
    got, end = later.series_at(dm.apply)
    np.testing.assert_array_equal(got, at["dd"])
    np.testing.assert_array_equal(end, ends["dd"])
    assert np.isnan(got[-1]).all() and np.isfinite(got[:-1]).all()


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """A model3 calibration, a 40 s 1 kHz labelled '+z' session and an unlabelled '-y' one."""
    d = tmp_path_factory.mktemp("strdrift")
    simulate(Scenario(protocol="six", hold_s=5.0, move_s=2.0, sample_rate_hz=200.0, seed=1), d / "cal.mcap")
    simulate(Scenario(protocol="+z", hold_s=40.0, sample_rate_hz=1000.0, seed=4), d / "drift.mcap")
    s = synth_session(poses=["-y"], hold_s=30.0, move_s=0.0, rate_hz=1000.0, seed=3, label=False)
    write_session(d / "unlabelled.mcap", s, chunk_size=32 * 1024)
    assert main(["fit", str(d / "cal.mcap"), "-o", str(d / "m3.json")]) == 0
    return d


def _numpy_drift(path, cal, up, cut):
    """(q (3, 3): rows x, y, z, columns q0, q1, q2; d at the end (3,) m) of the session at path in
    plain numpy: f = (a' - b) S^-T, a = f g / truth_g - up g, v and d by cumulative trapezoid over
    the kept samples (t - t0 <= until_s, the first max_samples), q by least squares on [1, t, t^2/2]."""
    from scipy.integrate import cumulative_trapezoid

    from accellog.store.reader import read_session

    s = read_session(path)
    keep = np.ones(s.n, bool)
    if "until_s" in cut:
        keep &= s.t_s - s.t_s[0] <= cut["until_s"]
    if "max_samples" in cut:
        keep[cut["max_samples"] :] = False
    t = s.t_s[keep]
    S, b = cal.S_b()
    f = (s.accel_g[keep] - b) @ np.linalg.inv(S).T
    g = cal.local_gravity_mps2
    a = f * g / cal.truth_g - np.asarray(up, float) * g
    v = cumulative_trapezoid(a, t, axis=0, initial=0.0)
    d = cumulative_trapezoid(v, t, axis=0, initial=0.0)
    q = np.linalg.lstsq(np.column_stack([np.ones_like(t), t, 0.5 * t**2]), d, rcond=None)[0].T
    return q, d[-1], f.mean(axis=0)


@pytest.mark.parametrize(
    ("name", "cut"),
    [("drift", {}), ("drift", {"until_s": 25.5}), ("drift", {"max_samples": 37_000}), ("unlabelled", {})],
    ids=["all", "until", "max_samples", "inferred_up"],
)
def test_drift_in_many_blocks_equals_numpy(sessions, name, cut):
    """The drift polynomial and the end displacement of a file read in many blocks are numpy's on
    the whole arrays (the inferred orientation: the face of the mean calibrated reading)."""
    from accellog.calibrate.calfile.calibration import load_calibration

    d = sessions
    path = d / f"{name}.mcap"
    assert len(list(iter_imu(path))) >= 10
    cal = load_calibration(d / "m3.json")
    out = run_drift(path, cal, **cut)
    assert out.fit_eval.t_s is None  # streamed: no series kept
    up = np.asarray(out.fit_eval.up_sensor, float)
    q, d_end, f_mean = _numpy_drift(path, cal, up, cut)
    assert np.degrees(np.arccos(up @ f_mean / np.linalg.norm(f_mean))) < 10.0
    np.testing.assert_allclose(out.drift.q, q, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out.fit_eval.disp_end_m, d_end, rtol=1e-9, atol=1e-12)
    assert np.isfinite(out.drift.cov).all() and out.fit_eval.drift_applied
    assert out.cal.drift is not None


def test_drift_cli_streams_an_mcap_file(sessions, capsys):
    d = sessions
    out = d / "m3d.json"
    assert main(["drift", str(d / "drift.mcap"), "--cal", str(d / "m3.json"), "-o", str(out), "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    whole = run_drift(d / "drift.mcap", d / "m3.json", stream=False)
    assert_json_close(json.loads(dumps({**whole.to_dict(), "output": str(out)})), cli)
    saved = json.loads(out.read_text())["drift"]
    assert saved["axes"]["z"]["q2_mps2"] == pytest.approx(whole.drift.q[2, 2], rel=RTOL)


def test_streamed_drift_refuses_nan_in_a_late_block(tmp_path, sessions):
    s = synth_session(poses=["+z"], hold_s=30.0, move_s=0.0, rate_hz=1000.0, seed=8)
    s.accel_g[25_000, 1] = np.nan
    write_session(tmp_path / "nan.mcap", s, chunk_size=32 * 1024)
    with pytest.raises(InputError, match=r"accel is NaN/inf at t = 2[45]\.") as streamed:
        run_drift(tmp_path / "nan.mcap", sessions / "m3.json")
    with pytest.raises(InputError) as whole:
        run_drift(tmp_path / "nan.mcap", sessions / "m3.json", stream=False)
    assert str(streamed.value) == str(whole.value)


def test_arange_above_is_numpys_arange_from_lo():
    from accellog.core.timeseries import arange_above

    rng = np.random.default_rng(9)
    for _ in range(3000):
        t0 = float(rng.choice([0.0, rng.uniform(0, 10), rng.uniform(0, 1e5), rng.uniform(0, 2e9)]))
        w = float(rng.choice([0.5, 2.0, 0.1, rng.uniform(0.001, 5)]))
        stop = t0 + rng.uniform(-1, 3000) * w
        lo = t0 + rng.uniform(-2, 3000) * w
        ref = np.arange(t0, stop, w)
        np.testing.assert_array_equal(arange_above(t0, stop, w, lo), ref[ref > lo])


@pytest.mark.parametrize("cut", [{}, {"until_s": 10.0}], ids=["all", "cut_before_it"])
def test_time_stamp_error_comes_first_in_the_merged_pass(tmp_path, sessions, capsys, cut):
    """The time-stamp check runs inside the first streamed pass: a duplicated stamp late in the file
    is still reported before a NaN reading early on (and after a cut), as by the whole-session path."""
    from accellog.flows.stages import run_evaluate_report, run_integrate

    s = synth_session(poses=["+z"], hold_s=30.0, move_s=0.0, rate_hz=1000.0, seed=8)
    s.accel_g[5_000, 1] = np.nan
    s.t_s[27_000] = s.t_s[26_999]
    p = write_session(tmp_path / "dup.mcap", s, chunk_size=32 * 1024)
    cal = sessions / "m3.json"
    calls = {
        "evaluate": lambda stream: run_evaluate_report(p, [cal], stream=stream, **cut),
        "integrate": lambda stream: run_integrate(p, cal, output=tmp_path / "o.csv", stream=stream, **cut),
        "drift": lambda stream: run_drift(p, cal, stream=stream, **cut),
    }
    for name, call in calls.items():
        with pytest.raises(InputError, match="duplicated time stamp at sample 27000") as streamed:
            call(True)
        with pytest.raises(InputError) as whole:
            call(False)
        assert str(streamed.value) == str(whole.value), name
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("good_blocks", [0, 2])
def test_merged_check_keeps_the_readers_own_refusal_first(monkeypatch, sessions, good_blocks):
    """A reader error mid-file (after a cut, or before any block) is raised as the separate
    time-stamp pass raised it, not replaced by the check's 'session has 0 samples'."""
    from accellog.navigate.evaluate import evaluate_blocks, targets
    from accellog.store import source as se

    path = sessions / "drift.mcap"
    real = se.iter_imu

    def failing(p):
        for i, b in enumerate(real(p)):
            if i == good_blocks:
                raise InputError("reader says no", where=str(p))
            yield b

    monkeypatch.setattr(se, "iter_imu", failing)
    with pytest.raises(InputError, match="reader says no"):
        evaluate_blocks(se.open_source(path), targets([]), until_s=1.0)
