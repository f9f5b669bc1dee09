"""evaluate on a session that visits every pose twice, heating then cooling (issue 10 item 2): a
calibration blind to temperature leaves residuals whose pose mean hides the heat/cool split and
the trend inside each hold; the per-pass table, the JSON and the .rrd show them. The control (the
temperature term fitted) claims nothing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rrd_readback import load_rrd
from support.synthetic import synthetic_session, true_theta

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.observe.segment import observations
from accellog.cli import main
from accellog.core.protocol import six_position
from accellog.flows.stages import run_evaluate_report
from accellog.store.writer import write_session

TB = np.array([3e-4, -2e-4, 2.5e-4])
"""Hidden bias temperature coefficient (g/degC)."""


def heat_cool(t):
    """25 -> 35 degC over the first round of six poses, back to 25 degC over the second."""
    return np.interp(t, [0.0, 135.0, 270.0], [25.0, 35.0, 25.0])


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("passes")
    model = build_model("model3+temp_bias")
    th = true_theta(model, seed=3)
    th[model.slices["temp_bias"]] = TB
    ramp = lambda t: 15.0 + np.asarray(t) / 32.0  # noqa: E731 - 15 -> 40 degC over the 24 poses
    for name, terms, temp, proto in (
        ("m3", "model3", lambda t: np.full(np.shape(t), 25.0), "six"),
        ("tb", "model3+temp_bias", ramp, "24"),  # covers the test's temperatures, precise enough
    ):
        s = synthetic_session(model, th, protocol=proto, hold_s=30.0, temp_path=temp, seed=11)
        obs = observations(s)
        Calibration.from_fit(fit_model(obs, build_model(terms)), obs=obs).save(d / f"{name}.json")
    twice = six_position(20.0) * 2
    s = synthetic_session(model, th, protocol=twice, hold_s=20.0, move_s=2.5, temp_path=heat_cool, seed=12)
    write_session(d / "test.mcap", s)
    return d


@pytest.mark.parametrize("stream", [True, False])
def test_passes_that_disagree_and_trends_are_reported_by_pose_name(files, stream):
    rep = run_evaluate_report(files / "test.mcap", [files / "m3.json", files / "tb.json"], stream=stream)
    _raw, m3, tb = rep.poses
    faces = [p.name for p in six_position(20.0)]
    assert [p.pose for p in m3.passes] == faces * 2
    assert [p.visit for p in m3.passes] == [1] * 6 + [2] * 6
    first, second = m3.passes[0], m3.passes[6]  # heating (25-27 degC), cooling (33-35 degC)
    assert first.temp_max_degC < 28.0 and second.temp_min_degC > 32.0
    # the residual follows the hidden coefficient: the passes differ by TB * dT, beyond noise
    dT = np.mean([second.temp_min_degC, second.temp_max_degC]) - np.mean(
        [first.temp_min_degC, first.temp_max_degC]
    )
    np.testing.assert_allclose(second.mean_resid_g - first.mean_resid_g, TB * dT, rtol=0.15, atol=3e-5)
    d = m3.to_dict()
    assert all(v["p_value"] < 1e-6 for v in d["pass_disagreement"].values())
    slopes = {(t["pose"], t["driver"]): t for t in d["trends"]}
    t_px = slopes[(faces[0], "temp_degC")]
    np.testing.assert_allclose(t_px["slope"], TB, atol=4 * max(t_px["sigma"]))
    assert t_px["flagged"] and t_px["unit"] == "g/degC"
    assert m3.flags[0].startswith("model3: passes disagree beyond noise in 6 of 6 revisited poses")
    assert m3.flags[1].startswith("model3: residuals trend with temp_degC inside")
    # the control: the temperature term is in the calibration, nothing is flagged
    assert tb.flags == [], tb.flags
    assert all(v["p_value"] > 1e-3 for v in tb.to_dict()["pass_disagreement"].values())


def test_evaluate_cli_prints_the_pass_table_and_draws_residuals_against_drivers(files, capsys, tmp_path):
    args = ["evaluate", str(files / "test.mcap"), "--cal", str(files / "m3.json")]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "residual per pass" in out and "passes disagree beyond noise" in out.replace("\n", " ")
    assert main([*args, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)["calibrated"][0]
    assert {"poses", "rms_g", "chi2_dof", "passes", "trends", "flags", "pass_disagreement"} <= set(d)
    assert len(d["passes"]) == 12 and d["passes"][6]["pose"] == d["passes"][0]["pose"] == "+z"
    assert d["passes"][6]["visit"] == 2
    rrd = tmp_path / "ev.rrd"
    assert main([*args, "--rrd", str(rrd)]) == 0
    r = load_rrd(rrd)
    ents = {e for e in r.entities if e.startswith("/residual_vs/")}
    assert any(e.startswith("/residual_vs/temp_degC/model3/") for e in ents), sorted(ents)[:10]
    assert any(e.startswith("/residual_vs/t_s/") for e in ents)
