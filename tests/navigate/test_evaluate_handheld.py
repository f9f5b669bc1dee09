"""evaluate on hand-held sessions (issue 10 item 3): without pose labels the session is judged on its
detected static intervals with the gravity-norm residual |f| - g, per interval, with chi2/dof
against the window noise and a line on what the norm cannot judge."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
from support.synthetic import cube_poses, synthetic_session, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.effects import HANDHELD_START
from accellog.cli import main
from accellog.flows.stages import load_input
from accellog.store.writer import write_session


def _unlabelled(path, seed: int):
    truth = build_model(HANDHELD_START)
    s = synthetic_session(truth, true_theta(truth, seed=5), protocol=cube_poses(6.0), hold_s=6.0, move_s=2.0,
                          seed=seed)  # fmt: skip
    return write_session(path, dataclasses.replace(s, poses=[]))


def test_simulated_imu_tk_session_is_judged_on_detected_intervals(tmp_path, capsys):
    cal_s, test_s = _unlabelled(tmp_path / "cal.mcap", 1), _unlabelled(tmp_path / "test.mcap", 2)
    cal = tmp_path / "cal.json"
    assert main(["fit", str(cal_s), "--orientation-free", "--model", HANDHELD_START, "-o", str(cal)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(test_s), "--cal", str(cal), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["kind"] == "handheld" and "rotation of the sensor frame" in d["cannot_judge"]
    raw, calib = d["raw"], d["calibrated"][0]
    assert len(calib["intervals"]) >= 20  # 26 holds of the cube
    assert all(iv["end_s"] > iv["start_s"] and iv["n_windows"] >= 1 for iv in calib["intervals"])
    # the calibration brings the norm residual to the noise floor, the raw reading is far from it
    assert calib["chi2_dof"] < 2.0, calib["chi2_dof"]
    assert raw["chi2_dof"] > 100 * calib["chi2_dof"] and raw["rms_g"] > 10 * calib["rms_g"]
    assert main(["evaluate", str(test_s), "--cal", str(cal)]) == 0
    out = capsys.readouterr().out
    assert "per detected static interval" in out and "cannot judge" in out


def test_handheld_evaluate_rrd_plots_the_norm_residual_against_the_drivers(tmp_path, capsys):
    from rrd_readback import load_rrd

    cal_s, test_s = _unlabelled(tmp_path / "cal.mcap", 1), _unlabelled(tmp_path / "test.mcap", 2)
    cal = tmp_path / "cal.json"
    assert main(["fit", str(cal_s), "--orientation-free", "--model", HANDHELD_START, "-o", str(cal)]) == 0
    rrd = tmp_path / "ev.rrd"
    assert main(["evaluate", str(test_s), "--cal", str(cal), "--rrd", str(rrd)]) == 0
    capsys.readouterr()
    r = load_rrd(rrd)
    ents = {e for e in r.entities if e.startswith("/residual_vs/")}
    for drv in ("t_s", "f_x_g"):  # raw reading and the calibration, one norm series each
        norm = sorted(e for e in ents if e.startswith(f"/residual_vs/{drv}/") and e.endswith("/norm"))
        assert len(norm) == 2, sorted(ents)
        pts = np.asarray(r.static(norm[0], "Points2D:positions"), float)
        assert pts.shape[0] >= 20


def test_real_ferraris_session_without_labels(tmp_path, capsys, shared_data):
    """imucal's Ferraris recording (102.4 Hz): fitted with its labels, evaluated with them removed.
    The six faces are found again; the calibration's norm residual is ~1 mg, the raw reading's ~57 mg
    (real holds scatter beyond the window noise: chi2/dof stays well above 1, as the fit says)."""
    s = load_input(shared_data / "imucal" / "example_ferraris_session.csv")
    lab = write_session(tmp_path / "lab.mcap", s)
    unl = write_session(tmp_path / "unl.mcap", dataclasses.replace(s, poses=[]))
    cal = tmp_path / "cal.json"
    assert main(["fit", str(lab), "-o", str(cal)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(unl), "--cal", str(cal), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["kind"] == "handheld"
    ivs = d["calibrated"][0]["intervals"]
    ups = np.array([iv["up_sensor"] for iv in ivs])
    faces = {tuple(np.round(u).astype(int)) for u in ups}
    assert len(faces) == 6, faces
    assert d["calibrated"][0]["rms_g"] < 3e-3 and d["raw"]["rms_g"] > 10 * d["calibrated"][0]["rms_g"]
