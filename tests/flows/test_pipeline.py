"""CLI stages and pipelines end to end on real MCAP files (simulated, seeded) and the seed's data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.sessions import synth_session

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.core.errors import InputError
from accellog.flows.pipeline import load_pipeline, run_pipeline
from accellog.flows.stages import run_fit
from accellog.store.reader import read_attachments, read_session, read_vector3
from accellog.store.writer import write_session

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("sessions")
    out = {}
    out["cal"] = write_session(d / "cal.mcap", synth_session(seed=41, hold_s=12.0))
    out["held"] = write_session(d / "held.mcap", synth_session(seed=42, hold_s=12.0))
    for k, seed in (("static_a", 43), ("static_b", 44)):
        s = synth_session(seed=seed, poses=["+z"], hold_s=65.0, move_s=0.0)
        out[k] = write_session(d / f"{k}.mcap", s)
    return out


def _json(capsys) -> dict:
    return json.loads(capsys.readouterr().out)


def test_fit_evaluate_drift_apply_cli(files, tmp_path, capsys):
    cal = tmp_path / "cal.json"
    assert main(["fit", str(files["cal"]), "--model", "model3", "-o", str(cal), "--json"]) == 0
    d = _json(capsys)
    assert d["terms"] == ["bias", "scale", "cross_axis"]
    assert len(d["params"]) == 12 and all(p["sigma"] > 0 for p in d["params"])
    assert 0.5 < d["chi2_dof"] < 2.0 and d["rms_g"] < 1e-3
    assert load_calibration(cal).fit.weighted is True
    assert main(["evaluate", str(files["static_a"]), "--cal", str(cal), "--json"]) == 0
    ev = _json(capsys)
    assert ev["raw"]["label"] == "no calibration"
    c = ev["calibrated"][0]
    assert set(c["mean_residual_mps2"]) == {"x", "y", "z"} and c["chi2_noise"] >= 0
    assert len(c["displacement_60s_m"]) == 3
    drift = tmp_path / "drift.json"
    assert main(["drift", str(files["static_a"]), "--cal", str(cal), "-o", str(drift), "--json"]) == 0
    dd = _json(capsys)
    assert "invalid once the sensor moves" in dd["drift"]["limits"]
    assert load_calibration(drift).drift is not None
    # tables (no --json) print without error
    assert main(["evaluate", str(files["static_b"]), "--cal", str(cal), "--cal", str(drift)]) == 0
    assert "after the drift model" in capsys.readouterr().out
    out = tmp_path / "applied.mcap"
    assert main(["apply", str(files["cal"]), "--cal", str(cal), "-o", str(out)]) == 0
    src = read_session(files["cal"])
    cp = read_session(out)
    assert np.array_equal(cp.accel_g, src.accel_g) and np.array_equal(cp.t_s, src.t_s)
    assert [p.name for p in cp.poses] == [p.name for p in src.poses]
    _, v, unit, _ = read_vector3(out, "/derived/accel_calibrated")
    assert unit == "g" and np.allclose(v, load_calibration(cal).correct(src), atol=1e-6)  # float32 storage
    assert any(n == "calibration/accel.json" for n, _, _ in read_attachments(out))


def test_segment_artifact_feeds_fit(files, tmp_path, capsys):
    obs = tmp_path / "obs.json"
    assert main(["segment", str(files["cal"]), "-o", str(obs), "--json"]) == 0
    d = _json(capsys)
    assert len(d["poses"]) == 6 and d["n_observations"] > 6
    cal = tmp_path / "c.json"
    assert main(["fit", str(obs), "--model", "model2", "-o", str(cal)]) == 0
    assert "S_zz" in capsys.readouterr().out


def test_workbench_pipeline_ladder(files, tmp_path):
    res = run_pipeline(
        REPO / "pipelines" / "workbench.toml",
        [files["cal"], files["held"], files["static_a"]],
        output_dir=tmp_path / "out",
    )
    lad = {r.model: r for r in res.ladder()}
    assert lad["model1"].chi2_dof > 10 * lad["model3"].chi2_dof
    assert lad["model3"].chi2_dof < 2.0
    assert len(res.pose_evaluations) == 5 and res.pose_evaluations[2].chi2 / res.pose_evaluations[2].dof < 2.5
    assert (tmp_path / "out" / "results.json").exists()
    assert load_calibration(tmp_path / "out" / "cal_model3_temp_bias_nonlin2.json").terms[-1] == "nonlin2"
    assert res.tables()


def test_orientation_free_fit_detects_static_holds():
    ups = np.random.default_rng(0).normal(size=(14, 3))
    s = synth_session(ups=ups, label=False, hold_s=5.0, move_s=2.0, phi=0.0, seed=45)
    out = run_fit(s, "bias+scale+misalignment_tri", orientation_free=True)
    assert len(out.obs.pose_names) >= 12
    S, b = out.cal.S_b()
    assert np.allclose(b, [0.03, -0.02, 0.05], atol=5e-4)
    assert np.allclose(np.diag(S), [1.01, 0.985, 1.02], atol=1e-3)


def test_six_position_pipeline_reproduces_the_seed(shared_data, capsys):
    d = shared_data / "capstone" / "final_trial"
    args = ["six_position_data.csv", "six_position_test_data.csv", "six_position_test_data.csv"]
    args += ["six_position_final_test_data.csv"]
    rc = main(["run", str(REPO / "pipelines" / "six_position.toml"), *(str(d / a) for a in args), "--json"])
    assert rc == 0
    r = _json(capsys)
    last = r["drift_evaluations"][-1]
    assert np.allclose(last["displacement"]["disp_end_m"], [-45.1, 56.8, 16.3], atol=0.05)
    assert np.allclose(last["displacement"]["disp_end_after_drift_m"], [-1.16, -1.31, -6.55], atol=0.005)
    assert r["drift_evaluations"][0]["label"] == "no calibration"
    assert np.allclose(r["drift_evaluations"][0]["displacement"]["disp_end_m"], [1760, 1061, -4014], atol=1.0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('[pipeline]\nname="x"\ninputs=["a"]\n[fit]\ninput="a"\nmodels=["model1"]\n[bogus]\nk=1\n', r"x.toml:7: unknown stage \[bogus\]"),
        ('[pipeline]\nname="x"\ninputs=["a"]\n[fit]\ninput="a"\nmodels=["model1"]\nwindw=2\n', r"x.toml:7: unknown key 'fit.windw'"),
        ('[pipeline]\nname="x"\ninputs=["a"]\n[fit]\ninput="a"\nmodles=["model1"]\n', r"unknown key 'fit.modles' \(did you mean models\?\)"),
        ('[pipeline]\nname="x"\ninputs=["a"]\n[fit]\ninput="a"\nmodels=["model1"]\nweighted="no"\n', r"x.toml:7: 'fit.weighted' must be a bool"),
        ('[pipeline]\nname="x"\ninputs=["a"]\n[fit]\ninput="b"\nmodels=["model1"]\n', r"x.toml:5: 'fit.input' = 'b' is not one of"),
        ('[pipeline]\nname="x"\ninputs=["a"]\n[fit]\ninput="a"\nmodels=["model1"]\n[drift]\nmodel="model3"\nfit_input="a"\n', r"'drift.model' = 'model3' is not in fit.models"),
        ('[pipeline]\nname="x"\ninputs=["a"\n', r"x.toml:\d+: not valid TOML"),
        ('[pipeline]\nname="x"\n', r"missing 'pipeline.inputs'"),
    ],
)  # fmt: skip
def test_pipeline_file_validation(tmp_path, text, match):
    p = tmp_path / "x.toml"
    p.write_text(text)
    with pytest.raises(InputError, match=match):
        load_pipeline(p)


def test_shipped_pipelines_validate_and_count_inputs(files, capsys):
    for name in ("six_position", "twenty_four_position", "workbench"):
        spec = load_pipeline(REPO / "pipelines" / f"{name}.toml")
        assert spec["pipeline"]["name"] == name
    rc = main(["run", str(REPO / "pipelines" / "six_position.toml"), str(files["cal"])])
    assert rc == 2
    assert "takes 4 inputs (calibration, test, drift_fit, drift_apply), got 1" in capsys.readouterr().err
