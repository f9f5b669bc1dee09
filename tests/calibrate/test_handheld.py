"""Hand-held sessions without pose labels (issue #10, item 3): diagnose works on the detected
static intervals with the orientation-free gravity-norm residual, says what the norm cannot
identify, and prints the detected intervals with the detector settings (CLI options)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
from support.synthetic import cube_poses, synthetic_session, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.effects import HANDHELD_START
from accellog.cli import main
from accellog.store.writer import write_session


def _unlabelled(tmp_path, terms: str, seed: int):
    truth = build_model(terms)
    th = true_theta(truth, seed=seed)
    s = synthetic_session(
        truth,
        th,
        protocol=cube_poses(6.0),
        hold_s=6.0,
        move_s=2.0,
        temp_path=lambda t: 40.0 - 16.0 * np.exp(-t / 120.0),
        seed=seed,
    )
    path = write_session(tmp_path / f"hand_{seed}.mcap", dataclasses.replace(s, poses=[]))
    return path, truth, th


def test_handheld_warmup_temperature_effect_found_on_detected_holds(tmp_path, capsys):
    path, truth, th = _unlabelled(tmp_path, HANDHELD_START + "+temp_bias", 3)
    assert main(["diagnose", str(path), "--json", "--detect-window-s", "0.5"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["handheld"] and d["model"] == HANDHELD_START
    det = d["detected"]
    assert det["window_s"] == 0.5 and det["threshold"] is None
    assert len(det["intervals"]) >= 20  # 26 holds, every one a distinct orientation
    assert all(iv["end_s"] > iv["start_s"] and iv["n"] > 100 for iv in det["intervals"])
    assert d["missing"] and d["best"] == "temp_bias", d["verdict"]
    bt = d["candidates"][0]["params"]
    truth_p = dict(zip(truth.param_names, th, strict=True))
    for a in "xyz":
        v, s = bt[f"bT_{a}"]
        assert abs(v - truth_p[f"bT_{a}"]) < 3 * s, (a, v, truth_p[f"bT_{a}"], s)
    advice = " ".join(d["advice"])
    assert "cross_axis: cannot be identified without orientations" in advice
    assert "rotation of the sensor frame" in advice and "fixture_tilt: needs pose labels" in advice
    # with the effect added the norm residual is at the noise floor
    assert main(["diagnose", str(path), "--model", HANDHELD_START, "--add", "temp_bias", "--json"]) == 0
    d2 = json.loads(capsys.readouterr().out)
    assert not d2["missing"] and d2["chi2_dof"] < 1.5, d2["verdict"]


def test_handheld_fixed_threshold_and_clean_session(tmp_path, capsys):
    path, _, _ = _unlabelled(tmp_path, HANDHELD_START, 4)
    assert main(["diagnose", str(path), "--json", "--threshold", "4"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["detected"]["threshold"] == 4.0 and len(d["detected"]["intervals"]) >= 20
    assert not d["missing"] and d["best"] is None, d["verdict"]
    assert main(["diagnose", str(path)]) == 0
    out = capsys.readouterr().out
    assert "static intervals detected" in out and "nothing is missing that the norm can show" in out


EDGES = "+z,-z,+y,-y,+x,-x,+x+y,-x-y,+x-y,-x+y,+x+z,-x-z,+x-z,-x+z,+y+z,-y-z,+y-z,-y+z"


def test_handheld_gyro_from_rotations_between_detected_holds(tmp_path, capsys):
    """An emulated session (gyro and accel) with its labels removed: `fit --orientation-free`
    calibrates the gyro from the detected intervals and the rotations between them (imu_tk style),
    reports it in --json, and recovers the chip's gyro errors (the emulator's truth: M = diag(1 + s)
    + C within 5 sigma + 2e-3, the bias within 0.02 deg/s), as the labelled holds' calibration does."""
    from accellog.acquire.emulator.sensor_model import GyroErrors
    from accellog.flows.simulate import Scenario, simulate
    from accellog.store.reader import read_session

    src = tmp_path / "edges.mcap"
    simulate(Scenario(protocol=EDGES, hold_s=5.0, move_s=2.0, sample_rate_hz=200.0, seed=5), src)
    labelled = read_session(src)
    hand = write_session(tmp_path / "hand.mcap", dataclasses.replace(labelled, poses=[]))
    out = {}
    for name, path, extra in (("labelled", src, []), ("hand", hand, ["--orientation-free"])):
        args = [
            "fit",
            str(path),
            "--model",
            HANDHELD_START,
            *extra,
            "-o",
            str(tmp_path / f"{name}.json"),
            "--json",
        ]
        assert main(args) == 0
        capsys.readouterr()
        out[name] = json.loads((tmp_path / f"{name}.json").read_text())["gyro"]
    stored = json.loads((tmp_path / "hand.json").read_text())["fit"]["detected_intervals"]
    assert len(stored) == 18 and all(iv["n"] > 500 and iv["end_s"] > iv["start_s"] for iv in stored)
    chip = GyroErrors.datasheet(Scenario().chip_seed)  # the chip the emulator drew for the session
    M_true = np.diag(1.0 + chip.scale) + chip.cross_axis
    for name in ("labelled", "hand"):
        g = out[name]
        assert g is not None and g["matrix"] is not None and g["t_ref_degC"] == chip.t_ref_degC, (name, g)
        M, s = np.array(g["matrix"]), np.array(g["matrix_sigma"])
        assert np.all(np.abs(M - M_true) < 5 * s + 2e-3), (name, M - M_true, s)
        b = np.array(g["bias_dps"])
        assert np.all(np.abs(b - chip.bias_dps) < 0.02), (name, b, chip.bias_dps)


def test_handheld_workbench_loop_ladder_and_detected_intervals_in_rrd(tmp_path, capsys):
    """workbench on an unlabelled warm-up: finds the temperature bias on the gravity norm, says it
    cannot tell it from a time drift on this one session and what recording would, says what the
    norm cannot identify, and draws the detected intervals on the .rrd timeline."""
    from rrd_readback import load_rrd

    path, _, _ = _unlabelled(tmp_path, HANDHELD_START + "+temp_bias", 5)
    rrd = tmp_path / "wb.rrd"
    assert main(["workbench", str(path), "--json", "--rrd", str(rrd)]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["handheld"] and d["start"] == HANDHELD_START and d["added"] == ["temp_bias"], d["verdicts"]
    # one monotonic warm-up: temperature follows time, so the blocked validation cannot tell
    # temp_bias from a time drift, and the verdict says so (never "nothing is missing")
    assert "cannot decide between temp_bias vs time_drift" in d["verdict"], d["verdict"]
    assert "nothing is missing" not in d["verdict"]
    assert any("heat then cool" in a for a in d["advice"]), d["advice"]
    assert any(
        s.startswith("cross_axis: cannot be identified without orientations") for s in d["cannot_identify"]
    )
    lad = d["ladder"]
    assert [r["model"] for r in lad] == [HANDHELD_START, HANDHELD_START + "+temp_bias"]
    assert lad[0]["chi2_dof"] > 5 and lad[1]["chi2_dof"] < 1.5 and lad[1]["added"] == ["temp_bias"]
    ivs = d["detected"]["intervals"]
    assert len(ivs) >= 20
    r = load_rrd(rrd)
    t, v = r.series("detect/still")
    np.testing.assert_allclose(t, [x for iv in ivs for x in (iv["start_s"], iv["end_s"])], atol=1e-9)
    assert v[:, 0].tolist() == [1.0, 0.0] * len(ivs)
    logs = r.texts("detect/log")
    assert len(logs) == len(ivs) and f"n {ivs[0]['n']}" in logs[0][1] and "swept 2..10" in logs[0][1]
    assert "Detected static intervals" in r.static("docs/detected", "TextDocument:text")[0]
    bars = r.ladder_bars("log10_chi2_dof")
    np.testing.assert_allclose([b[2] for b in bars], np.log10([x["chi2_dof"] for x in lad]), rtol=1e-6)
    # the still signal is drawn over the raw accel plot
    raw = next(v for v in r.views() if v["origin"] == "/accel/raw")
    assert any("/detect/still" in c for c in raw["contents"]), raw


def test_handheld_workbench_on_real_ferraris_session_says_what_it_lacks(tmp_path, capsys, shared_data):
    """Real data (imucal's Ferraris recording, 102.4 Hz) with its labels removed: six faces only,
    so the orientation-free fit is refused with one line naming the file, and no .rrd is written."""
    from accellog.flows.stages import load_input

    s = load_input(shared_data / "imucal" / "example_ferraris_session.csv")
    assert len(s.poses) == 6
    path = write_session(tmp_path / "ferraris_unlabelled.mcap", dataclasses.replace(s, poses=[]))
    rrd = tmp_path / "f.rrd"
    assert main(["workbench", str(path), "--json", "--rrd", str(rrd)]) != 0
    err = capsys.readouterr().err
    assert "accellog: error:" in err and "ferraris_unlabelled.mcap" in err
    assert "at most 6 distinct static orientations" in err and "Traceback" not in err
    assert not rrd.exists()
