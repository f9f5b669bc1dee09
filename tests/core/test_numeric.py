"""core.numeric: the fits' one solver (MINPACK through scipy.optimize.leastsq, its verdict kept) on
MINPACK test problems (More, Garbow & Hillstrom 1981) against their known optima, a solve that does
not converge is a one-line ModelError, and no module calls a least-squares solver of its own."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from accellog.core.errors import ModelError
from accellog.core.numeric import _zero_border, chi2_sf, jacobian_array, least_squares

# Meyer (MGH #10, NIST StRD "MGH10"): y = x1 exp(x2 / (t + x3)); certified values (NIST)
MEYER_T = 45.0 + 5.0 * np.arange(1, 17)
MEYER_Y = np.array(
    [34780, 28610, 23650, 19630, 16370, 13720, 11540, 9744, 8261, 7030, 6005, 5147, 4427, 3820, 3307, 2872],
    float,
)


def meyer(x):
    return x[0] * np.exp(x[1] / (MEYER_T + x[2])) - MEYER_Y


def meyer_jac(x):
    d = MEYER_T + x[2]
    e = np.exp(x[1] / d)
    return np.column_stack([e, x[0] * e / d, -x[0] * x[1] * e / d**2])


def freudenstein_roth(x):  # MGH #2: from (0.5, -2) the local minimum, not the zero at (5, 4)
    return np.array(
        [-13 + x[0] + ((5 - x[1]) * x[1] - 2) * x[1], -29 + x[0] + ((x[1] + 1) * x[1] - 14) * x[1]]
    )


def freudenstein_roth_jac(x):
    return np.array([[1.0, -3 * x[1] ** 2 + 10 * x[1] - 2], [1.0, 3 * x[1] ** 2 + 2 * x[1] - 14]])


def brown_badly_scaled(x):  # MGH #4: zero at (1e6, 2e-6), |x2| << 1 = x_scale
    return np.array([x[0] - 1e6, x[1] - 2e-6, x[0] * x[1] - 2])


def brown_badly_scaled_jac(x):
    return np.array([[1.0, 0.0], [0.0, 1.0], [x[1], x[0]]])


# (residuals, Jacobian, start, minimiser, sum of squares there, relative tolerance on the minimiser)
PROBLEMS = {
    "meyer": (
        meyer, meyer_jac, [0.02, 4000.0, 250.0],
        [5.6096364710e-03, 6.1813463463e03, 3.4522363462e02], 8.7945855171e01, 1e-8,
    ),
    # the local minimum lies in a flat valley: its cost fixes x only to ~1e-7 (x from the zero of
    # the gradient, solved in 40-digit arithmetic)
    "freudenstein_roth": (
        freudenstein_roth, freudenstein_roth_jac, [0.5, -2.0],
        [11.41277898690209, -0.8968052532744765], 48.98425367924, 1e-6,
    ),
    "brown_badly_scaled": (
        brown_badly_scaled, brown_badly_scaled_jac, [1.0, 1.0], [1e6, 2e-6], 0.0, 1e-8,
    ),
}  # fmt: skip


@pytest.mark.parametrize("x_scale", [1.0, "jac"])
@pytest.mark.parametrize("name", sorted(PROBLEMS))
def test_minpack_problems_reach_the_known_optimum(name, x_scale):
    fun, jac, x0, want_x, want_ss, rtol = PROBLEMS[name]
    sol = least_squares(fun, np.array(x0), what=name, jac=jac, x_scale=x_scale)
    assert sol.converged and sol.status > 0, sol.message
    np.testing.assert_allclose(sol.x, want_x, rtol=rtol, atol=0)
    assert float(sol.fun @ sol.fun) == pytest.approx(want_ss, rel=1e-10, abs=1e-20)
    np.testing.assert_array_equal(sol.fun, fun(sol.x))
    np.testing.assert_allclose(sol.jac, jac(sol.x), rtol=1e-12)


def test_finite_difference_jacobian_reaches_the_meyer_optimum():
    sol = least_squares(meyer, np.array([0.02, 4000.0, 250.0]), what="meyer", x_scale="jac")
    assert float(sol.fun @ sol.fun) == pytest.approx(87.945855171, rel=1e-9)


def test_a_solve_that_does_not_converge_is_a_model_error():
    with pytest.raises(
        ModelError,
        match=r"^Meyer test fit did not converge \(\d+ evaluations\): Number of calls .* maxfev = 10\.$",
    ):
        least_squares(
            meyer, np.array([0.02, 4000.0, 250.0]), what="Meyer test fit", jac=meyer_jac, max_nfev=10
        )
    nan_at_start = lambda x: np.array([x[0], math.nan, 1.0])  # noqa: E731
    with pytest.raises(ModelError, match=r"^bad fit did not converge: .*not finite"):
        least_squares(nan_at_start, np.ones(2), what="bad fit")


def test_the_start_is_evaluated_once():
    """leastsq checks the shapes at x0 and MINPACK starts there: the residuals and the Jacobian at x0
    are computed once (a 24 h fit's Jacobian is 13 MB and takes a pass over 127k rows)."""
    x0 = np.array([0.02, 4000.0, 250.0])
    seen: dict[str, list] = {"fun": [], "jac": []}

    def fun(x):
        seen["fun"].append(x.copy())
        return meyer(x)

    def jac(x):
        seen["jac"].append(x.copy())
        return meyer_jac(x)

    sol = least_squares(fun, x0, what="meyer", jac=jac, x_scale=1.0)
    assert [np.array_equal(x, x0) for x in seen["fun"]].count(True) == 1
    assert [np.array_equal(x, x0) for x in seen["jac"]].count(True) == 1
    np.testing.assert_array_equal(sol.x, least_squares(meyer, x0, what="meyer", jac=meyer_jac, x_scale=1.0).x)


def test_a_jacobian_built_in_a_jacobian_array_reaches_minpack_uncopied():
    """The solver is handed (m + 1, n + 1) with a zero border (module docstring): a Jacobian written
    into ``jacobian_array`` is that array already; any other array, or one whose border was written,
    is copied; the solve is the same either way."""
    J = jacobian_array(16, 3)
    J[:] = meyer_jac(np.array([0.02, 4000.0, 250.0]))
    bordered = _zero_border(J)
    assert bordered.shape == (17, 4) and np.shares_memory(bordered, J) and not bordered[-1].any()
    plain = meyer_jac(np.array([0.02, 4000.0, 250.0]))
    assert not np.shares_memory(_zero_border(plain), plain)
    np.testing.assert_array_equal(_zero_border(plain), bordered)
    written = jacobian_array(16, 3)
    written.base[-1, 0] = 1.0  # a border that is not zero: not handed over
    assert not np.shares_memory(_zero_border(written), written)
    assert not np.shares_memory(_zero_border(jacobian_array(17, 3)[:16]), J)  # not its top-left block

    def in_place(x):
        out = jacobian_array(16, 3)
        out[:] = meyer_jac(x)
        return out

    x0 = np.array([0.02, 4000.0, 250.0])
    a = least_squares(meyer, x0, what="meyer", jac=meyer_jac, x_scale=1.0)
    b = least_squares(meyer, x0, what="meyer", jac=in_place, x_scale=1.0)
    np.testing.assert_array_equal(a.x, b.x)


def test_chi2_sf():
    from scipy.stats import chi2

    for k, x in [(1, 0.5), (3, 7.8), (40, 40.0), (5280, 5300.0), (20000, 21000.0)]:
        assert chi2_sf(x, k) == pytest.approx(float(chi2.sf(x, k)), rel=1e-12)
    assert chi2_sf(0.0, 3) == 1.0 and chi2_sf(math.inf, 3) == 0.0
    assert math.isnan(chi2_sf(1.0, 0)) and math.isnan(chi2_sf(1.0, -2))


def test_no_other_least_squares_solver():
    """One solver: scipy's least-squares solvers are called in core.numeric only, and every module
    that calls least_squares takes core.numeric's (with its convergence check)."""
    root = Path(__file__).resolve().parents[2] / "accellog"
    scipy_solver = re.compile(r"(optimize\.|import .*)\b(leastsq|least_squares|curve_fit)\b")
    offenders = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel == "core/numeric.py":
            continue
        text = path.read_text()
        offenders += [
            f"{rel}: {line.strip()}"
            for line in text.splitlines()
            if scipy_solver.search(line) and "accellog.core.numeric" not in line
        ]
        if "least_squares(" in text and not re.search(
            r"from accellog\.core\.numeric import .*least_squares", text
        ):
            offenders.append(f"{rel}: calls least_squares without core.numeric's")
    assert not offenders, offenders
