"""The model workbench: hidden effects are found, clean data invents nothing, advice is right."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.synthetic import cube_poses, synthetic_obs, synthetic_session, true_theta

from accellog.calibrate.diagnosis.diagnose import diagnose
from accellog.calibrate.diagnosis.ladder import ladder
from accellog.calibrate.diagnosis.transfer import predict_residual
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _temp(t):
    """Warm-up plus a slow ambient swing: distinguishable from time and from the warm-up curve."""
    return 24.0 + 8.0 * (1.0 - np.exp(-t / 400.0)) + 1.5 * np.sin(2 * np.pi * t / 700.0)


# effect -> (model it is hidden from, protocol, parameter overrides)
CASES = {
    "bias": ("scale+cross_axis", "24", {}),
    "scale": ("model1", "24", {}),
    "cross_axis": ("model2", "24", {}),
    "misalignment_tri": ("model2", "24", {}),
    "temp_bias": ("model3", "24", {}),
    "temp_bias2": ("model3", "24", {}),
    "temp_scale": ("model3", "24", {}),
    "temp_scale2": ("model3", "24", {"sT2_x": 4e-5, "sT2_y": -3e-5, "sT2_z": 3e-5}),
    "nonlin2": ("model3", "24", {}),
    "nonlin3": ("model3", "cube", {}),
    "g_cross": ("model3", "cube", {}),
    "time_drift": ("model3", "24", {}),
    "warmup": ("model3", "24", {}),
    "fixture_tilt": ("model3", "24", {}),
}


def _obs(model, th, protocol, seed, **kw):
    proto = cube_poses() if protocol == "cube" else protocol
    return synthetic_obs(model, th, protocol=proto, temp_path=_temp, seed=seed, **kw)


@pytest.mark.parametrize("effect", list(CASES))
def test_hidden_effect_is_found_and_fixed(effect):
    base_name, protocol, over = CASES[effect]
    base = build_model(base_name)
    truth = base.with_terms([effect])
    th = true_theta(truth, over, seed=11)
    obs = _obs(truth, th, protocol, seed=21)
    d = diagnose(obs, base)
    assert d.missing and d.best == effect, (
        d.verdict,
        [(c["effect"], c.get("delta_bic")) for c in d.candidates[:3]],
    )
    assert d.candidates[0]["effect"] == effect and d.candidates[0]["significant"]
    assert f"--add {effect}" in " ".join(d.advice)
    # adding it brings chi2/dof to ~1 and held-out residuals to the noise floor
    fixed = base.with_terms([effect])
    res = fit_model(obs, fixed)
    assert abs(res.chi2_dof - 1.0) < 6 * np.sqrt(2.0 / res.dof), res.chi2_dof
    held = _obs(truth, th, protocol, seed=99)
    rows = ladder(obs, [base, fixed], heldout_obs=held)
    assert rows[1].heldout_rms_g < 1.2 * rows[1].heldout_noise_g, rows
    assert rows[0].heldout_rms_g > rows[1].heldout_rms_g


@pytest.mark.parametrize("seed", range(6))
def test_clean_session_invents_nothing(seed):
    m = build_model("model3")
    th = true_theta(m, seed=seed)
    protocol = "cube" if seed % 3 == 2 else "24"
    d = diagnose(_obs(m, th, protocol, seed=300 + seed), m)
    assert not d.missing, d.verdict
    assert d.best is None and not any(c.get("significant") for c in d.candidates)
    assert "nothing is missing" in d.verdict
    assert not any(a.startswith("refit") for a in d.advice)


def test_effect_outside_library_shows_in_driver_signals_and_user_term_fixes_it():
    ef = EXAMPLES / "effects_creep.py"
    truth = build_model("model3", add=["pose_creep2"], effects_file=ef)
    th = true_theta(truth, {"c_x": 2e-6, "c_y": -1.5e-6, "c_z": 1e-6}, seed=3)
    obs = _obs(truth, th, "24", seed=5)
    d = diagnose(obs, build_model("model3"))
    assert d.missing
    assert d.driver_signals[0]["signal"].startswith("t_in_pose_s") and d.driver_signals[0]["significant"]
    # the library cannot explain it; the user-written term from a file can
    d2 = diagnose(obs, build_model("model3", effects_file=ef))
    assert d2.best == "pose_creep2"
    res = fit_model(obs, build_model("model3", add=["pose_creep2"], effects_file=ef))
    assert abs(res.chi2_dof - 1) < 0.3
    held = _obs(truth, th, "24", seed=6)
    r = predict_residual(res, held)
    assert np.sqrt(np.mean(r**2)) < 1.2 * np.sqrt(np.mean(held.sigma_g**2))


def test_made_up_driver_humidity():
    ef = EXAMPLES / "effects_humidity.py"
    truth = build_model("model3", add=["humidity_bias"], effects_file=ef)
    th = true_theta(truth, {"hb_x": 3e-5, "hb_y": -2e-5, "hb_z": 2e-5}, seed=4)

    def hum(o):
        return {"humidity_pct": 50 + 20 * np.sin(0.7 * o.pose_id) + 0.01 * o.t_in_pose_s}

    obs = _obs(truth, th, "24", seed=8, extra_drivers=hum)
    d = diagnose(obs, build_model("model3"), drivers=hum(obs))
    assert d.missing and d.driver_signals[0]["signal"] == "humidity_pct"
    d2 = diagnose(obs, build_model("model3", effects_file=ef), drivers=hum(obs))
    assert d2.best == "humidity_bias"
    # without the signal, a model that needs it says what to supply
    d3 = diagnose(obs, build_model("model3", effects_file=ef))
    row = next(c for c in d3.candidates if c["effect"] == "humidity_bias")
    assert not row["identifiable"] and "humidity_pct" in row["reason"]


def test_non_identifiable_advice():
    m = build_model("model3")
    th = true_theta(m, seed=1)
    obs = synthetic_obs(m, th, protocol="six", temp_path=lambda t: 25.0 + 0.1 * t / t.max(), seed=2)
    d = diagnose(obs, m)
    reasons = {c["effect"]: c.get("reason", "") for c in d.candidates if not c["identifiable"]}
    assert "temperature spans only 0.1 degC" in reasons["temp_bias"]
    assert "warm-up" in reasons["temp_bias"]
    assert "24-pose" in reasons["fixture_tilt"]
    assert "off the axes" in reasons["nonlin3"] and "off the axes" in reasons["g_cross"]
    assert "host" in reasons["clock"]
    assert any(a.startswith("temp_bias:") for a in d.advice)
    d = diagnose(synthetic_obs(m, th, protocol="24", seed=3), m)  # 24 poses: tilt is testable
    assert next(c for c in d.candidates if c["effect"] == "fixture_tilt")["identifiable"]


def test_cli_diagnose_on_mcap(tmp_path, capsys):
    from accellog.store.writer import write_session

    truth = build_model("model3+temp_bias")
    th = true_theta(truth, seed=2)
    s = synthetic_session(
        truth, th, protocol="six", temp_path=lambda t: 24 + 8 * (1 - np.exp(-t / 30)), eps_clock=3e-4
    )
    p = write_session(tmp_path / "s.mcap", s)
    assert main(["diagnose", str(p), "--model", "model3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["missing"] and out["best"] == "temp_bias" and out["chi2_dof"] > 10
    assert out["noise_floor_g"] > 0 and out["candidates"][0]["effect"] == "temp_bias"
    assert {"signal", "axis", "correlation"} <= set(out["driver_signals"][0])
    assert abs(out["clock"]["eps_ppm"] - 300) < 10
    assert main(["diagnose", str(p), "--model", "model3", "--add", "temp_bias"]) == 0
    assert "nothing is missing" in capsys.readouterr().out
    assert main(["diagnose", str(p), "--model", "model9"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("accellog: error:") and "valid names" in err
    assert main(["diagnose", str(tmp_path / "nope.mcap")]) == 2


def _cv_scores_dense(res, obs):
    """cv_scores as it was: the dense 3n_g x 3n_g matrix per hold, eigvalsh and solve on it."""
    J = res.jacobian
    sig = np.asarray(obs.sigma_g, float)
    r = (res.residual_g / sig).ravel()
    if not res.weighted:
        J = J / sig.ravel()[:, None]
    A = np.linalg.pinv(J.T @ J)
    out = []
    for g in [np.flatnonzero(np.asarray(obs.pose_id) == k) for k in np.unique(obs.pose_id)]:
        rows = (g[:, None] * 3 + np.arange(3)).ravel()
        Jg = J[rows]
        M = np.eye(rows.size) - Jg @ A @ Jg.T
        if np.linalg.eigvalsh(0.5 * (M + M.T)).min() < 1e-8:
            out.append(np.inf)
            continue
        rc = np.linalg.solve(M, r[rows])
        out.append(float(rc @ rc))
    return np.asarray(out)


@pytest.mark.parametrize(
    ("model", "protocol", "weighted", "windows"),
    [
        ("model3", "24", True, 6),
        ("model3+temp_bias+temp_scale", "24", True, 20),
        ("model2", "six", False, 6),
        ("model3+g_cross", "cube", True, 3),
        ("model2", "+z,-z,+x,-x,+y", True, 4),  # only +y fixes S_yy: that hold cannot be predicted
    ],
)
def test_cv_scores_small_matrix_form_equals_the_dense_form(model, protocol, weighted, windows):
    """The p x p (push-through) cross-validation equals the dense per-hold inverse to 1e-9,
    infinities (holds the others cannot predict) included."""
    from accellog.calibrate.diagnosis.cross_validation import cv_scores

    name, *add = model.split("+")
    m = build_model(name, add=add)
    truth = build_model("model3").with_terms(["temp_bias"])
    obs = _obs(truth, true_theta(truth, seed=3), protocol, seed=5, windows_per_hold=windows)
    res = fit_model(obs, m, weighted=weighted)
    dense, fast = _cv_scores_dense(res, obs), cv_scores(res, obs)
    np.testing.assert_array_equal(np.isinf(fast), np.isinf(dense))
    assert np.isinf(dense).sum() == (1 if protocol.endswith("+y") else 0)
    np.testing.assert_allclose(fast[np.isfinite(dense)], dense[np.isfinite(dense)], rtol=1e-9)
