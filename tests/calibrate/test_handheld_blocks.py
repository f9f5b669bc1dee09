"""Hand-held sessions without a second session: candidates judged by blocks of the temperature range
and of time on the gravity norm (issue #10: a proxy must not win just because it fits this session).

block_cv on the gravity norm must equal the dense hat-matrix form; on a heat-then-cool session (temperature does
not follow time) the workbench must end at the true temperature effect without a tie, while one
monotonic warm-up gives "cannot decide" (tests/calibrate/test_handheld.py).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
from support.synthetic import cube_poses, synthetic_session, true_theta

from accellog.calibrate.diagnosis.transfer import _whitened, block_cv, block_groups, blocking_drivers
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.effects import HANDHELD_START
from accellog.calibrate.model.fit import fit_orientation_free
from accellog.calibrate.observe.detected_holds import detect_holds
from accellog.cli import main
from accellog.store.writer import write_session


def _session(temp_path, seed: int):
    truth = build_model(HANDHELD_START + "+temp_bias")
    th = true_theta(truth, seed=seed)
    s = synthetic_session(
        truth, th, protocol=cube_poses(6.0), hold_s=6.0, move_s=2.0, temp_path=temp_path, seed=seed
    )
    return dataclasses.replace(s, poses=[]), truth, th


def _dense(res, obs, groups):
    J, r, per = _whitened(res, obs, norm=True)
    assert per == 1
    A = np.linalg.pinv(J.T @ J)
    out = []
    for g in groups:
        M = np.eye(len(g)) - J[g] @ A @ J[g].T
        if np.linalg.eigvalsh(0.5 * (M + M.T)).min() < 1e-6:
            out.append(np.inf)
            continue
        x = np.linalg.solve(M, r[g])
        out.append(float(x @ x))
    return np.asarray(out)


def test_norm_block_cv_equals_the_dense_form():
    s, _, _ = _session(lambda t: 40.0 - 16.0 * np.exp(-np.asarray(t) / 120.0), 2)
    obs, _ = detect_holds(s)
    res = fit_orientation_free(obs, build_model(HANDHELD_START + "+temp_bias"))
    for x in blocking_drivers(obs).values():
        groups = block_groups(x, 5)
        fast, dense = block_cv(res, obs, groups, norm=True), _dense(res, obs, groups)
        np.testing.assert_array_equal(np.isinf(fast), np.isinf(dense))
        np.testing.assert_allclose(fast[np.isfinite(dense)], dense[np.isfinite(dense)], rtol=1e-8)
        assert np.all(np.isfinite(fast)) and np.all(fast > 0)


def test_heat_then_cool_handheld_session_ends_at_the_temperature_effect(tmp_path, capsys):
    T = 26 * 8.0  # 26 holds of 6 s + 2 s moves
    s, _, _ = _session(lambda t: 25.0 + 15.0 * np.sin(np.pi * np.asarray(t) / T), 4)
    path = write_session(tmp_path / "heat_cool.mcap", s)
    assert main(["workbench", str(path), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["handheld"] and d["added"] == ["temp_bias"], d["verdict"]
    assert "cannot decide" not in d["verdict"] and "nothing is missing" in d["verdict"], d["verdict"]
    assert d["ladder"][-1]["chi2_dof"] < 1.5
