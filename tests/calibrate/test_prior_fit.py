"""A calibration as the prior of an orientation-free fit (calibrate.model.prior): on stops near
level the data move what they see (the biases) and leave what they cannot see (cross-axis, the
scale along gravity) at the prior's values; fixed parameters stay at the start."""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic import synthetic_obs

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model, fit_orientation_free
from accellog.calibrate.model.prior import Prior
from accellog.core.errors import ModelError
from accellog.core.protocol import PoseSpec
from accellog.core.rotations import quat_between


def level_stops(n: int = 30, max_tilt_deg: float = 15.0, seed: int = 0) -> list[PoseSpec]:
    """n stops z-up, tilted up to max_tilt_deg in random directions (a ground robot's)."""
    rng = np.random.default_rng(seed)
    tilt = np.deg2rad(rng.uniform(2.0, max_tilt_deg, n))
    az = rng.uniform(0.0, 2 * np.pi, n)
    ups = np.c_[np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
    return [
        PoseSpec(f"s{i}", tuple(u), tuple(quat_between(u, np.array([0.0, 0.0, 1.0]))), 8.0)
        for i, u in enumerate(ups)
    ]


def lab_and_truth(seed: int = 3):
    m = build_model("model3")
    rng = np.random.default_rng(seed)
    th = m.initial_theta()
    th[:3], th[3:6], th[6:] = [0.05, -0.04, 0.07], [1.02, 0.98, 1.01], rng.uniform(-0.01, 0.01, 6)
    lab = fit_model(synthetic_obs(m, th, protocol="six", seed=seed), m)
    aged = th.copy()
    aged[:3] += [0.005, -0.008, 0.006]  # biases aged 5-8 mg since the lab
    return m, lab, th, aged


def test_prior_moves_the_seen_biases_and_keeps_the_unseen_terms():
    m, lab, _, aged = lab_and_truth()
    obs = synthetic_obs(m, aged, protocol=level_stops(), hold_s=8.0, windows_per_hold=4, seed=5)
    obs.up_sensor = obs.meas_g / np.linalg.norm(obs.meas_g, axis=1, keepdims=True)  # unlabelled
    obs.q_sensor_to_world = None
    prior = Prior.of(m.param_names, lab.theta, lab.cov, m)
    fit = fit_orientation_free(obs, m, prior=prior)
    src = {r["name"]: r for r in fit.prior_sources}
    for k, name in enumerate(m.param_names[:3]):  # every bias within 3 sigma of the aged truth
        assert abs(fit.theta[k] - aged[k]) < 3 * fit.sigma[k], (name, fit.theta[k], aged[k], fit.sigma[k])
        assert src[name]["source"] == "data" and abs(fit.theta[k] - aged[k]) < 1.5e-3
    for name in ("S_xz", "S_zx", "S_yz", "S_zy"):  # the norm cannot see them: the prior holds them
        assert src[name]["source"] == "prior" and abs(src[name]["moved_sigma"]) < 0.5
    assert fit.theta[m.index["S_zz"]] == pytest.approx(lab.theta[m.index["S_zz"]], abs=2e-3)
    # without the aging allowance the lab's 0.02 mg sigma pins the aged biases: the fit rejects it
    tight = fit_orientation_free(obs, m, prior=Prior.of(m.param_names, lab.theta, lab.cov, m, aging={}))
    assert tight.chi2_dof > 10 * fit.chi2_dof


def test_fixed_parameters_stay_at_the_start_with_sigma_zero():
    m = build_model("bias+scale")
    th = m.initial_theta()
    th[:3] = [0.03, -0.02, 0.05]
    obs = synthetic_obs(m, th, protocol=level_stops(), hold_s=8.0, windows_per_hold=4, seed=1)
    free = fit_orientation_free(obs, m)  # b_z and S_zz only together: b_z is lost in their sum
    fit = fit_orientation_free(obs, m, fixed=["S_xx", "S_yy", "S_zz"])
    assert fit.fixed == ["S_xx", "S_yy", "S_zz"]
    np.testing.assert_array_equal(fit.theta[3:], [1.0, 1.0, 1.0])
    np.testing.assert_array_equal(fit.sigma[3:], 0.0)
    np.testing.assert_allclose(fit.theta[:3], th[:3], atol=4 * fit.sigma[:3].max())
    assert free.sigma[2] > 30 * fit.sigma[2]
    with pytest.raises(ModelError, match="not parameters"):
        fit_orientation_free(obs, m, fixed=["S_qq"])


def test_prior_must_hold_every_parameter_of_the_model():
    m, lab, _, _ = lab_and_truth()
    with pytest.raises(ModelError, match="no value for bT_x"):
        Prior.of(m.param_names, lab.theta, lab.cov, build_model("model3+temp_bias"))


def test_a_calibration_with_effects_added_for_a_prior(tmp_path):
    """Calibration.with_effects: the lab's parameters and covariance kept, the added effect's at
    their initial values with 1-sigma = its typical size, uncorrelated; nothing to add: itself."""
    from accellog.calibrate.calfile.calibration import Calibration

    _, lab, _, _ = lab_and_truth()
    cal = Calibration.from_fit(lab)
    ext = cal.with_effects(["temp_bias", "bias"])
    assert ext.param_names == [*cal.param_names, "bT_x", "bT_y", "bT_z"] and ext.terms[-1] == "temp_bias"
    np.testing.assert_array_equal(ext.theta[:12], cal.theta)
    np.testing.assert_array_equal(ext.cov[:12, :12], cal.cov)
    np.testing.assert_array_equal(ext.theta[12:], 0.0)
    np.testing.assert_array_equal(ext.cov[12:, :12], 0.0)
    np.testing.assert_allclose(ext.sigma[12:], 1.5e-3)
    Prior.of(ext.param_names, ext.theta, ext.cov, build_model("model3+temp_bias"))  # a prior of that model
    assert cal.with_effects(["scale"]) is cal
