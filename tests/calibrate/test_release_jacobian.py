"""FitResult.release_jacobian: the Jacobian a fit remakes when read is bit for bit the one it kept,
and diagnose, which releases every fit's, gives the same diagnosis as when they are kept."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from support.synthetic import cube_poses, synthetic_obs, true_theta

from accellog.calibrate.diagnosis import diagnose as diag_mod
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import FitResult, fit_model, fit_orientation_free


def _temp(t):
    return 24.0 + 8.0 * (1.0 - np.exp(-t / 400.0)) + 1.5 * np.sin(2 * np.pi * t / 700.0)


@pytest.mark.parametrize(
    ("spec", "free", "weighted"),
    [
        ("model3", False, True),
        ("model3", False, False),
        ("model3+warmup+fixture_tilt+temp_bias", False, True),
        ("bias+scale+misalignment_tri", True, True),
        ("bias+scale+misalignment_tri", True, False),
    ],
)
def test_released_jacobian_is_remade_bit_for_bit(spec, free, weighted):
    m = build_model(spec)
    th = true_theta(m, seed=3)
    if free:
        obs = synthetic_obs(m, th, protocol=cube_poses(), windows_per_hold=2, seed=9)
        r = fit_orientation_free(obs, m, weighted=weighted)
    else:
        obs = synthetic_obs(m, th, protocol="24", temp_path=_temp, seed=4)
        r = fit_model(obs, m, weighted=weighted)
    kept = r.jacobian.copy()
    r.release_jacobian()
    assert r.__dict__["_jacobian"] is None  # the array is no longer held
    again = r.jacobian
    assert again is not kept and np.array_equal(again, kept)
    assert np.array_equal(r.jacobian, kept)  # every read remakes the same


def test_release_keeps_a_jacobian_that_cannot_be_remade():
    m = build_model("model3")
    obs = synthetic_obs(m, true_theta(m, seed=3), protocol="24", seed=4)
    r = fit_model(obs, m)
    bare = FitResult(**{f.name: getattr(r, f.name) for f in dataclasses.fields(r) if f.init})
    bare.release_jacobian()  # built by hand: nothing to remake it from, so it stays
    assert np.array_equal(bare.jacobian, r.jacobian)


def test_diagnose_with_released_jacobians_is_unchanged(monkeypatch):
    truth = build_model("model3").with_terms(["temp_bias"])
    obs = synthetic_obs(truth, true_theta(truth, seed=11), protocol="24", temp_path=_temp, seed=21)
    released = json.dumps(diag_mod.diagnose(obs, build_model("model3")).to_dict(), sort_keys=True)
    monkeypatch.setattr(FitResult, "release_jacobian", lambda self: None)
    kept = json.dumps(diag_mod.diagnose(obs, build_model("model3")).to_dict(), sort_keys=True)
    assert released == kept
    assert '"best": "temp_bias"' in released
