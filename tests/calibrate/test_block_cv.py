"""Blocked validation in the p x p form (issue #11: diagnose linear in the windows, bounded memory).

transfer.block_cv predicts each contiguous block of windows from the fit to the others. It used to
form the dense 3m x 3m matrix I - H_BB of every block (m = a fifth of the windows: 4 GB and hours
of eigvalsh on a 24 h session); the push-through form must give the same chi2 to 1e-9, infinities
(blocks the others cannot determine) included.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic import synthetic_obs, true_theta

from accellog.calibrate.diagnosis.transfer import _whitened, block_cv, block_groups, blocking_drivers
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model


def _block_cv_dense(res, obs, groups):
    """block_cv as it was: the dense block matrix, eigvalsh and solve on it."""
    J, r, _ = _whitened(res, obs)
    A = np.linalg.pinv(J.T @ J)
    out = []
    for g in groups:
        rows = (np.asarray(g)[:, None] * 3 + np.arange(3)).ravel()
        Jg = J[rows]
        M = np.eye(rows.size) - Jg @ A @ Jg.T
        if np.linalg.eigvalsh(0.5 * (M + M.T)).min() < 1e-6:
            out.append(np.inf)
            continue
        out.append(float(np.linalg.solve(M, r[rows]) @ np.linalg.solve(M, r[rows])))
    return np.asarray(out)


@pytest.mark.parametrize(
    ("model", "protocol", "weighted", "k", "unpredictable"),
    [
        ("model3", "24", True, 5, 0),
        ("model3+temp_bias+temp_scale", "24", True, 5, 0),
        ("model3+temp_bias", "six", True, 6, 0),
        ("model2", "six", False, 3, 6),  # each block holds whole faces the others never see
    ],
)
def test_block_cv_small_form_equals_the_dense_form(model, protocol, weighted, k, unpredictable):
    name, *add = model.split("+")
    truth = build_model("model3").with_terms(["temp_bias"])
    obs = synthetic_obs(
        truth, true_theta(truth, seed=3), protocol=protocol, hold_s=20.0, move_s=3.0,
        windows_per_hold=4, temp_path=lambda t: 25.0 + 10.0 * np.asarray(t) / 600.0, seed=5,
    )  # fmt: skip
    res = fit_model(obs, build_model(name, add=add), weighted=weighted)
    n_inf = 0
    for x in blocking_drivers(obs).values():
        groups = block_groups(x, k)
        dense, fast = _block_cv_dense(res, obs, groups), block_cv(res, obs, groups)
        np.testing.assert_array_equal(np.isinf(fast), np.isinf(dense))
        np.testing.assert_allclose(fast[np.isfinite(dense)], dense[np.isfinite(dense)], rtol=1e-9)
        n_inf += int(np.isinf(dense).sum())
    assert n_inf == unpredictable
