"""A hold longer than the reduction's chunk and than what a file's pass keeps in memory (the rest
spilled to a temporary file) gives what plain numpy computes from the whole hold: window means
and standard deviations, the autocorrelation time (summed block autocovariance about the hold's
mean), the PoseStats; and the spill gives back the samples bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from support.sessions import synth_session

from accellog.calibrate.observe import stream_segment
from accellog.calibrate.observe.hold_noise import BLOCK, tau_from_rho
from accellog.calibrate.observe.holds import CHUNK_ROWS, HoldSamples
from accellog.calibrate.observe.segment import observations, pose_stats
from accellog.store.reader import read_session
from accellog.store.writer import write_session

TRIM_S = 0.5


def test_spilled_samples_come_back_bit_for_bit_in_aligned_chunks():
    rng = np.random.default_rng(1)
    n = 2 * CHUNK_ROWS + 1234
    t, acc, temp = np.arange(n) * 1e-3, rng.normal(size=(n, 3)), rng.normal(size=n)
    for with_temp in (True, False):
        hs = HoldSamples(spill_rows=50_000)
        for sl in (slice(0, 7), slice(7, 40_000), slice(40_000, 60_001), slice(60_001, n)):
            hs.add(t[sl], acc[sl], temp[sl] if with_temp else None)
        assert hs.spill is not None and hs.parts == []
        got = list(hs.chunks())
        assert [len(c[0]) for c in got] == [CHUNK_ROWS, CHUNK_ROWS, 1234]
        np.testing.assert_array_equal(np.concatenate([c[0] for c in got]), t)
        np.testing.assert_array_equal(np.concatenate([c[1] for c in got]), acc)
        if with_temp:
            np.testing.assert_array_equal(np.concatenate([c[2] for c in got]), temp)
        else:
            assert all(c[2] is None for c in got)
        hs.close()
    kept = HoldSamples(spill_rows=None)  # in memory: pieces joined across their boundaries
    for sl in (slice(0, 100_000), slice(100_000, n)):
        kept.add(t[sl], acc[sl], temp[sl])
    assert kept.spill is None
    np.testing.assert_array_equal(np.concatenate([c[1] for c in kept.chunks()]), acc)


def _numpy_tau(x: np.ndarray) -> np.ndarray:
    """Sokal's tau from the autocovariance summed over non-overlapping BLOCK-blocks of x centred
    on its mean, each block's by its own zero-padded FFT (plain numpy)."""
    xc = x - x.mean(axis=0)
    acov = np.zeros((BLOCK, 3))
    for i in range(len(x) // BLOCK):
        f = np.fft.rfft(xc[i * BLOCK : (i + 1) * BLOCK], 2 * BLOCK, axis=0)
        acov += np.fft.irfft(np.abs(f) ** 2, 2 * BLOCK, axis=0)[:BLOCK]
    return tau_from_rho(acov / acov[0])


@pytest.fixture(scope="module")
def long_holds(tmp_path_factory):
    """Three 140 s holds at 1 kHz (~140 k samples each: more than one chunk) in an MCAP file."""
    s = synth_session(poses=["+z", "-z", "+x"], hold_s=140.0, rate_hz=1000.0, seed=8)
    p = tmp_path_factory.mktemp("long") / "long.mcap"
    write_session(p, s)
    return p


@pytest.mark.parametrize("spill", [True, False])
def test_long_holds_equal_plain_numpy(long_holds, monkeypatch, spill):
    monkeypatch.setattr(stream_segment, "SPILL_ROWS", 50_000 if spill else 1 << 30)
    stats: list = []
    obs = observations(long_holds, window_s=2.0, trim_s=TRIM_S, stats_out=stats)
    s = read_session(long_holds)
    i = 0
    for p, ps in zip(sorted(s.poses, key=lambda p: p.start_s), stats, strict=True):
        keep = (s.t_s >= p.start_s + TRIM_S) & (s.t_s < p.end_s - TRIM_S)
        t, acc = s.t_s[keep], s.accel_g[keep]
        assert len(t) > CHUNK_ROWS
        nwin = int(np.floor((t[-1] - t[0]) / 2.0 + 1e-9))
        starts = np.unique(np.searchsorted(t, t[0] + (t[-1] - t[0]) * np.arange(nwin) / nwin))
        pieces = np.split(np.arange(len(t)), starts[1:])
        k = len(pieces)
        np.testing.assert_allclose(obs.meas_g[i : i + k], [acc[j].mean(axis=0) for j in pieces], rtol=1e-13)
        std = np.array([acc[j].std(axis=0, ddof=1) for j in pieces])
        np.testing.assert_allclose(obs.std_g[i : i + k], std, rtol=1e-9)
        n = np.array([len(j) for j in pieces])[:, None]
        np.testing.assert_allclose(obs.sigma_g[i : i + k], std * np.sqrt(_numpy_tau(acc) / n), rtol=1e-9)
        np.testing.assert_allclose(obs.t_s[i : i + k], [t[j].mean() for j in pieces], rtol=1e-13)
        np.testing.assert_allclose(ps.mean_g, acc.mean(axis=0), rtol=1e-13)
        np.testing.assert_allclose(ps.std_g, acc.std(axis=0, ddof=1), rtol=1e-9)
        np.testing.assert_allclose(ps.tau_samples, _numpy_tau(acc), rtol=1e-9)
        assert ps.n == len(t) and ps.start_s == t[0] and ps.end_s == t[-1]
        i += k
    assert i == len(obs.meas_g)
    whole = pose_stats(s)  # the session in memory (one block, never spilled)
    for a, b in zip(whole, stats, strict=True):
        np.testing.assert_allclose(a.sem_g, b.sem_g, rtol=1e-9)
