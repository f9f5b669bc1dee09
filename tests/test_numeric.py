"""core.numeric: the chi-square survival function against scipy's, the small least squares against
scipy's on a nonlinear problem (and at the optimum: no Gauss-Newton step left)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import least_squares as scipy_lsq
from scipy.special import chdtrc

from accellog.core.numeric import chi2_sf, least_squares


@pytest.mark.parametrize("k", [0.5, 1, 2, 3, 7, 19, 20, 21, 40, 101, 1000, 5280, 20000, 1e6])
def test_chi2_sf_equals_scipy(k):
    rng = np.random.default_rng(int(k * 10) % 1000)
    xs = [k * math.exp(u) for u in rng.uniform(-4.0, 1.2, 40)] + [k - 1.0, k, k + 1.0, k + 2.0, 1e-3]
    for x in xs:
        if x <= 0:
            continue
        want = float(chdtrc(k, x))
        if want < 1e-250:
            continue
        assert chi2_sf(x, k) == pytest.approx(want, rel=1e-10, abs=0), (k, x)


def test_chi2_sf_edges():
    assert chi2_sf(0.0, 3) == 1.0 and chi2_sf(math.inf, 3) == 0.0
    assert math.isnan(chi2_sf(1.0, 0)) and math.isnan(chi2_sf(math.nan, 3))


def test_least_squares_reaches_the_optimum_scipy_approaches():
    """Exponential fit y = a exp(b t) + c: same optimum as scipy's (to scipy's tolerance), and
    converged: the Gauss-Newton step left at the solution is at rounding level."""
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 2.0, 50)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 + rng.normal(0, 0.01, t.size)
    fun = lambda p: p[0] * np.exp(p[1] * t) + p[2] - y  # noqa: E731
    jac = lambda p: np.column_stack([np.exp(p[1] * t), p[0] * t * np.exp(p[1] * t), np.ones_like(t)])  # noqa: E731
    x0 = np.array([1.0, 0.0, 0.0])
    ours = least_squares(fun, jac, x0, x_scale=0.1)
    ref = scipy_lsq(fun, x0, jac=jac, x_scale=0.1, ftol=1e-15, xtol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(ours.x, ref.x, rtol=1e-9)
    step = np.linalg.lstsq(ours.jac, -ours.fun, rcond=None)[0]
    assert np.all(np.abs(step) <= 1e-12 * np.maximum(np.abs(ours.x), 0.1))
    np.testing.assert_array_equal(ours.fun, fun(ours.x))
    np.testing.assert_array_equal(ours.jac, jac(ours.x))


def test_fit_command_imports_no_scipy(tmp_path):
    """`accellog fit` (accelerometer model3 + gyro) runs without importing scipy (its start-up)."""
    import subprocess
    import sys

    from accellog.flows.simulate import Scenario, simulate

    p = tmp_path / "s.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0), p)
    code = (
        "import sys; from accellog.cli import main; rc = main(['fit', sys.argv[1], '-o', sys.argv[2]]);"
        "sys.exit(rc or 3 * any(m == 'scipy' or m.startswith('scipy.') for m in sys.modules))"
    )
    r = subprocess.run(
        [sys.executable, "-c", code, str(p), str(tmp_path / "c.json")], capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "c.json").exists()
