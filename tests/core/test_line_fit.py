"""core.timeseries.LineFit fed in blocks is numpy's least-squares line of all the points at once,
also for a 24 h host clock (x up to 86 400 s, 50 ppm slope, 20 us of jitter: the residuals are
1e-10 of the values)."""

from __future__ import annotations

import numpy as np
import pytest

from accellog.core.timeseries import LineFit


@pytest.mark.parametrize("cuts", [[], [1], [7, 8, 5000], list(range(100, 90_000, 997))])
def test_line_fit_in_blocks_is_numpys(cuts):
    rng = np.random.default_rng(len(cuts))
    x = np.sort(rng.uniform(0.0, 86_400.0, 100_000))
    y = 50e-6 * x + 0.3 + rng.normal(0.0, 20e-6, x.size)
    line = LineFit()
    for a, b in zip([0, *cuts], [*cuts, x.size], strict=True):
        line.add(x[a:b], y[a:b])
    (slope, c), rss, *_ = np.linalg.lstsq(np.stack([x, np.ones_like(x)], axis=1), y, rcond=None)
    assert line.count == x.size
    assert line.slope == pytest.approx(slope, rel=1e-9)
    assert line.residual_ss == pytest.approx(rss[0], rel=1e-9)
    assert line.intercept == pytest.approx(c, rel=1e-9)


def test_line_fit_without_spread_has_no_slope():
    line = LineFit()
    line.add([2.0, 2.0], [1.0, 3.0])
    assert np.isnan(line.slope) and np.isnan(line.residual_ss)
