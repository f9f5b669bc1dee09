"""evaluate: residual means, chi2 against noise, displacement, on seeded simulated sessions."""

from __future__ import annotations

import numpy as np
import pytest
from support.sessions import synth_session

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.observe.segment import observations
from accellog.core.errors import InputError
from accellog.navigate.evaluate import evaluate, evaluate_poses

G = 9.80665


def _cal(model: str, seed: int = 21) -> Calibration:
    s = synth_session(seed=seed, hold_s=20.0)
    obs = observations(s)
    return Calibration.from_fit(fit_model(obs, build_model(model)), obs=obs, local_gravity_mps2=G)


def _static(seed: int, hold_s: float = 60.0):
    s = synth_session(seed=seed, poses=["+z"], hold_s=hold_s, move_s=0.0)
    s.poses = []
    return s


def test_model3_residual_is_noise_and_model1_is_not():
    test = _static(22)
    ev3 = evaluate(test, _cal("model3"))
    ev1 = evaluate(test, _cal("model1"))
    raw = evaluate(test, None, raw_truth_g=1.0)
    assert "inferred" in ev3.notes[0]
    # model3: the mean residual is explained by noise + calibration uncertainty
    assert ev3.chi2_total < 16.0
    assert np.all(np.abs(ev3.mean_resid_mps2) < 0.01)
    # model1 ignores a 2 % scale error on z: 0.02 g residual, far beyond noise
    assert abs(ev1.mean_resid_mps2[2]) == pytest.approx(0.02 * G, rel=0.1)
    assert ev1.chi2_noise > 100 * ev3.chi2_noise
    # raw: bias 0.05 g + 2 % scale on z
    assert raw.mean_resid_mps2[2] == pytest.approx(0.07 * G, rel=0.05)
    # displacement grows as 1/2 a t^2 for a constant residual
    d60 = raw.disp_at(60.0)
    assert d60[2] == pytest.approx(0.5 * raw.mean_resid_mps2[2] * 60.0**2, rel=0.05)
    assert np.all(np.abs(ev3.disp_at(60.0)) < np.abs(d60))
    out = ev3.to_dict()
    assert set(out["mean_residual_mps2"]) == {"x", "y", "z"} and out["displacement_60s_m"] is not None


def test_cut_and_orientation_checks():
    test = _static(23)
    ev = evaluate(test, _cal("model3"), until_s=30.0)
    assert ev.t_end_s <= 30.0 and np.isnan(ev.t_used_s[2])
    ev = evaluate(test, _cal("model3"), max_samples=1000)
    assert ev.n == 1000
    multi = synth_session(seed=24)
    with pytest.raises(InputError, match="one orientation"):
        evaluate(multi, _cal("model3"))
    pe = evaluate_poses(multi, _cal("model3"))
    assert pe.chi2 / pe.dof < 2.0 and len(pe.pose_names) == 6


def test_moving_test_session_is_refused():
    test = _static(25)
    sl = test.slice_time(20.0, 21.0)
    test.accel_g[sl] += 0.3
    with pytest.raises(InputError, match=r"labelled static but moves at t = 2[01]\."):
        evaluate(test, _cal("model3"))
