"""observations computes each hold's mean once and hands it to the checks, the window statistics and
the autocorrelation: every result is exactly (bit for bit) what each computes from the samples."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.sessions import synth_session

from accellog.calibrate.observe.hold_noise import BLOCK, autocorrelation, integrated_autocorr_time
from accellog.calibrate.observe.label_check import label_mismatches
from accellog.calibrate.observe.segment import observations, window_stats
from accellog.core.errors import InputError


def _holds(s, trim_s: float = 0.5) -> list:
    """(label, sample slice) of every hold trimmed by trim_s (s), in time order."""
    return [
        (p, s.slice_time(p.start_s + trim_s, p.end_s - trim_s))
        for p in sorted(s.poses, key=lambda p: p.start_s)
    ]


@pytest.mark.parametrize("n", [50, 2 * BLOCK + 7])  # one FFT, and block spectra
def test_given_mean_is_the_computed_one(n):
    x = np.random.default_rng(3).normal(size=(n, 3)).cumsum(axis=0) * 1e-4 + 1.0
    m = x.mean(axis=0)
    assert np.array_equal(autocorrelation(x, mean=m), autocorrelation(x))
    assert np.array_equal(integrated_autocorr_time(x, mean=m), integrated_autocorr_time(x))
    x0 = x[:, 0]  # 1-D: its own mean (a pairwise sum, not the column's sum above)
    assert integrated_autocorr_time(x0, mean=x0.mean(axis=0)) == integrated_autocorr_time(x0)
    starts = np.arange(0, n, 17)
    for a, b in zip(window_stats(x, starts, m), window_stats(x, starts), strict=True):
        assert np.array_equal(a, b)


def test_observations_rows_from_each_hold_alone():
    s = synth_session(hold_s=12.0, seed=4)
    obs = observations(s, window_s=2.0)
    i = 0
    for _p, sl in _holds(s):
        acc, t = s.accel_g[sl], s.t_s[sl]
        nwin = max(1, int(np.floor((t[-1] - t[0]) / 2.0 + 1e-9)))
        starts = np.unique(np.searchsorted(t, t[0] + (t[-1] - t[0]) * np.arange(nwin) / nwin))
        mean, std, n = window_stats(acc, starts)  # each from the samples, no shared mean
        tau = integrated_autocorr_time(acc)
        k = len(starts)
        assert np.array_equal(obs.meas_g[i : i + k], mean)
        assert np.array_equal(
            obs.sigma_g[i : i + k] >= std * np.sqrt(tau / n[:, None]), np.ones((k, 3), bool)
        )
        i += k
    assert i == obs.meas_g.shape[0]


def test_label_check_with_shared_means():
    s = synth_session(hold_s=12.0, seed=5)
    holds = _holds(s)
    means = [s.accel_g[sl].mean(axis=0) for _p, sl in holds]
    assert label_mismatches(s, holds) == label_mismatches(s, holds, means=means) == []
    swapped = [dataclasses.replace(p, up_sensor=-np.asarray(p.up_sensor, float)) for p in s.poses]
    s.poses = swapped  # every label upside down: each hold is named, with or without the means
    holds = _holds(s)
    means = [s.accel_g[sl].mean(axis=0) for _p, sl in holds]
    bad = label_mismatches(s, holds, means=means)
    assert bad == label_mismatches(s, holds) and len(bad) == len(holds)
    with pytest.raises(
        InputError, match=r"pose .\+z. .*measured gravity is 1[78]\d deg from the label.*and 5 more holds"
    ):
        observations(s)


def test_non_finite_sample_named_with_its_time():
    s = synth_session(hold_s=12.0, seed=6)
    _p, sl = _holds(s)[2]
    i = sl.start + 100
    s.accel_g[i, 1] = np.nan
    s.accel_g[i + 5, 2] = np.inf
    with pytest.raises(InputError, match=rf"accel is NaN/inf at t = {s.t_s[i]:.3f} s \(2 bad samples\)"):
        observations(s)
