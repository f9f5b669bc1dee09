"""drift: polynomial displacement drift q0 + q1 t + 1/2 q2 t^2, its uncertainty and application."""

from __future__ import annotations

import numpy as np
import pytest
from support.sessions import synth_session

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.calfile.drift_model import LIMITS, DriftModel
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.observe.segment import observations
from accellog.navigate.drift import drift_from_session, fit_drift
from accellog.navigate.integrate import displacement


def test_fit_recovers_polynomial_and_sigma_is_honest():
    """Constant residual bias + white noise: q2 recovered within its propagated 1-sigma scale."""
    rng = np.random.default_rng(5)
    q2_true = np.array([0.02, -0.01, 0.005])
    zs = []
    for k in range(30):
        t = np.cumsum(rng.uniform(0.004, 0.007, 10000))
        a = q2_true + rng.normal(0, 0.03, (t.size, 3))
        _, d = displacement(t, a, remove_gravity_mps2=None)
        m = fit_drift(t, d, accel_resid_mps2=a - q2_true)
        zs.append((m.q[:, 2] - q2_true) / m.sigma[:, 2])
        if k == 0:
            assert m.predict(t)[-1] == pytest.approx(d[-1], abs=0.05 * np.abs(d[-1]).max())
            assert np.allclose(m.apply(t, d)[-1], 0, atol=0.5)
    zs = np.array(zs)
    assert 0.5 < np.std(zs) < 1.6  # sigma matches the scatter of the estimates
    assert np.abs(np.mean(zs)) < 0.6


def test_dict_round_trip_and_limits():
    t = np.linspace(0, 60, 1000)
    d = np.c_[t**2, t, np.ones_like(t)]
    m = fit_drift(t, d, up_sensor=(0.0, 0.0, 1.0))
    assert np.allclose(m.q[0], [0, 0, 2], atol=1e-9)
    assert np.isnan(m.sigma).all()  # no acceleration series: no pretend uncertainty
    back = DriftModel.from_dict(m.to_dict())
    assert np.allclose(back.q, m.q) and back.up_sensor == (0.0, 0.0, 1.0)
    assert m.to_dict()["limits"] == LIMITS and "invalid once the sensor moves" in LIMITS


def test_drift_stage_on_sessions_reduces_displacement():
    s = synth_session(seed=31, hold_s=20.0)
    obs = observations(s)
    cal = Calibration.from_fit(fit_model(obs, build_model("model1")), obs=obs)  # misses scale: residual bias
    a = synth_session(seed=32, poses=["+z"], hold_s=60.0, move_s=0.0)
    b = synth_session(seed=33, poses=["+z"], hold_s=60.0, move_s=0.0)
    a.poses, b.poses = [], []
    cal_d, dm = drift_from_session(a, cal)
    assert cal_d.drift is dm and cal.drift is None
    from accellog.navigate.evaluate import evaluate

    ev = evaluate(b, cal_d)
    assert ev.drift_applied
    assert np.abs(ev.disp_end_drift_m).max() < 0.2 * np.abs(ev.disp_end_m).max()
