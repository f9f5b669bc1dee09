"""Noise statistics of a static hold: autocorrelation-aware standard error of the mean.

Successive MEMS samples are not independent (the digital low-pass filter, slow drifts), so the
naive standard error std/sqrt(n) is too small. With the integrated autocorrelation time

    tau = 1 + 2 sum_{k>=1} rho_k            (samples; rho_k = autocorrelation at lag k)

the effective sample size is n_eff = n / tau and the standard error of the mean is

    sem = std * sqrt(tau / n).

tau is estimated with Sokal's automatic window (smallest M with M >= c * tau(M)); batch means
(`batch_means_sem`) give an independent check. All functions work column-wise on (n,) or (n,k)
arrays in any unit; the result has the unit of the input.
"""

from __future__ import annotations

import numpy as np

SOKAL_C = 5.0
"""Window factor of Sokal's automatic windowing (5 is the usual choice)."""


BLOCK = 16384
"""Samples per block when long series are autocorrelated block-wise (lags < BLOCK)."""

BLOCK_GROUP = 8
"""Blocks transformed at a time: the spectra of a 600 s hold at 1 kHz all at once peaked at 57 MB,
8 at a time 13 MB (and 4x less CPU: no complex product of the whole set)."""


def autocorrelation(
    x: np.ndarray, block: int = BLOCK, mean: np.ndarray | None = None, centred: bool = False
) -> np.ndarray:
    """Normalised autocorrelation rho_k of each column of x (FFT, zero padded).

    Series longer than 2 * block use summed block spectra (non-overlapping blocks, all centred on
    the global mean, BLOCK_GROUP at a time): lags k < block, O(n log block) instead of O(n log n). A column with zero
    variance (e.g. a constant quantised reading) gets rho = (1, 0, 0, ...). mean: x.mean(axis=0)
    when the caller has it already (the same values, not computed again); centred: x is x - mean
    already (the caller's, not made again).
    """
    x = np.asarray(x, float)
    squeeze = x.ndim == 1
    x2 = x[:, None] if squeeze else x
    n = x2.shape[0]
    mean = None if centred else (x2.mean(axis=0) if mean is None else np.asarray(mean, float).reshape(-1))
    xc = x2 if mean is None else x2 - mean
    if n > 2 * block:
        power = None  # summed |rfft|^2 of the blocks, BLOCK_GROUP blocks at a time
        for i in range(0, n // block, BLOCK_GROUP):
            j = min(n // block, i + BLOCK_GROUP)
            spec = np.fft.rfft(xc[i * block : j * block].reshape(j - i, block, -1), n=2 * block, axis=1)
            p = (spec.real**2 + spec.imag**2).sum(axis=0)
            power = p if power is None else power + p
        acov = np.fft.irfft(power, n=2 * block, axis=0)[:block]
    else:
        nfft = 1 << int(np.ceil(np.log2(max(2 * n - 1, 1))))
        spec = np.fft.rfft(xc, n=nfft, axis=0)
        acov = np.fft.irfft((spec * np.conj(spec)).real, n=nfft, axis=0)[:n]
    var0 = acov[0]
    ok = var0 > 1e-300
    rho = np.zeros_like(acov)
    rho[:, ok] = acov[:, ok] / var0[ok]
    rho[0, :] = 1.0
    return rho[:, 0] if squeeze else rho


def integrated_autocorr_time(
    x: np.ndarray, c: float = SOKAL_C, mean: np.ndarray | None = None, centred: bool = False
) -> float | np.ndarray:
    """Integrated autocorrelation time tau (samples, >= 1) of each column, Sokal's window.

    tau(M) = 1 + 2 sum_{k=1..M} rho_k; M = smallest lag with M >= c * tau(M). Returns a float for
    1-D input, an array (k,) for (n,k) input. mean, centred: as for autocorrelation.
    """
    x = np.asarray(x, float)
    squeeze = x.ndim == 1
    tau = tau_from_rho(autocorrelation(x[:, None] if squeeze else x, mean=mean, centred=centred), c)
    return float(tau[0]) if squeeze else tau


def tau_from_rho(rho: np.ndarray, c: float = SOKAL_C) -> np.ndarray:
    """Sokal's windowed tau (k,) from autocorrelations rho (lags, k) (see integrated_autocorr_time)."""
    n = rho.shape[0]
    if n < 3:
        return np.ones(rho.shape[1])
    taus = 2.0 * np.cumsum(rho, axis=0) - 1.0  # tau(M) for M = 0..n-1
    lags = np.arange(n)[:, None]
    ok = lags >= c * taus
    first = np.where(ok.any(axis=0), ok.argmax(axis=0), n - 1)
    return np.maximum(taus[first, np.arange(rho.shape[1])], 1.0)


def sem_autocorr(
    x: np.ndarray, quantum: float = 0.0, c: float = SOKAL_C, tau: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(sem, tau): autocorrelation-aware standard error of the column means, sem = std sqrt(tau/n).

    quantum: resolution of the data (e.g. 1/16384 g); the sem is floored at quantum/sqrt(12 n) so a
    constant quantised column never claims a zero uncertainty. tau: integrated_autocorr_time(x, c)
    when the caller has it (the same values, not computed again).
    """
    x = np.asarray(x, float)
    n = x.shape[0]
    tau_a = np.asarray(integrated_autocorr_time(x, c=c) if tau is None else tau)
    std = x.std(axis=0, ddof=1) if n > 1 else np.zeros(x.shape[1:])
    sem = std * np.sqrt(tau_a / max(n, 1))
    floor = quantum / np.sqrt(12.0 * max(n, 1))
    return np.maximum(sem, floor), tau_a


def batch_means_sem(x: np.ndarray, n_batches: int = 20) -> np.ndarray:
    """Standard error of the mean by non-overlapping batch means: std(batch means) / sqrt(B).

    Valid when each batch is much longer than tau; a cross-check of `sem_autocorr`.
    """
    x = np.asarray(x, float)
    n = x.shape[0]
    b = max(min(n_batches, n), 2)
    m = n // b
    if m < 1:
        return np.full(x.shape[1:], np.nan)
    means = x[: m * b].reshape(b, m, *x.shape[1:]).mean(axis=1)
    return means.std(axis=0, ddof=1) / np.sqrt(b)
