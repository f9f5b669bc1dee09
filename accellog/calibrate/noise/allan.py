"""Overlapping Allan deviation, accumulated chunk by chunk with bounded memory, and its confidence intervals.

A rate signal y_k (k = 0..n-1, any unit u, sample period tau0 s) is integrated to the phase
x_0 = 0, x_{k+1} = x_k + (y_k - c) tau0 (c: a constant offset, the mean of the first chunk, which keeps x
small; a constant cannot change the Allan variance). With N = n + 1 phase points and tau = m tau0
(NIST SP 1065 eq. 11, the estimator of ``allantools.oadev``):

    AVAR(tau) = 1 / (2 tau^2 (N - 2m)) * sum_{j=0}^{N-2m-1} (x_{j+2m} - 2 x_{j+m} + x_j)^2      (u^2)

``AllanAccumulator`` evaluates it for the octave factors m = 1, 2, 4, ... while the data stream in:

- m <= ``m_exact`` (default 2^18): exactly, from a ring of the last 2 m_exact phase points (the sums of
  squares are accumulated as each chunk arrives);
- m > m_exact: from the phase points on a grid of stride D = ``decimate`` (default 1024 samples), i.e.
  the same sum over the start points j that are multiples of D (still m / D >= 256 overlapping
  estimates per tau). Reported with ``stride`` = D so that nothing pretends to be the full estimator.

Memory: 2 m_exact + chunk + n / D phase points per column (about 25 MB for 6 columns at the defaults,
whatever the session length). Equivalent degrees of freedom use the simple formulas of NIST SP 1065
Table 5 (``edf_simple``) for the noise type alpha dominating at each tau; the confidence interval of
AVAR is AVAR edf / chi2_{edf}(1 - p/2) .. AVAR edf / chi2_{edf}(p/2).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from accellog.core.numeric import chi2_ppf

M_EXACT = 1 << 18
"""Largest averaging factor accumulated exactly (every start point j)."""
DECIMATE = 1 << 10
"""Stride of the phase grid kept for the averaging factors above M_EXACT."""
_SPLIT_MIN = 50_000
"""Chunk length from which the columns are split over two threads."""

ALPHA_WHITE_PM, ALPHA_WHITE_FM, ALPHA_FLICKER_FM, ALPHA_RW_FM = 2, 0, -1, -2
"""Power-law exponents of the rate PSD S_y(f) ~ f^alpha: quantisation (white phase), white noise (VRW/ARW),
flicker (bias instability), random walk (rate random walk)."""


@dataclass
class AllanCurve:
    """Overlapping Allan deviation of k columns at octave taus.

    tau_s (t,), m (t,) averaging factors, adev (t, k) in the unit of the input, n_terms (t,) squared second
    differences summed, stride (t,) 1 where exact, D where on the decimated grid; n_phase: N phase points.
    """

    tau_s: np.ndarray
    m: np.ndarray
    adev: np.ndarray
    n_terms: np.ndarray
    stride: np.ndarray
    n_phase: int
    rate_hz: float

    @property
    def avar(self) -> np.ndarray:
        return self.adev**2

    def edf(self, alpha: np.ndarray) -> np.ndarray:
        """(t, k) equivalent degrees of freedom for noise types alpha (t, k) (NIST SP 1065 Table 5)."""
        return edf_simple(self.n_phase, self.m[:, None], np.asarray(alpha))

    def interval(self, alpha: np.ndarray, p: float = 0.3173) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) two-sided (1 - p) confidence interval of the ADEV (default 68.3 %, i.e. 1 sigma)."""
        edf = np.maximum(self.edf(alpha), 1.0)
        lo = self.avar * edf / chi2_ppf(1.0 - p / 2.0, edf)
        hi = self.avar * edf / chi2_ppf(p / 2.0, edf)
        return np.sqrt(lo), np.sqrt(hi)


def edf_simple(n_phase: int, m: float | np.ndarray, alpha: int | np.ndarray) -> np.ndarray:
    """Equivalent degrees of freedom of the overlapping AVAR (NIST SP 1065 Table 5), vectorised.

    n_phase: N phase points; m: averaging factor; alpha: 2 (white PM), 0 (white FM), -1 (flicker FM),
    -2 (random-walk FM). Same formulas as ``allantools.edf_simple``. Floored at 1.
    """
    N = float(n_phase)
    m, alpha = np.broadcast_arrays(np.asarray(m, float), np.asarray(alpha))
    out = np.full(m.shape, N - 1.0)
    wp = (N + 1) * (N - 2 * m) / (2 * (N - m))
    wf = ((3 * (N - 1) / (2 * m)) - (2 * (N - 2) / N)) * (4 * m**2 / (4 * m**2 + 5))
    ff = np.where(m == 1, 2 * (N - 2) / (2.3 * N - 4.9), 5 * N**2 / (4 * m * (N + 3 * m)))
    rf = (N - 2) / (m * (N - 3) ** 2) * ((N - 1) ** 2 - 3 * m * (N - 1) + 4 * m**2)
    for a, v in ((2, wp), (0, wf), (-1, ff), (-2, rf)):
        out = np.where(alpha == a, v, out)
    return np.maximum(out, 1.0)


class AllanAccumulator:
    """Streaming overlapping AVAR of k columns: ``add`` chunks (n_i, k) of the rate, then ``curve()``."""

    def __init__(
        self, rate_hz: float, n_cols: int, *, m_exact: int = M_EXACT, decimate: int = DECIMATE
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz={rate_hz} must be > 0")
        if m_exact < 1 or m_exact & (m_exact - 1) or decimate < 1 or decimate & (decimate - 1):
            raise ValueError("m_exact and decimate must be powers of two")
        self.rate_hz, self.k = float(rate_hz), int(n_cols)
        self.tau0 = 1.0 / self.rate_hz
        self.m_exact, self.decimate = int(m_exact), int(decimate)
        self.offset: np.ndarray | None = None
        self.n_phase = 1  # x_0 = 0
        # phase kept column-major (k, n): every tau works on contiguous rows
        self._tail = np.zeros((self.k, 1))  # last <= 2 m_exact phase points, from global index _tail_start
        self._tail_start = 0
        self._grid = [np.zeros((self.k, 1))]  # phase at global indices 0, D, 2D, ...
        self._exact_m = [1 << i for i in range(self.m_exact.bit_length())]
        self._sums = np.zeros((len(self._exact_m), self.k))
        self._terms = np.zeros(len(self._exact_m), np.int64)

    def add(self, y: np.ndarray) -> None:
        """Append a chunk (n, k) of the rate (consecutive samples; any unit)."""
        y = np.asarray(y, float)
        if y.ndim == 1:
            y = y[:, None]
        if y.shape[1] != self.k:
            raise ValueError(f"chunk has {y.shape[1]} columns, expected {self.k}")
        n_new = y.shape[0]
        if n_new == 0:
            return
        if self.offset is None:
            self.offset = y.mean(axis=0)
        g_new = self.n_phase  # global index of the chunk's first phase point
        g0, t = self._tail_start, self._tail.shape[1]
        xx = np.empty((self.k, t + n_new))
        xx[:, :t] = self._tail
        new = xx[:, t:]
        np.subtract(y.T, self.offset[:, None], out=new)
        np.cumsum(new, axis=1, out=new)
        new *= self.tau0
        new += self._tail[:, -1:]
        g_end = g_new + n_new
        if (
            self.k > 1 and n_new >= _SPLIT_MIN
        ):  # two halves of the columns on two threads (numpy frees the GIL)
            h = self.k // 2
            with ThreadPoolExecutor(1) as pool:
                other = pool.submit(self._second_differences, xx[:h], slice(0, h), g0, g_new, g_end)
                self._second_differences(xx[h:], slice(h, self.k), g0, g_new, g_end)
                other.result()
        else:
            self._second_differences(xx, slice(0, self.k), g0, g_new, g_end)
        for i, m in enumerate(self._exact_m):
            self._terms[i] += max(0, (g_end - 2 * m) - max(0, g_new - 2 * m))
        first = (-g_new) % self.decimate  # grid points inside the new chunk
        if first < n_new:
            self._grid.append(new[:, first :: self.decimate].copy())
        keep = min(2 * self.m_exact, xx.shape[1])
        self._tail = xx[:, -keep:].copy()
        self._tail_start = g_end - keep
        self.n_phase = g_end

    def _second_differences(self, xx: np.ndarray, cols: slice, g0: int, g_new: int, g_end: int) -> None:
        """Add the squared second differences whose last point j + 2m is new, for columns ``cols``."""
        for i, m in enumerate(self._exact_m):
            j0, j1 = max(0, g_new - 2 * m), g_end - 2 * m
            if j1 <= j0:
                continue
            a, n = j0 - g0, j1 - j0
            d = np.subtract(xx[:, a + 2 * m : a + 2 * m + n], xx[:, a + m : a + m + n])
            d -= xx[:, a + m : a + m + n]
            d += xx[:, a : a + n]
            self._sums[i, cols] += np.einsum("ij,ij->i", d, d)

    def curve(self) -> AllanCurve:
        """The ADEV at every octave factor m with at least 2 second differences."""
        ms, devs, nts, strides = [], [], [], []
        for i, m in enumerate(self._exact_m):
            if self._terms[i] >= 2:
                ms.append(m)
                devs.append(np.sqrt(self._sums[i] / (2.0 * self._terms[i])) / m * self.rate_hz)
                nts.append(int(self._terms[i]))
                strides.append(1)
        grid = np.concatenate(self._grid, axis=1)
        D = self.decimate
        m = 2 * self.m_exact
        while 2 * m < self.n_phase:
            q = m // D
            n = grid.shape[1] - 2 * q
            if n < 2:
                break
            d = grid[:, 2 * q :] - 2.0 * grid[:, q : q + n] + grid[:, :n]
            ms.append(m)
            devs.append(np.sqrt(np.einsum("ij,ij->i", d, d) / (2.0 * n)) / m * self.rate_hz)
            nts.append(n)
            strides.append(D)
            m *= 2
        ms_arr = np.asarray(ms, np.int64)
        return AllanCurve(
            tau_s=ms_arr * self.tau0,
            m=ms_arr,
            adev=np.asarray(devs).reshape(len(ms), self.k),
            n_terms=np.asarray(nts, np.int64),
            stride=np.asarray(strides, np.int64),
            n_phase=self.n_phase,
            rate_hz=self.rate_hz,
        )


def oadev(y: np.ndarray, rate_hz: float, **kw) -> AllanCurve:
    """Overlapping ADEV of a whole rate series y (n,) or (n, k) at octave taus (one chunk)."""
    y = np.asarray(y, float)
    acc = AllanAccumulator(rate_hz, 1 if y.ndim == 1 else y.shape[1], **kw)
    acc.add(y)
    return acc.curve()
