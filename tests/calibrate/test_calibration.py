"""calibration: Calibration from a fit, JSON round trip, correction, one-line errors on bad files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.sessions import B_TRUE, S_TRUE, synth_session

from accellog.calibrate.calfile.calibration import Calibration, load_calibration
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.model.session_drivers import rate_of_change, session_drivers
from accellog.calibrate.observe.segment import observations
from accellog.core.errors import InputError
from accellog.core.units import STANDARD_GRAVITY_MPS2


@pytest.fixture(scope="module")
def cal3() -> Calibration:
    s = synth_session(seed=11)
    obs = observations(s)
    fit = fit_model(obs, build_model("model3"), weighted=True, gravity_g=1.0)
    return Calibration.from_fit(
        fit,
        obs=obs,
        local_gravity_mps2=9.81,
        sources=[{"path": "synthetic", "sha256": None, "kind": "emulator"}],
    )


def test_from_fit_recovers_truth_and_round_trips(cal3, tmp_path):
    S, b = cal3.S_b()
    assert np.abs(S - S_TRUE).max() < 5e-4 and np.abs(b - B_TRUE).max() < 3e-4
    p = tmp_path / "cal.json"
    cal3.save(p)
    d = json.loads(p.read_text())
    assert d["format"] == "accellog.calibration" and d["format_version"] == 1
    assert d["model"]["terms"] == ["bias", "scale", "cross_axis"]
    assert all({"name", "value", "sigma", "unit"} <= set(q) for q in d["params"])
    assert d["gravity"]["mps2_per_unit"] == pytest.approx(9.81)
    assert d["temperature"]["mean_degC"] == pytest.approx(30.0, abs=0.2)
    back = load_calibration(p)
    assert np.array_equal(back.theta, cal3.theta) and np.array_equal(back.cov, cal3.cov)
    assert back.param_names == cal3.param_names
    assert not list(tmp_path.glob(".cal.json.*"))  # no temp file left behind


def test_correct_inverts_the_model(cal3):
    S, b = cal3.S_b()
    f = np.array([[0.0, 0.0, 1.0], [0.3, -0.2, 0.9]])
    reading = f @ S.T + b
    assert np.allclose(cal3.correct(reading), f, atol=1e-12)
    s = synth_session(seed=12)
    out = cal3.correct(s)
    assert out.shape == (s.n, 3)
    assert np.allclose(cal3.correct_mps2(reading), f * 9.81)


def test_drivers_from_session():
    s = synth_session(seed=13)
    d = session_drivers(s)
    assert np.allclose(d["dtemp_degC_per_s"][100:-100], 0.001, atol=1e-9)
    k = s.slice_time(s.poses[1].start_s + 1.0, s.poses[1].start_s + 1.001).start
    assert d["t_in_pose_s"][k] == pytest.approx(s.t_s[k] - s.poses[1].start_s)
    t = np.linspace(0, 100, 2001)
    assert np.allclose(rate_of_change(t, np.round(3 * t, 1)), 3.0, atol=0.01)


def test_bad_calibration_files(tmp_path, cal3):
    p = tmp_path / "x.json"
    with pytest.raises(InputError, match="no such calibration file"):
        load_calibration(p)
    p.write_text('{"format": "accellog.calibration",\n "params": [1,')
    with pytest.raises(InputError, match=r"x.json:2: not valid JSON"):
        load_calibration(p)
    p.write_text(json.dumps({"cal_type": "Ferraris", "K_a": [[1]]}))
    with pytest.raises(InputError, match="imucal calibration"):
        load_calibration(p)
    p.write_text(json.dumps({"foo": 1}))
    with pytest.raises(InputError, match="not an accellog calibration file"):
        load_calibration(p)
    d = cal3.to_dict()
    d["format_version"] = 99
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match="format_version 99"):
        load_calibration(p)
    d = cal3.to_dict()
    d["covariance"] = d["covariance"][:3]
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"'covariance' must be 12 x 12 numbers"):
        load_calibration(p)
    d = cal3.to_dict()
    d["params"] = d["params"][:3]
    d["covariance"] = [r[:3] for r in d["covariance"][:3]]
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match="do not match model"):
        load_calibration(p)


def test_standard_gravity_convention_units():
    """truth_g = g_local/g0 (standard g): output in standard g, mps2_per_unit = g0."""
    s = synth_session(seed=14, g_scale=9.79 / STANDARD_GRAVITY_MPS2)
    obs = observations(s)
    fit = fit_model(obs, build_model("model3"), gravity_g=9.79 / STANDARD_GRAVITY_MPS2)
    cal = Calibration.from_fit(fit, gravity_convention="local", local_gravity_mps2=9.79)
    assert cal.mps2_per_unit == pytest.approx(STANDARD_GRAVITY_MPS2)
    S, _ = cal.S_b()
    assert np.abs(S - S_TRUE).max() < 5e-4
