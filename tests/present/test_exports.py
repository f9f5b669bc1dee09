"""`accellog export`: each target's documented names and units, checked by applying the target's own
correction formula to the readings and comparing with accellog's calibration."""

from __future__ import annotations

import json

import numpy as np
import pytest
from ruamel.yaml import YAML

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("export")
    sim, still = d / "six.mcap", d / "still.mcap"
    simulate(Scenario(protocol="six", hold_s=4.0, move_s=1.0, sample_rate_hz=200.0, seed=21), sim)
    simulate(Scenario(protocol="+z", hold_s=120.0, sample_rate_hz=200.0, seed=22), still)
    cals = {}
    for model in ("model2", "model3"):
        cals[model] = d / f"{model}.json"
        assert main(["fit", str(sim), "-m", model, "-o", str(cals[model])]) == 0
    return sim, still, cals


def _params(text: str, sep: str) -> dict[str, float]:
    out = {}
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.split(sep)
        name, value = (parts[2], parts[3]) if sep == "\t" else (parts[0], parts[1])
        out[name] = float(value)
    return out


@pytest.mark.parametrize(("target", "sep", "off", "scl"), [
    ("px4", "\t", "CAL_ACC0_{}OFF", "CAL_ACC0_{}SCALE"),
    ("ardupilot", ",", "INS_ACCOFFS_{}", "INS_ACCSCAL_{}"),
])  # fmt: skip
def test_autopilot_params_reproduce_the_calibration(fitted, tmp_path, capsys, target, sep, off, scl):
    sim, _, cals = fitted
    s = read_session(sim)
    raw_mps2 = s.accel_g * G0
    for model, tol in (("model2", 1e-6), ("model3", None)):
        out = tmp_path / f"{model}.{target}"
        rc, _, err = _run(["export", cals[model], "--to", target, "-o", out], capsys)
        assert rc == 0, err
        p = _params(out.read_text(), sep)
        o = np.array([p[off.format(a)] for a in "XYZ"])
        k = np.array([p[scl.format(a)] for a in "XYZ"])
        corrected = (raw_mps2 - o) * k  # PX4 Correct() / ArduPilot _rotate_and_correct_accel
        ref = load_calibration(cals[model]).correct_mps2(s)
        err_mps2 = np.max(np.abs(corrected - ref))
        if tol is not None:  # bias + scale: the autopilot form holds it exactly (9 digits printed)
            assert err_mps2 < tol * G0
            assert "cross-axis" not in err
        else:  # cross-axis is dropped and the stated bound covers the error
            bound = float(err.split("up to ")[1].split(" m/s^2")[0])
            assert 0 < err_mps2 <= 1.5 * bound
        gyro = [n for n in p if "GYR" in n]
        assert len(gyro) in (0, 3)


def test_kalibr_and_ros_yaml(fitted, tmp_path, capsys):
    _, still, cals = fitted
    rc, _, err = _run(["export", cals["model3"], "--to", "kalibr"], capsys)
    assert rc != 0 and "--noise-from" in err and len(err.strip().splitlines()) == 1
    out = tmp_path / "imu.yaml"
    rc, stdout, err = _run(
        ["export", cals["model3"], "--to", "kalibr", "--noise-from", still, "-o", out, "--json"], capsys
    )
    assert rc == 0, err
    y = YAML(typ="safe").load(out.read_text())
    assert set(y) == {"accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                      "gyroscope_random_walk", "rostopic", "update_rate"}  # fmt: skip
    assert y["update_rate"] == pytest.approx(200.0, rel=1e-3) and y["rostopic"] == "/imu/data"
    # emulator: 300 ug/sqrt(Hz) one-sided -> two-sided density sigma_c = 300e-6 g0 / sqrt(2) before the DLPF
    assert 0.3 < y["accelerometer_noise_density"] / (300e-6 * G0 / np.sqrt(2)) < 1.2
    assert 0 < y["accelerometer_random_walk"] < 1e-2 and 0 < y["gyroscope_noise_density"] < 1e-2
    lines = out.read_text().splitlines()  # units stay as comments on the value's line
    assert any(ln.startswith("update_rate: ") and ln.endswith("  # Hz") for ln in lines)
    units = json.loads(stdout)["units"]
    assert units["accelerometer_random_walk"] == "m/s^3/sqrt(Hz)"
    out = tmp_path / "ros.yaml"
    assert _run(["export", cals["model3"], "--to", "ros", "-o", out], capsys)[0] == 0
    p = YAML(typ="safe").load(out.read_text())  # imu_calib: corrected = SM raw - bias
    cal = load_calibration(cals["model3"])
    s = read_session(fitted[0])
    SM, bias = np.reshape(p["SM"], (3, 3)), np.array(p["bias"])
    assert np.allclose((s.accel_g * G0) @ SM.T - bias, cal.correct_mps2(s), rtol=0, atol=1e-6)
    out = tmp_path / "plain.yaml"
    assert _run(["export", cals["model3"], "--to", "yaml", "-o", out], capsys)[0] == 0
    plain = YAML(typ="safe").load(out.read_text())
    assert plain["params"] and len(plain["S"]) == 9
    # floats are written as repr: the reload is the calibration's float64, bit for bit
    assert plain["S"] == np.asarray(cal.S_b()[0]).ravel().tolist()
    assert [p["value"] for p in plain["params"].values()] == [float(v) for v in cal.theta]
