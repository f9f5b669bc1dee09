"""Effect library and model composition: names, presets, forward/inverse, user effects, specs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.synthetic import cube_poses, true_theta

from accellog.calibrate.model.compose import build_model, model_from_spec
from accellog.calibrate.model.effects import LIBRARY, load_effects_file
from accellog.cli import main
from accellog.core.errors import InputError, ModelError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
ARCH_NAMES = [
    "bias",
    "scale",
    "cross_axis",
    "misalignment_tri",
    "temp_bias",
    "temp_bias2",
    "temp_scale",
    "temp_scale2",
    "nonlin2",
    "nonlin3",
    "g_cross",
    "time_drift",
    "warmup",
    "fixture_tilt",
    "clock",
]


def test_library_has_exactly_the_architecture_names():
    assert list(LIBRARY) == ARCH_NAMES


def test_presets_match_the_seed():
    m1, m2, m3 = (build_model(f"model{i}") for i in (1, 2, 3))
    assert m1.param_names == ["b_x", "b_y", "b_z"]
    assert m2.param_names == ["b_x", "b_y", "b_z", "S_xx", "S_yy", "S_zz"]
    assert m3.n_params == 12 and {"S_xy", "S_zy", "S_yx"} <= set(m3.param_names)
    assert build_model("bias+scale+cross_axis").param_names == m3.param_names
    th = m3.initial_theta()
    S, b = m3.S_b(th)
    np.testing.assert_array_equal(S, np.eye(3))
    np.testing.assert_array_equal(b, np.zeros(3))
    assert m3.param_units[0] == "g"


def test_unknown_name_lists_valid_names():
    with pytest.raises(ModelError, match="valid names: model1, model2, model3, bias"):
        build_model("model3", add=["temperature"])
    with pytest.raises(ModelError, match="same terms"):
        build_model("model3+misalignment_tri")


def test_missing_driver_says_what_to_record():
    m = build_model("model3", add=["temp_bias"])
    with pytest.raises(ModelError, match=r"temp_degC.*TEMP_OUT"):
        m.predict(m.initial_theta(), np.array([[0, 0, 1.0]]), {"t_s": np.zeros(1)})


def test_seed_form_predict_is_S_a_plus_b():
    m = build_model("model3")
    rng = np.random.default_rng(0)
    th = true_theta(m, seed=4)
    S, b = m.S_b(th)
    f = rng.normal(size=(50, 3))
    np.testing.assert_allclose(m.predict(th, f, {}), f @ S.T + b, atol=1e-15)


@pytest.mark.parametrize(
    "extra",
    [
        [],
        ["temp_scale", "temp_scale2", "temp_bias"],
        ["nonlin2", "nonlin3", "g_cross"],
        ["warmup", "time_drift", "temp_bias2"],
    ],
)
def test_correct_inverts_predict(extra):
    m = build_model("model3", add=extra)
    th = true_theta(m, seed=7)
    rng = np.random.default_rng(1)
    n = 2000
    f = rng.normal(size=(n, 3)) * 0.8
    drv = {"t_s": np.linspace(0, 900, n), "temp_degC": rng.uniform(15, 45, n)}
    a = m.predict(th, f, drv)
    assert np.max(np.abs(a - f)) > 1e-3  # the effects do something
    np.testing.assert_allclose(m.correct(th, a, drv), f, atol=1e-12)


def test_fixture_tilt_rotates_truth_only():
    m = build_model("model3+fixture_tilt")
    th = m.initial_theta()
    th[m.index["tilt_x_rad"]] = 0.01
    poses = cube_poses()
    up = np.array([p.up_sensor for p in poses])
    q = np.array([p.q_sensor_to_world for p in poses])
    f = m.truth_g(th, up, q, 1.0)
    np.testing.assert_allclose(np.linalg.norm(f, axis=1), 1.0, atol=1e-12)
    ang = np.degrees(np.arccos(np.clip(np.sum(f * up, axis=1), -1, 1)))
    np.testing.assert_allclose(ang, np.degrees(0.01), rtol=1e-6)
    with pytest.raises(ModelError, match="24-pose"):
        m.truth_g(th, up, None, 1.0)


def test_user_effect_file_round_trip(tmp_path):
    m = build_model("model3", add=["humidity_bias"], effects_file=EXAMPLES / "effects_humidity.py")
    assert m.param_names[-3:] == ["hb_x", "hb_y", "hb_z"] and m.param_units[-1] == "g/%RH"
    spec = json.loads(json.dumps(m.to_spec()))
    assert spec["effects_file_sha256"] and spec["terms"][-1] == "humidity_bias"
    with pytest.raises(ModelError, match=r"--effects-file.*"):
        model_from_spec(spec)  # the spec names a file: never imported on its own
    m2 = model_from_spec(spec, EXAMPLES / "effects_humidity.py")
    assert m2.param_names == m.param_names
    th = true_theta(m, {"hb_x": 2e-4, "hb_y": -1e-4, "hb_z": 3e-4}, seed=2)
    f = np.tile([0.0, 0.0, 1.0], (5, 1))
    drv = {"humidity_pct": np.linspace(30, 70, 5)}
    a = m2.predict(th, f, drv)
    np.testing.assert_allclose(m2.correct(th, a, drv), f, atol=1e-12)
    with pytest.raises(ModelError, match="humidity_pct"):
        m2.predict(th, f, {})
    # the file changed since the model was fitted: refused before it runs
    copy = tmp_path / "h.py"
    copy.write_text((EXAMPLES / "effects_humidity.py").read_text())
    spec2 = build_model("model1", add=["humidity_bias"], effects_file=copy).to_spec()
    copy.write_text(copy.read_text() + "\n# edited\n")
    with pytest.raises(InputError, match="sha256"):
        model_from_spec(spec2, copy)


def test_bad_effects_files(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("x = (\n")
    with pytest.raises(InputError, match=r"bad.py:\d"):
        load_effects_file(bad)
    empty = tmp_path / "empty.py"
    empty.write_text("x = 1\n")
    with pytest.raises(InputError, match="no effects"):
        load_effects_file(empty)
    clash = tmp_path / "clash.py"
    clash.write_text(
        "from accellog.calibrate.model.effects import Effect\nE = Effect('bias', (), contribution=lambda p, f, d: f*0)\n"
    )
    with pytest.raises(InputError, match="clashes"):
        load_effects_file(clash)


def test_cli_effects_lists_library(capsys):
    assert main(["effects", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["effect"] for r in rows] == ARCH_NAMES
    assert main(["effects", "--effects-file", str(EXAMPLES / "effects_creep.py")]) == 0
    out = capsys.readouterr().out
    assert "pose_creep2" in out and "tau_warmup_s [s]" in out
    assert main(["effects", "--effects-file", "/nonexistent/e.py"]) == 2
    assert "accellog: error:" in capsys.readouterr().err


def test_correct_handles_long_sessions_vectorised():
    """3.6e6 samples (1 h at 1 kHz) with a temperature-dependent S in one call; the inverse is exact
    (its speed is measured in benchmarks/bench_fit_speed.py, not here)."""
    m = build_model("model3", add=["temp_bias", "temp_scale"])
    th = true_theta(m, seed=1)
    n = 3_600_000
    a = np.tile([0.01, -0.02, 1.0], (n, 1))
    drv = {"temp_degC": np.linspace(20, 40, n)}
    f = m.correct(th, a, drv)
    assert f.shape == (n, 3) and np.all(np.isfinite(f))
    idx = np.array([0, 1, n // 3, n // 2, n - 1])
    back = m.predict(th, f[idx], {"temp_degC": drv["temp_degC"][idx]})
    np.testing.assert_allclose(back, a[idx], atol=1e-12)
