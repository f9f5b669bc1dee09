"""noise: integrated autocorrelation time and standard errors on seeded AR(1) series."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from accellog.calibrate.observe.hold_noise import (
    autocorrelation,
    batch_means_sem,
    integrated_autocorr_time,
    sem_autocorr,
)


def _ar1(phi: float, n: int, k: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return lfilter([1.0], [1.0, -phi], rng.normal(0, 1, (n, k)), axis=0)


def test_tau_of_ar1_matches_theory():
    for phi in (0.0, 0.5, 0.8):
        x = _ar1(phi, 40000, 3, seed=int(phi * 10))
        tau = integrated_autocorr_time(x)
        assert np.allclose(tau, (1 + phi) / (1 - phi), rtol=0.15), (phi, tau)


def test_sem_covers_the_spread_of_means():
    """Over 400 independent AR(1) runs the sem predicts the scatter of the run means."""
    phi = 0.7
    x = _ar1(phi, 2000 * 400, 1, seed=3).reshape(400, 2000)
    means = x.mean(axis=1)
    sems = np.array([sem_autocorr(r[:, None])[0][0] for r in x[:50]])
    assert np.median(sems) == np.clip(np.median(sems), 0.7 * means.std(), 1.3 * means.std())
    naive = x[:50].std(axis=1).mean() / np.sqrt(2000)
    assert naive < 0.6 * means.std()  # the naive error is far too small
    bm = batch_means_sem(x[0][:, None])[0]
    assert 0.5 * means.std() < bm < 1.6 * means.std()


def test_constant_column_is_floored_by_quantum():
    x = np.full((1000, 2), 0.5)
    rho = autocorrelation(x)
    assert rho[0, 0] == 1.0 and np.all(rho[1:] == 0)
    sem, tau = sem_autocorr(x, quantum=1 / 16384)
    assert np.allclose(tau, 1.0)
    assert np.allclose(sem, (1 / 16384) / np.sqrt(12 * 1000))
