"""core.timeseries.cumtrapz, the one carried trapezoid integrator: scipy's cumulative_trapezoid on the
whole series, and the same bits when the series is fed in blocks with a carry."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid

from accellog.core.timeseries import cumtrapz


@pytest.fixture
def series():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.004, 0.006, 2000))  # uneven stamps (s)
    return t, rng.normal(0.0, 1.0, (t.size, 3))


def test_whole_series_is_scipys_cumulative_trapezoid(series):
    t, a = series
    np.testing.assert_array_equal(cumtrapz(t, a), cumulative_trapezoid(a, t, axis=0, initial=0))


@pytest.mark.parametrize("cuts", [[1], [7, 8, 900], [1999]])
def test_blocks_with_a_carry_give_the_whole_series_bits(series, cuts):
    t, a = series
    start = np.array([0.5, -1.0, 2.0])
    whole = start + cumulative_trapezoid(a, t, axis=0, initial=0)
    pieces, prev, acc = [], None, start
    for sl in np.split(np.arange(t.size), cuts):
        v = cumtrapz(t[sl], a[sl], acc, prev=prev)
        pieces.append(v)
        prev, acc = (t[sl][-1], a[sl][-1]), v[-1]
    got = np.concatenate(pieces)
    np.testing.assert_allclose(got, whole, rtol=0, atol=1e-12)  # scipy adds the start after its sum
    np.testing.assert_array_equal(got, cumtrapz(t, a, start))  # the blocks: the whole series' bits
