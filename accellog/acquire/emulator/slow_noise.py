"""Slow bias noise of the emulated sensors: bias instability (flicker) and rate random walk, keyed by sample index.

Both are recursive (the value at sample j depends on every earlier sample), yet the emulator asks for
arbitrary index ranges; ``MarkovBank`` therefore keeps the state at the start of every block of
``BLOCK`` samples (computed forward once, reused), so any split of the stream gives the same values.

- Rate random walk K (u/s/sqrt(Hz)): b_{j+1} = b_j + K sqrt(tau0) w_j; AVAR = K^2 tau / 3.
- Bias instability B (u): flicker noise S(f) = h_{-1} / f (one-sided), h_{-1} = B^2 / pi, so that the
  AVAR floor is 2 ln 2 h_{-1} = (2 ln 2 / pi) B^2 (ADEV = 0.664 B, IEEE Std 952). Built as a sum of
  first-order Gauss-Markov processes x_{j+1} = phi x_j + sqrt(1 - phi^2) s w_j, phi = exp(-tau0 / T_c),
  with correlation times T_c spaced by a factor r: their summed PSD is (s^2 / ln r) / f between
  1 / (2 pi T_c,max) and 1 / (2 pi T_c,min), hence s^2 = B^2 ln r / pi.
"""

from __future__ import annotations

import math

import numpy as np

BLOCK = 1 << 16
FLICKER_TC_S = tuple(0.03 * math.sqrt(10.0) ** i for i in range(13))
"""Correlation times of the flicker bank (0.03 s .. 3e4 s, ratio sqrt(10)): ADEV flat to 1 % from ~1 s to ~1e3 s."""


class MarkovBank:
    """Sum over P first-order processes x_{j+1} = phi_p x_j + q_p w_j (3 axes each), at any sample index."""

    def __init__(self, seed: int, stream: int, phi: np.ndarray, q: np.ndarray, x0_sigma: np.ndarray) -> None:
        self.seed, self.stream = int(seed), int(stream)
        self.phi = np.asarray(phi, float)  # (P,)
        self.q = np.asarray(q, float)  # (P, 3)
        self.x0_sigma = np.asarray(x0_sigma, float)  # (P, 3): stationary start (0 for a random walk)
        self._state: dict[int, np.ndarray] = {}
        self._blocks: dict[int, np.ndarray] = {}

    def _white(self, b: int) -> np.ndarray:
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([self.seed, self.stream, 7, b])))
        return rng.standard_normal((BLOCK, self.phi.size, 3))

    def _start_state(self, b: int) -> np.ndarray:
        """(P, 3) process values at the first sample of block b (computed forward from the last known)."""
        if not self._state:
            rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([self.seed, self.stream, 8])))
            self._state[0] = rng.standard_normal(self.x0_sigma.shape) * self.x0_sigma
        known = max(k for k in self._state if k <= b)
        for k in range(known, b):
            self._state[k + 1] = self._run(k)[-1]
        return self._state[b]

    def _run(self, b: int) -> np.ndarray:
        """(BLOCK+1, P, 3): state at the block's samples and at the next block's first sample."""
        from scipy.signal import lfilter

        x0 = self._state[b]
        w = self._white(b) * self.q
        out = np.empty((BLOCK + 1, *x0.shape))
        out[0] = x0
        for p, ph in enumerate(self.phi):
            out[1:, p, :], _ = lfilter([1.0], [1.0, -ph], w[:, p, :], axis=0, zi=ph * x0[p][None, :])
        return out

    def _block(self, b: int) -> np.ndarray:
        blk = self._blocks.get(b)
        if blk is None:
            self._start_state(b)
            run = self._run(b)
            self._state[b + 1] = run[-1]
            blk = run[:-1].sum(axis=1)
            if len(self._blocks) >= 4:
                self._blocks.pop(next(iter(self._blocks)))
            self._blocks[b] = blk
        return blk

    def at(self, index: np.ndarray) -> np.ndarray:
        """(n, 3) summed process values at sample indices (n,) >= 0."""
        idx = np.asarray(index, np.int64).reshape(-1)
        if idx.size == 0:
            return np.zeros((0, 3))
        b0, b1 = int(idx.min()) // BLOCK, int(idx.max()) // BLOCK
        parts = np.concatenate([self._block(b) for b in range(b0, b1 + 1)])
        return parts[idx - b0 * BLOCK]


def slow_bias(
    seed: int, stream: int, odr_hz: float, bias_instability: np.ndarray, random_walk: np.ndarray
) -> MarkovBank | None:
    """The bank for per-axis B (u) and K (u/s/sqrt(Hz)) at output rate odr_hz; None if both are zero."""
    B, K = np.asarray(bias_instability, float), np.asarray(random_walk, float)
    if not (np.any(B) or np.any(K)):
        return None
    tau0 = 1.0 / odr_hz
    ratio = math.sqrt(10.0)
    s = B * math.sqrt(math.log(ratio) / math.pi)
    phi = [math.exp(-tau0 / tc) for tc in FLICKER_TC_S]
    q = [np.sqrt(1.0 - ph**2) * s for ph in phi]
    x0 = [s for _ in phi]
    phi.append(1.0)
    q.append(K * math.sqrt(tau0))
    x0.append(np.zeros(3))
    return MarkovBank(seed, stream, np.array(phi), np.array(q), np.array(x0))
