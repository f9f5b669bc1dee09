"""Least-squares fit: seed reproduction, uncertainties vs Monte Carlo, rank refusals, warnings."""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic import cube_poses, synthetic_obs, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model, fit_orientation_free
from accellog.core.errors import InputError, ModelError
from accellog.core.session import ObsTable


def _temp(t):
    return 24.0 + 8.0 * (1.0 - np.exp(-t / 400.0)) + 1.5 * np.sin(2 * np.pi * t / 700.0)


def _pose_mean_obs(path) -> ObsTable:
    P = np.loadtxt(path, delimiter=",", skiprows=1)
    truth, mean, std = P[:, [0, 3, 6]], P[:, [1, 4, 7]], P[:, [2, 5, 8]]
    n = truth.shape[0]
    return ObsTable(
        meas_g=mean,
        sigma_g=std / np.sqrt(5400.0),
        up_sensor=truth,
        pose_id=np.arange(n),
        pose_names=["+z", "-z", "+y", "-y", "+x", "-x"],
        t_s=np.arange(n) * 30.0,
        t_in_pose_s=np.full(n, 15.0),
        n_samples=np.full(n, 5400),
        std_g=std,
    )


@pytest.mark.parametrize("trial", [1, 2, 3])
def test_unweighted_fit_reproduces_seed_params(shared_data, trial):
    obs = _pose_mean_obs(shared_data / f"capstone/trial_{trial}/six_position_data_{trial}.csv")
    ref = np.loadtxt(
        shared_data / f"capstone/trial_{trial}/optim_params_{trial}.csv", delimiter=",", skiprows=2
    )
    r1 = fit_model(obs, build_model("model1"), weighted=False)
    r2 = fit_model(obs, build_model("model2"), weighted=False)
    r3 = fit_model(obs, build_model("model3"), weighted=False)
    np.testing.assert_allclose(r1.b, ref[0, :3], atol=1e-9)
    np.testing.assert_allclose(r2.b, ref[1, :3], atol=1e-9)
    np.testing.assert_allclose(np.diag(r2.S), ref[1, 3:6], atol=1e-9)
    np.testing.assert_allclose(r3.b, ref[2, :3], atol=1e-9)
    np.testing.assert_allclose(r3.S.ravel(), ref[2, 3:], atol=1e-9)
    assert r3.dof == 6 and np.all(r3.sigma > 0) and not r3.weighted


def test_weighted_fit_final_trial_reference(shared_data):
    obs = _pose_mean_obs(shared_data / "capstone/final_trial/six_position_data.csv")
    r = fit_model(obs, build_model("model3"), weighted=True)
    # README [recomputed] weighted fit: b = (0.092154, 0.046237, -0.249640)
    np.testing.assert_allclose(r.b, [0.092154, 0.046237, -0.249640], atol=2e-6)
    assert r.chi2_dof > 100 and any("misses an effect" in w for w in r.warnings)
    d = r.to_dict()
    assert d["params"][0]["name"] == "b_x" and d["params"][0]["unit"] == "g"


def _mc(model_name, truth_name, n_seeds, protocol, weighted=True, **kw):
    m = build_model(model_name)
    mt = build_model(truth_name)
    th = true_theta(mt, seed=5)
    est, sig = [], []
    for s in range(n_seeds):
        obs = synthetic_obs(mt, th, protocol=protocol, windows_per_hold=3, hold_s=15.0, seed=1000 + s, **kw)
        r = fit_model(obs, m, weighted=weighted)
        est.append(r.theta)
        sig.append(r.sigma)
    est, sig = np.array(est), np.array(sig)
    ratio = est.std(axis=0, ddof=1) / sig.mean(axis=0)
    bias_z = np.abs(est.mean(axis=0) - th[: m.n_params]) / (est.std(axis=0, ddof=1) / np.sqrt(n_seeds))
    return ratio, bias_z


def test_sigma_matches_monte_carlo_linear():
    """model3, 24 poses: empirical std of each parameter over 300 seeds = reported 1-sigma (CRB)."""
    ratio, bias_z = _mc("model3", "model3", 300, "24")
    assert np.all((ratio > 0.87) & (ratio < 1.13)), ratio
    assert np.all(bias_z < 4.5), bias_z  # unbiased


def test_sigma_matches_monte_carlo_nonlinear_and_unweighted():
    ratio, _ = _mc("model3+fixture_tilt", "model3+fixture_tilt", 200, "24")
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio
    # unweighted: covariance scaled by the residual variance (noise is homoscedastic here)
    ratio, _ = _mc("model3", "model3", 200, "six", weighted=False)
    assert np.all((ratio > 0.82) & (ratio < 1.18)), ratio


def test_nonlinear_fit_recovers_warmup_and_tilt():
    mt = build_model("model3+warmup+fixture_tilt+temp_bias")
    th = true_theta(mt, seed=3)
    obs = synthetic_obs(mt, th, protocol="24", temp_path=_temp, seed=4)
    r = fit_model(obs, mt)
    z = (r.theta - th) / r.sigma
    assert np.all(np.abs(z) < 5), dict(zip(r.param_names, z, strict=True))
    assert abs(r.chi2_dof - 1) < 0.25


def test_rank_check_names_missing_poses():
    m = build_model("model2")
    obs = synthetic_obs(m, true_theta(m), protocol="+z,-z,+y,-y", seed=1)
    with pytest.raises(
        ModelError, match=r"S_xx not identifiable \(scale of x needs x at two levels: both \+x and -x"
    ):
        fit_model(obs, m)
    # +x alone with x = 0 in the other poses determines bias+scale of x: no refusal
    fit_model(synthetic_obs(m, true_theta(m), protocol="+z,-z,+y,-y,+x", seed=1), m)
    m3 = build_model("model3")
    few = synthetic_obs(m3, true_theta(m3), protocol="+z,-z", windows_per_hold=1, seed=1)
    with pytest.raises(ModelError, match="only 6 equations"):
        fit_model(few, m3)


def test_rank_check_temperature_and_tilt_advice():
    m = build_model("model3+temp_bias")
    obs = synthetic_obs(m, true_theta(m), protocol="six", seed=1)  # temperature constant 25 degC
    with pytest.raises(ModelError, match=r"temperature spans only 0\.0 degC"):
        fit_model(obs, m)
    m = build_model("model3+fixture_tilt")
    obs = synthetic_obs(m, true_theta(m), protocol="six", seed=1)
    with pytest.raises(ModelError, match=r"fixture_tilt not identifiable.*24-pose protocol"):
        fit_model(obs, m)


def test_input_errors_and_acceptance_warnings():
    m = build_model("model3")
    obs = synthetic_obs(m, true_theta(m), protocol="six", seed=2)
    obs.sigma_g[0, 0] = 0.0
    with pytest.raises(InputError, match="sigma_g"):
        fit_model(obs, m)
    fit_model(obs, m, weighted=False)  # sigma not needed
    th = true_theta(m, {"S_xx": 1.5, "b_y": 1.3})
    obs = synthetic_obs(m, th, protocol="six", seed=2)
    w = fit_model(obs, m).warnings
    assert any("scale of x = 1.5" in s for s in w) and any("offset of y" in s for s in w)


def test_orientation_free_fit_matches_labelled():
    """imu_tk / ArduPilot style: |S^-1(a - b)| = 1 g over unlabelled, well-spread orientations."""
    m = build_model("bias+scale+misalignment_tri")
    th = true_theta(m, seed=8)
    obs = synthetic_obs(m, th, protocol=cube_poses(), windows_per_hold=2, seed=9)
    r = fit_orientation_free(obs, m)
    z = (r.theta - th) / r.sigma
    assert np.all(np.abs(z) < 5), z
    assert r.method == "orientation_free" and 0.5 < r.chi2_dof < 1.6
    with pytest.raises(ModelError, match="misalignment_tri"):
        fit_orientation_free(obs, build_model("model3"))


def test_a_term_the_data_does_not_show_is_said_insignificant():
    """A term beyond the linear model whose parameters are 0 within their uncertainty is named with
    its Wald test (the statistic and p as numpy and scipy.stats give them); one the data shows is
    not; the linear model is never judged so."""
    from scipy import stats

    m = build_model("model3+nonlin2")
    absent = synthetic_obs(m, true_theta(m, {"k2_x": 0.0, "k2_y": 0.0, "k2_z": 0.0}), protocol="24", seed=5)
    r = fit_model(absent, m)
    said = [w for w in r.warnings if w.startswith("nonlin2 is not significant")]
    sl = m.slices["nonlin2"]
    th, c = r.theta[sl], r.cov[sl, sl]
    wald = float(th @ np.linalg.solve(c, th))
    assert said and f"Wald chi2 {wald:.3g} on 3 dof, p = {stats.chi2.sf(wald, 3):.2g}" in said[0]
    shown = synthetic_obs(
        m, true_theta(m, {"k2_x": 0.004, "k2_y": -0.003, "k2_z": 0.002}), protocol="24", seed=5
    )
    assert not [w for w in fit_model(shown, m).warnings if "not significant" in w]
    m3 = build_model("model3")  # b, S near their 'absent' values are still not judged
    assert not [w for w in fit_model(absent, m3).warnings if "not significant" in w]
