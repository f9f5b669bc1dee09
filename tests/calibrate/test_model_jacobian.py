"""Analytic Jacobians of the library effects (accellog.calibrate.model.jacobian) equal central
differences of Model.predict (labelled) and of |Model.correct| (gravity norm) for every effect, at a
point away from the start (every parameter at a plausible nonzero value, temperature varying)."""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic import cube_poses, synthetic_obs, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.effects import HANDHELD_START, LIBRARY
from accellog.calibrate.model.fit import _Problem, _steps, obs_drivers
from accellog.calibrate.model.jacobian import norm_jacobian, numeric_columns, predict_jacobian
from accellog.calibrate.model.residual_fns import numjac

EFFECTS = [e for e in LIBRARY if LIBRARY[e].static and e not in ("misalignment_tri", "cross_axis")]


def _case(base: str, effect: str):
    have = build_model(base).term_names  # bias and scale are the base's own (a term is named once)
    m = build_model(base, add=[e for e in dict.fromkeys([effect, "temp_scale"]) if e not in have])
    th = true_theta(m)
    obs = synthetic_obs(
        m,
        th,
        protocol=cube_poses(8.0),
        hold_s=8.0,
        windows_per_hold=2,
        temp_path=lambda t: 25 + 8 * np.sin(t / 90),
    )
    return m, th, obs, obs_drivers(obs)


def _central(fun, th, steps):
    cols = []
    for k in range(th.size):
        e = np.zeros_like(th)
        e[k] = steps[k]
        cols.append((fun(th + e) - fun(th - e)) / (2 * steps[k]))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("effect", EFFECTS)
def test_labelled_columns_match_differences(effect):
    m, th, obs, drv = _case("model3", effect)
    f = m.truth_g(th, obs.up_sensor, obs.q_sensor_to_world)
    J = predict_jacobian(m, th, f, drv)
    Jn = _central(lambda x: m.predict(x, f, drv), th, _steps(m, th))
    keep = [k for k in range(th.size) if k not in numeric_columns(m)]
    assert np.abs(J[..., keep] - Jn[..., keep]).max() < 1e-7 * np.abs(Jn).max()
    # the fit's Jacobian (analytic columns + differences for fixture_tilt) equals all-differences
    prob = _Problem(m, obs, drv, 1.0 / obs.sigma_g, 1.0, obs.q_sensor_to_world)
    Jf = numjac(prob.resid, th, _steps(m, th))
    Jr = _central(prob.resid, th, _steps(m, th))
    assert np.abs(Jf - Jr).max() < 1e-7 * np.abs(Jr).max()


@pytest.mark.parametrize("effect", [e for e in EFFECTS if e != "fixture_tilt"])
def test_norm_columns_match_differences(effect):
    m, th, obs, drv = _case(HANDHELD_START, effect)
    J = norm_jacobian(m, th, obs.meas_g, drv)
    Jn = _central(lambda x: np.linalg.norm(m.correct(x, obs.meas_g, drv), axis=1), th, _steps(m, th))
    assert np.abs(J - Jn).max() < 1e-7 * np.abs(Jn).max()
