"""Residual against the reading f_i (issue #10 item 2): a hidden quadratic nonlinearity shows as a
parabola in the f_x panel of model3 and is gone once nonlin2 is fitted."""

from __future__ import annotations

import numpy as np
from support.synthetic import synthetic_obs, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.present.residual_views import DRIVERS, panels


def test_nonlinearity_shows_against_the_reading_and_vanishes_when_fitted():
    truth = build_model("model3").with_terms(["nonlin2"])
    th = true_theta(truth, seed=2)
    obs = synthetic_obs(truth, th, protocol="24", hold_s=20.0, windows_per_hold=4, seed=3)
    fits = {"model3": fit_model(obs, build_model("model3")), "model3+nonlin2": fit_model(obs, truth)}
    got = {(p.driver, p.label): p for p in panels(obs, fits)}
    assert {"f_x_g", "f_y_g", "f_z_g", "f_xf_y_g2"} <= {d for d, _ in got} <= set(DRIVERS)

    def r2(p, i):  # share of the axis-i residual explained by a parabola in f_i
        x, y = p.x, p.residual_mg[:, i]
        fit = np.polyval(np.polyfit(x, y, 2), x)
        return 1.0 - np.sum((y - fit) ** 2) / np.sum((y - y.mean()) ** 2)

    before = [r2(got[(f"f_{a}_g", "model3")], i) for i, a in enumerate("xyz")]
    after = [r2(got[(f"f_{a}_g", "model3+nonlin2")], i) for i, a in enumerate("xyz")]
    assert max(before) > 0.8, before
    assert max(after) < 0.3, after
