"""evaluate / integrate over a session's blocks: an MCAP file in many blocks gives the numbers plain
numpy computes on the whole arrays with the calibration's own correction (within 1e-9 relative:
the carried sums, the cuts across blocks), on simulated sessions long enough for several chunk
groups; the running sums against the whole-series formulas when fed in small irregular blocks; a
CSV input integrated with a calibration."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.sessions import RTOL, assert_json_close, synth_session
from support.sessions import random_blocks as _blocks

from accellog.calibrate.observe.hold_noise import BLOCK, AutocorrTime, integrated_autocorr_time, tau_from_rho
from accellog.cli import main
from accellog.core.errors import InputError
from accellog.core.jsonio import dumps
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import run_evaluate_report
from accellog.navigate.stream_sums import ResidualSums
from accellog.store.stream import iter_imu
from accellog.store.writer import write_session


@pytest.mark.parametrize("n", [5000, 2 * BLOCK + 7, 5 * BLOCK + 123])
def test_autocorr_time_in_pieces_equals_the_whole_series(n):
    rng = np.random.default_rng(n)
    x = np.cumsum(rng.normal(size=(n, 3)), axis=0) * 0.01 + rng.normal(size=(n, 3)) + [5.0, -3.0, 0.2]
    acc = AutocorrTime()
    for sl in _blocks(n, rng):
        acc.add(x[sl])
    np.testing.assert_allclose(acc.tau(), integrated_autocorr_time(x), rtol=RTOL)
    np.testing.assert_allclose(acc.tau(), tau_from_rho(_block_rho(x)), rtol=RTOL)


def _block_rho(x: np.ndarray) -> np.ndarray:
    """Plain numpy: the autocorrelation summed over non-overlapping BLOCK-blocks of x centred on
    its global mean (one FFT of the whole series when it has <= 2 BLOCK samples)."""
    xc = x - x.mean(axis=0)
    b = BLOCK if len(x) > 2 * BLOCK else len(x)
    acov = np.zeros((b, x.shape[1]))
    for i in range(len(x) // b):
        y = xc[i * b : (i + 1) * b]
        for j in range(x.shape[1]):
            acov[:, j] += np.correlate(y[:, j], y[:, j], "full")[b - 1 :] if b < 6000 else _fft_acov(y[:, j])
    return acov / acov[0]


def _fft_acov(y: np.ndarray) -> np.ndarray:
    f = np.fft.rfft(y, 2 * len(y))
    return np.fft.irfft(f * np.conj(f), 2 * len(y))[: len(y)]


def test_residual_sums_in_pieces_equal_one_block():
    """Windows whose edges fall exactly on samples and on block boundaries; times read between
    samples, at the end, within and beyond the 0.5 s tolerance."""
    n = 2 * BLOCK + 5000
    rng = np.random.default_rng(3)
    t = np.arange(n) * 0.001  # window edges 0, 2, 4 ... s are sample times
    r = rng.normal(size=(n, 3)) * 0.03 + [0.01, -0.2, 0.05]
    times = (0.0, 10.0005, 30.0, 38.0, 38.5)  # t_end 37.767 s: 38.0 takes the end, 38.5 NaN
    one = ResidualSums(times, 2.0)
    one.add(t, r)
    a = one.finish()
    many = ResidualSums(times, 2.0)
    for sl in _blocks(n, rng, cuts=[2000, 2001, 4000, n - 1]):
        many.add(t[sl], r[sl])
    b = many.finish()
    for k in ("mean", "std", "tau", "rms", "disp_at", "disp_end"):
        np.testing.assert_allclose(b[k], a[k], rtol=RTOL, atol=1e-15, err_msg=k)
    np.testing.assert_array_equal(np.isnan(b["t_used"]), [False, False, False, False, True])
    # the whole-series formulas
    np.testing.assert_allclose(a["std"], r.std(axis=0, ddof=1), rtol=1e-12)
    starts = np.unique(np.searchsorted(t, np.arange(t[0], t[-1], 2.0)))
    means = np.add.reduceat(r, starts, axis=0) / np.diff(np.append(starts, n))[:, None]
    assert a["rms"] == pytest.approx(np.sqrt(np.mean(means**2)), rel=1e-12)


@pytest.fixture(autouse=True)
def small_groups(monkeypatch):
    """Chunk groups of 64 KiB instead of 4 MiB: a 40 s session streams in ~15 blocks."""
    from accellog.store.mcap import fastread

    monkeypatch.setattr(fastread, "_GROUP_BYTES", 1 << 16)


def _static_mcap(path, seed: int, hold_s: float = 40.0, bump_at_s: float | None = None):
    """A 1 kHz '+z' hold (more than 2 x noise.BLOCK samples) with uneven sample times and a
    30 -> 40 degC ramp, written as MCAP; bump_at_s: the sensor is knocked (+0.3 g for 0.4 s)."""
    s = synth_session(poses=["+z"], hold_s=hold_s, move_s=0.0, rate_hz=1000.0, seed=seed)
    s.temp_degC = 30.0 + 10.0 * s.t_s / s.t_s[-1]
    if bump_at_s is not None:
        s.accel_g[s.slice_time(bump_at_s, bump_at_s + 0.4)] += 0.3
    return write_session(path, s, chunk_size=32 * 1024)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    """Six-position calibrations (model3, + temperature bias, + drift model), a 40 s 1 kHz '+z'
    test session and a six-pose session for the per-pose path."""
    d = tmp_path_factory.mktemp("streval")
    simulate(Scenario(protocol="six", hold_s=5.0, move_s=2.0, sample_rate_hz=200.0, seed=1), d / "cal.mcap")
    simulate(Scenario(protocol="+z", hold_s=40.0, sample_rate_hz=200.0, seed=4), d / "drift.mcap")
    simulate(
        Scenario(protocol="six", hold_s=10.0, move_s=2.0, sample_rate_hz=200.0, seed=5), d / "poses.mcap"
    )
    _static_mcap(d / "test.mcap", seed=2)
    assert main(["fit", str(d / "cal.mcap"), "-o", str(d / "m3.json")]) == 0
    assert main(["fit", str(d / "cal.mcap"), "--add", "temp_bias", "-o", str(d / "tb.json")]) == 0
    assert main(["drift", str(d / "drift.mcap"), "--cal", str(d / "m3.json"), "-o", str(d / "m3d.json")]) == 0
    return d


def test_test_session_spans_several_chunk_groups(sessions):
    assert len([b.n for b in iter_imu(sessions / "test.mcap")]) >= 10


def _numpy_track(path, cal_path, cut=None):
    """(t, d) of the session at path in plain numpy: f = the calibration's own correction of the
    samples, a = f g / truth_g - up g, v and d by cumulative trapezoid over the kept samples
    (t - t0 <= until_s, the first max_samples); d with the calibration's drift model removed."""
    from scipy.integrate import cumulative_trapezoid

    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.store.reader import read_session

    cut = cut or {}
    s, cal = read_session(path), load_calibration(cal_path)
    keep = np.ones(s.n, bool)
    if "until_s" in cut:
        keep &= s.t_s - s.t_s[0] <= cut["until_s"]
    if "max_samples" in cut:
        keep[cut["max_samples"] :] = False
    t, g = s.t_s[keep], cal.local_gravity_mps2
    a = cal.correct(s)[keep] * g / cal.truth_g - np.asarray(s.poses[0].up_sensor, float) * g
    v = cumulative_trapezoid(a, t, axis=0, initial=0.0)
    d = cumulative_trapezoid(v, t, axis=0, initial=0.0)
    return t, v, d if cal.drift is None else cal.drift.apply(t, d)


@pytest.mark.parametrize(
    "cut", [{}, {"until_s": 25.5}, {"max_samples": 37_000}], ids=["all", "until", "max_samples"]
)
def test_evaluate_in_many_blocks_equals_numpy(sessions, cut):
    """Each calibration's end displacement (model3, + temperature bias, + drift model) of a file
    read in many blocks is numpy's on the whole arrays."""
    d = sessions
    cals = [d / "m3.json", d / "tb.json", d / "m3d.json"]
    streamed = run_evaluate_report(d / "test.mcap", cals, **cut)
    assert not streamed.data.in_memory and streamed.single[0].t_s is None
    assert [e.drift_applied for e in streamed.single[1:]] == [False, False, True]
    for ev, cal in zip(streamed.single[1:], cals, strict=True):
        t, _v, disp = _numpy_track(d / "test.mcap", cal, cut)
        assert ev.t_end_s == pytest.approx(t[-1], rel=1e-12)
        end = ev.disp_end_drift_m if ev.drift_applied else ev.disp_end_m
        np.testing.assert_allclose(end, disp[-1], rtol=1e-9, atol=1e-12, err_msg=str(cal))


def test_evaluate_takes_an_opened_streamed_session_in_memory_too(sessions):
    """run_evaluate on an opened Source (e.g. reused from an earlier stage) with stream=False reads
    its file whole: its displacement series is numpy's."""
    from accellog.flows.stages import run_evaluate
    from accellog.store.source import open_source

    d = sessions
    opened = open_source(d / "test.mcap")
    got = run_evaluate(opened, d / "m3.json", stream=False)[-1]
    t, _v, disp = _numpy_track(d / "test.mcap", d / "m3.json")
    np.testing.assert_allclose(got.t_s, t, rtol=1e-12)
    np.testing.assert_allclose(got.disp_series_m, disp, rtol=1e-9, atol=1e-12)


def test_streamed_per_pose_evaluate_equals_numpy(sessions):
    """Hold by hold on a file read in many blocks: every window's residual is numpy's (the mean of
    the calibration's correction over the window's samples, each trimmed hold cut into runs of the
    windows' sample counts, minus its up vector in truth units), each hold's mean their 1/sigma^2
    weighted mean."""
    from accellog.calibrate.calfile.calibration import load_calibration
    from accellog.store.reader import read_session

    d = sessions
    rep = run_evaluate_report(d / "poses.mcap", [d / "m3.json"])
    assert not rep.data.in_memory and rep.kind == "poses"
    s, cal, obs, ev = read_session(d / "poses.mcap"), load_calibration(d / "m3.json"), rep.obs, rep.poses[1]
    f = cal.correct(s)
    assert ev.pose_names == [p.name for p in s.poses]
    for k, p in enumerate(s.poses):
        rows = obs.pose_id == k
        idx = np.flatnonzero((s.t_s >= p.start_s + 0.5) & (s.t_s < p.end_s - 0.5))
        n = obs.n_samples[rows]
        assert n.sum() == idx.size  # the windows tile the trimmed hold
        r = np.array([f[w].mean(axis=0) for w in np.split(idx, np.cumsum(n)[:-1])])
        r -= np.asarray(p.up_sensor, float) * cal.truth_g
        np.testing.assert_allclose(ev.window_resid_g[rows], r, rtol=0, atol=1e-13)
        wt = 1.0 / obs.sigma_g[rows] ** 2
        np.testing.assert_allclose(
            ev.mean_resid_g[k], (r * wt).sum(axis=0) / wt.sum(axis=0), rtol=0, atol=1e-13
        )


def test_integrate_csv_in_many_blocks_equals_numpy(sessions, capsys):
    """`integrate -o` streams the CSV block by block: its rows are numpy's t, v, d (9 digits)."""
    d = sessions
    args = ["integrate", str(d / "test.mcap"), "--cal", str(d / "m3.json"), "--json"]
    assert main([*args, "-o", str(d / "s.csv")]) == 0
    said = json.loads(capsys.readouterr().out)
    rows = np.loadtxt(d / "s.csv", delimiter=",", skiprows=1)
    t, v, disp = _numpy_track(d / "test.mcap", d / "m3.json")
    assert rows.shape == (t.size, 7) and t.size > 2 * BLOCK
    np.testing.assert_allclose(rows[:, 0], t, rtol=1e-8)
    np.testing.assert_allclose(rows[:, 1:4], v, rtol=1e-7, atol=1e-9)  # the CSV holds 9 significant digits
    np.testing.assert_allclose(rows[:, 4:7], disp, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(said["disp_end_m"], disp[-1], rtol=1e-9, atol=1e-12)
    assert said["output"] == str(d / "s.csv")


def test_streamed_evaluate_refuses_a_moving_session(tmp_path):
    """The knock the session was given (+0.3 g at 35.0-35.4 s, in a late block) is named, one line."""
    path = _static_mcap(tmp_path / "m.mcap", seed=6, bump_at_s=35.0)
    with pytest.raises(InputError) as streamed:
        run_evaluate_report(path, [])
    msg = str(streamed.value)
    assert "\n" not in msg and str(path) in msg and "labelled static but moves at t = " in msg
    lo, hi = (float(x) for x in msg.split("moves at t = ")[1].split()[0].rstrip("s:,").split("-"))
    assert lo <= 35.4 and hi >= 35.0 and hi - lo <= 2.0, msg  # the window that holds the knock


def test_integrate_a_csv_input_with_a_calibration(sessions, tmp_path, capsys):
    """A CSV input is one block in memory; its CSV rows end at the displacement the JSON reports
    (this ended in a traceback when the calibration was given)."""
    s = synth_session(poses=["+z"], hold_s=20.0, move_s=0.0, rate_hz=200.0, seed=9)
    rows = "\n".join(
        f"{t:.6f},{x:.9f},{y:.9f},{z:.9f}" for t, (x, y, z) in zip(s.t_s, s.accel_g, strict=True)
    )
    (tmp_path / "s.csv").write_text("Static. Z up.\ntime (s)x (g),y (g),z (g)\n" + rows + "\n")
    out = tmp_path / "o.csv"
    args = [
        "integrate",
        str(tmp_path / "s.csv"),
        "--cal",
        str(sessions / "m3.json"),
        "-o",
        str(out),
        "--json",
    ]
    assert main(args) == 0
    res = json.loads(capsys.readouterr().out)
    got = np.loadtxt(out, delimiter=",", skiprows=1)
    assert got.shape == (s.n, 7)
    np.testing.assert_allclose(got[-1, 4:], res["disp_end_m"], rtol=1e-8, atol=1e-12)
    assert abs(got[-1, 6]) > 0.0


def test_unlabelled_static_file_evaluated_in_one_pass(tmp_path, monkeypatch):
    """An unlabelled static file (an `import csv` output): the up vector is guessed from its first
    block's mean reading and checked against the pass's own mean, so the file is read once; a guess
    the whole mean contradicts (+x up for the first 100 s, +z for the 300 s after) costs a second
    pass and gives the numbers of the session in memory."""
    import accellog.store.source as source
    from accellog.navigate.evaluate import Target, evaluate, evaluate_blocks
    from accellog.store.reader import read_session
    from accellog.store.source import open_source

    done: list[int] = []
    real = source.iter_imu

    def counted(path):
        yield from real(path)
        done.append(1)  # a pass that read the file to its end

    monkeypatch.setattr(source, "iter_imu", counted)
    rng = np.random.default_rng(5)
    for first_face, passes in (([0.0, 0.0, 1.0], 1), ([1.0, 0.0, 0.0], 2)):
        f = np.tile([0.0, 0.0, 1.0], (400_000, 1))
        f[:100_000] = first_face
        s = synth_session(poses=["+z"], hold_s=1.0, move_s=0.0, label=False)  # the meta of a logger
        acc = f + rng.normal(0.0, 0.002, f.shape)
        path = tmp_path / f"static_{passes}.mcap"
        write_session(path, s.__class__(meta=s.meta, t_s=np.arange(f.shape[0]) * 1e-3,
                                        sample_index=np.arange(f.shape[0], dtype=np.int64), accel_g=acc))  # fmt: skip
        done.clear()
        (ev,) = evaluate_blocks(open_source(path), [Target(None)], check_moving=False)
        assert len(done) == passes
        whole = evaluate(read_session(path), None, check_moving=False)
        assert list(ev.up_sensor) == list(whole.up_sensor) == [0, 0, 1]
        assert_json_close(json.loads(dumps(ev.to_dict())), json.loads(dumps(whole.to_dict())))
