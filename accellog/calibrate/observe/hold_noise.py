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

    Series longer than 2 * block use summed block spectra (``AutocorrTime``: non-overlapping
    blocks, all centred on the global mean): lags k < block, O(n log block) instead of O(n log n).
    A column with zero variance (e.g. a constant quantised reading) gets rho = (1, 0, 0, ...).
    mean: x.mean(axis=0) when the caller has it already (the same values, not computed again);
    centred: x is x - mean already (the caller's, not made again).
    """
    x = np.asarray(x, float)
    squeeze = x.ndim == 1
    x2 = x[:, None] if squeeze else x
    n = x2.shape[0]
    mean = None if centred else (x2.mean(axis=0) if mean is None else np.asarray(mean, float).reshape(-1))
    xc = x2 if mean is None else x2 - mean
    if n > 2 * block:
        acc = AutocorrTime(block)
        for i in range(0, n, block * BLOCK_GROUP):
            acc.add(xc[i : i + block * BLOCK_GROUP])
        rho = acc.rho()
    else:
        nfft = 1 << int(np.ceil(np.log2(max(2 * n - 1, 1))))
        spec = np.fft.rfft(xc, n=nfft, axis=0)
        rho = _normalised(np.fft.irfft((spec * np.conj(spec)).real, n=nfft, axis=0)[:n])
    return rho[:, 0] if squeeze else rho


def _normalised(acov: np.ndarray) -> np.ndarray:
    """rho = acov / acov[0] per column (rho = (1, 0, ...) for a column of zero variance)."""
    var0 = acov[0]
    ok = var0 > 1e-300
    rho = np.zeros_like(acov)
    rho[:, ok] = acov[:, ok] / var0[ok]
    rho[0, :] = 1.0
    return rho


class AutocorrTime:
    """The autocorrelation (``rho``) and integrated autocorrelation time (``tau``) of a (n,k) series
    fed in consecutive pieces, in memory bounded by BLOCK_GROUP blocks whatever n.

    For n > 2 B (B = block) the autocovariance is summed over non-overlapping B-blocks centred on
    the global mean m, which is only known at the end; with y = x - c (c: the first piece's mean,
    so no cancellation) and m' = m - c,

        sum_j (y_j - m')(y_{j+k} - m') = Syy(k) - m' (P(k) + Q(k)) + m'^2 (B - k)

    (pairs inside one block; P(k) = sum_{j<B-k} y_j, Q(k) = sum_{j>=k} y_j), so Syy (summed block
    power spectra), P and Q accumulate and m' enters at the end. Up to 2 B samples are kept until
    the series is known to be long (a short one: one FFT of it all, ``autocorrelation``)."""

    def __init__(self, block: int = BLOCK, c: float = SOKAL_C) -> None:
        self.block, self.c = block, c
        self.pending: list[np.ndarray] = []
        self.n_pending = 0
        self.n = 0
        self.shift: np.ndarray | None = None
        self.total: np.ndarray | None = None  # sum of y over every sample (remainder included)
        self.nb = 0
        self.spec: np.ndarray | None = None  # (B+1, k) summed |rfft|^2 of the blocks
        self.ysum: np.ndarray | None = None  # (B, k) summed blocks
        self.long = False

    def add(self, x: np.ndarray) -> None:
        x = np.asarray(x, float)
        if x.shape[0] == 0:
            return
        if self.shift is None:
            self.shift = x.mean(axis=0)
            self.total = np.zeros(x.shape[1])
        y = x - self.shift  # pending samples are kept shifted
        self.n += x.shape[0]
        self.total += y.sum(axis=0)
        self.pending.append(y)
        self.n_pending += x.shape[0]
        if not self.long and self.n_pending > 2 * self.block:
            self.long = True
        if self.long and self.n_pending >= self.block:
            self._blocks()

    def _blocks(self) -> None:
        """Fold every complete B-block of the pending samples into the sums, BLOCK_GROUP at a time."""
        buf = np.concatenate(self.pending) if len(self.pending) > 1 else self.pending[0]
        b = self.block
        nb = buf.shape[0] // b
        if self.spec is None or self.ysum is None:
            self.spec = np.zeros((b + 1, buf.shape[1]))
            self.ysum = np.zeros((b, buf.shape[1]))
        for i in range(0, nb, BLOCK_GROUP):
            y = buf[i * b : min(nb, i + BLOCK_GROUP) * b].reshape(-1, b, buf.shape[1])
            s = np.fft.rfft(y, n=2 * b, axis=1)  # (blocks, b + 1, k)
            self.spec += (s.real * s.real + s.imag * s.imag).sum(axis=0)  # |s|^2
            self.ysum += y.sum(axis=0)  # P and Q are linear in y: built from the block sum at the end
        self.nb += nb
        rest = buf[nb * b :].copy()  # not a view: buf is freed
        self.pending = [rest] if rest.shape[0] else []
        self.n_pending = rest.shape[0]

    def rho(self) -> np.ndarray:
        """(lags, k) autocorrelation of everything added (autocorrelation's values)."""
        if not self.long:
            return autocorrelation(np.concatenate(self.pending), self.block)  # its own mean
        if self.total is None or self.spec is None or self.ysum is None:
            raise RuntimeError("long mode without folded blocks")
        b = self.block
        m = self.total / self.n
        syy = np.fft.irfft(self.spec, n=2 * b, axis=0)[:b]
        lags = np.arange(b, dtype=float)[:, None]
        cs = np.cumsum(self.ysum, axis=0)  # summed over blocks: cs[j] = sum_b sum_{i<=j} y_bi
        p = cs[::-1]  # P(k) = cs[B-1-k]
        q = cs[-1] - np.concatenate([np.zeros((1, cs.shape[1])), cs[:-1]])  # Q(k) = total - cs[k-1]
        return _normalised(syy - m * (p + q) + m * m * (b - lags) * self.nb)

    def tau(self) -> np.ndarray:
        """(k,) tau in samples, >= 1 (integrated_autocorr_time of everything added)."""
        return tau_from_rho(self.rho(), self.c)


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
    return sem_of(std, tau_a, n, quantum), tau_a


def sem_of(std: np.ndarray, tau: np.ndarray, n: int, quantum: float = 0.0) -> np.ndarray:
    """sem = std sqrt(tau / n), floored at quantum / sqrt(12 n) (sem_autocorr from its parts)."""
    sem = std * np.sqrt(tau / max(n, 1))
    return np.maximum(sem, quantum / np.sqrt(12.0 * max(n, 1)))


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
