"""The .rrd files written by the pipeline commands (--rrd) and by `accellog demo`, read back:
what a user looks for is there, and the numbers are the pipeline's numbers."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rrd_readback import load_rrd

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import run_fit
from accellog.store.reader import read_session


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    d = tmp_path_factory.mktemp("rrdpipe")
    cal, test = d / "cal.mcap", d / "test.mcap"
    simulate(Scenario(protocol="six", hold_s=6.0, move_s=2.0, sample_rate_hz=200.0, seed=1), cal)
    simulate(Scenario(protocol="+z", hold_s=25.0, sample_rate_hz=200.0, seed=2), test)
    return d, cal, test


def test_fit_rrd_has_raw_calibrated_holds_and_residuals(sessions, capsys):
    d, cal_mcap, _ = sessions
    out, rrd = d / "m3.json", d / "fit.rrd"
    assert main(["fit", str(cal_mcap), "-o", str(out), "--rrd", str(rrd), "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)
    s = read_session(cal_mcap)
    cal = load_calibration(out)
    r = load_rrd(rrd)
    t, raw = r.series("/accel/raw")
    np.testing.assert_allclose(t, s.t_s, atol=1e-9)
    np.testing.assert_allclose(raw, s.accel_g, rtol=0, atol=1e-12)
    _, calibrated = r.series("/accel/model3")
    np.testing.assert_allclose(calibrated, cal.correct(s), rtol=0, atol=1e-12)
    # each hold's 0/1 series is 1 exactly inside its labelled window
    for k, p in enumerate(s.poses):
        tk, on = r.series(f"/poses/active/{k:02d}")
        inside = tk[on.ravel() > 0.5]
        assert inside.min() == pytest.approx(p.start_s, abs=1e-6) and inside.max() <= p.end_s + 1e-6
    # residual bars: measured - predicted per pose (mg) = the fit's window residuals averaged per pose
    fo = run_fit(s, "model3")
    expected = np.array([fo.fit.residual_g[fo.obs.pose_id == k].mean(axis=0) for k in range(6)]) * 1000
    bars = np.column_stack([r.bar_values(f"/residuals/model3/{a}") for a in "xyz"])
    np.testing.assert_allclose(bars, expected, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(
        cal.theta, [p["value"] for p in fit["params"]] if "params" in fit else cal.theta
    )
    # ... and drawn as bars named by pose (a 2D view: the bar chart view only numbers its bars)
    assert any(v["class"] == "2D" and v["origin"] == "/charts/residuals/model3" for v in r.views())
    assert r.static("/charts/residuals/model3/ticks", "Points2D:labels")[:6] == list(fo.obs.pose_names)
    assert any(e.startswith("/docs/parameters") for e in r.entities)


def test_evaluate_rrd_tracks_end_at_the_reported_displacement(sessions, capsys):
    d, cal_mcap, test = sessions
    out = d / "m3b.json"
    assert main(["fit", str(cal_mcap), "-o", str(out)]) == 0
    capsys.readouterr()
    rrd = d / "eval.rrd"
    assert main(["evaluate", str(test), "--cal", str(out), "--rrd", str(rrd), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    r = load_rrd(rrd)
    for ev in [res["raw"], *res["calibrated"]]:
        label = ev["label"].replace(" ", "_")
        _, disp = r.series(f"/tracks/test/{label}")
        np.testing.assert_allclose(disp[-1], ev["displacement"]["disp_end_m"], rtol=1e-9, atol=1e-9)
    assert "/world/tracks/test/model3" in r.entities
    assert any(v["class"] == "3D" and v["origin"] == "/world" for v in r.views())


@pytest.mark.slow
def test_demo_rrd_tells_the_whole_story(tmp_path):
    rrd = tmp_path / "demo.rrd"
    assert main(["demo", "--quick", "-o", str(tmp_path / "demo"), "--rrd", str(rrd)]) == 0
    r = load_rrd(rrd)
    ents = r.entities
    for e in (
        "/accel/raw",
        "/accel/Model_3",
        "/temperature",
        "/residuals/model3/x",
        "/tracks/test/no_calibration",
        "/tracks/test/Model_3_drift_model",
        "/world/tracks/robot/truth",
        "/docs/ladder",
        "/docs/results/robot_tracks",
    ):
        assert e in ents, e
    names = {v["name"] for v in r.views()}
    assert {"static test tracks 3D (m)", "robot tracks vs truth (m)"} <= names
    # every time-series view opens on its own data's time range (issue 10), e.g. the robot tab
    plots = [v for v in r.views() if v["class"] == "TimeSeries"]
    assert plots and all(v["axis_range"] and None not in v["time_range"] for v in plots)
    robot_t = r.series("/tracks/robot/Model_3")[0]
    robot = next(v for v in plots if v["name"] == "Model 3: position (m)")
    np.testing.assert_allclose(robot["time_range"], (robot_t.min(), robot_t.max()), atol=1e-9)
    # the ladder's held-out RMS falls step by step to the final model
    heldout = [v for _, _, v in r.ladder_bars("log10_heldout_rms_mg")]  # log10 mg
    assert heldout[-1] < heldout[2] - np.log10(5)  # model3 + found effects vs model3
    # the robot tracks end where the error table says they end
    truth_end = r.series("/tracks/robot/truth")[1][-1]
    _, model3 = r.series("/tracks/robot/Model_3")
    doc = r.static("/docs/results/robot_tracks", "TextDocument:text")[0]
    row = next(line for line in doc.splitlines() if line.startswith("| Model 3 |"))
    final_err = float(row.split("|")[2])
    assert np.linalg.norm(model3[-1] - truth_end) == pytest.approx(final_err, rel=0.05, abs=0.01)
