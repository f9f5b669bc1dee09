"""The same observations give the same fit, bit for bit, whatever the process's heap holds.

The case: six poses with a hidden nonlin2, fitted with model3 + nonlin2 + warmup. There is no
warm-up in the data, so the fit drives tau far below the observation times, where the warm-up
amplitude and the bias cancel: nearly collinear Jacobian columns. scipy 1.17's MINPACK QR then
recomputed a column norm with one element read past the Jacobian buffer, so chi2 changed from its
7th digit with what earlier, freed arrays had left in memory (four different values for the fills
below before accellog.core.numeric appended its zero column).
"""

from __future__ import annotations

import numpy as np
from support.synthetic import synthetic_obs, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.core.numeric import least_squares


def _fit_after_heap_fill(obs, model, fill: float):
    junk = [np.full(k, fill) for k in range(2000, 2400, 3)]  # freed blocks around the Jacobian's size
    del junk
    return fit_model(obs, model)


def test_degenerate_fit_does_not_depend_on_the_heap():
    truth = build_model("model3").with_terms(["nonlin2"])
    model = truth.with_terms(["warmup"])
    obs = synthetic_obs(truth, true_theta(truth, seed=11), protocol="six", hold_s=30.0, seed=7)
    fits = [_fit_after_heap_fill(obs, model, fill) for fill in (0.0, 1.0, 1e3, 1e6)]
    assert len({f.chi2.hex() for f in fits}) == 1, [repr(f.chi2) for f in fits]
    for f in fits[1:]:
        assert f.theta.tobytes() == fits[0].theta.tobytes()
        assert f.cov.tobytes() == fits[0].cov.tobytes()


def test_least_squares_returns_the_callers_parameters_only():
    """The zero column is the solver's business: x, jac and the evaluations see n parameters."""
    A = np.array([[1.0, 0.0], [0.0, 2.0], [1.0, 1.0]])
    y = np.array([1.0, 2.0, 3.0])
    seen: list[int] = []

    def fun(x):
        seen.append(x.size)
        return A @ x - y

    sol = least_squares(fun, np.zeros(2), what="test", jac=lambda x: A, x_scale=np.array([1.0, 2.0]))
    assert sol.x.shape == (2,) and sol.jac.shape == (3, 2) and set(seen) == {2}
    np.testing.assert_allclose(sol.x, np.linalg.lstsq(A, y, rcond=None)[0], rtol=1e-12)
    sol2 = least_squares(fun, np.zeros(2), what="test")  # MINPACK's own differences, scalar x_scale
    np.testing.assert_allclose(sol2.x, sol.x, rtol=1e-7)
    # as many residuals as parameters: still solvable (the extra parameter brings its own zero row)
    sq = least_squares(lambda x: A[:2] @ x - y[:2], np.zeros(2), what="test", jac=lambda x: A[:2])
    np.testing.assert_allclose(sq.x, [1.0, 1.0], rtol=1e-12)
    assert sq.fun.shape == (2,)
