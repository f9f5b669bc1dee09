"""`accellog export` read the way each consumer reads it: imu_calib's ``SM raw - bias``
(dpkoch/imu_calib AccelCalib::applyCalib), ArduPilot's ``_rotate_and_correct_accel`` (driver rotation,
then (accel - offset) .* scale) and PX4's ``Correct()`` ((data - offset) .* scale after the driver's
rotation), applied to raw samples and compared with `accellog apply`'s correction: 1e-6 where the
format holds the model, within the loss the header states where it does not."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from ruamel.yaml import YAML

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.calibrate.calfile.sections import DeviceInfo
from accellog.cli import main
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0
from accellog.flows.simulate import Scenario, simulate
from accellog.present.export_frames import rotation
from accellog.present.exports import export_calibration
from accellog.store.reader import read_session


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A six-position session with a temperature ramp, fitted with model2, model3 and model3+temp_bias."""
    d = tmp_path_factory.mktemp("targets")
    sim = d / "six.mcap"
    sc = Scenario(protocol="six", hold_s=4.0, move_s=1.0, sample_rate_hz=200.0, seed=31)
    sc.temperature = {"kind": "ramp", "T0": 20.0, "rate_degC_per_s": 0.3}
    simulate(sc, sim)
    cals = {}
    for model in ("model2", "model3", "model3+temp_bias"):
        cals[model] = d / f"{model}.json"
        assert main(["fit", str(sim), "-m", model, "-o", str(cals[model])]) == 0
    return read_session(sim), cals


def _parm(text: str) -> dict[str, float]:
    """ArduPilot NAME,VALUE lines (comments skipped)."""
    rows = [ln.split(",") for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    return {k: float(v) for k, v in rows}


def _px4(text: str) -> dict[str, float]:
    """QGroundControl .params rows: vehicle, component, name, value, type."""
    rows = [ln.split("\t") for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    return {r[2]: float(r[3]) for r in rows}


def _stated_mps2(text: str, what: str) -> float:
    line = next(ln for ln in text.splitlines() if ln.startswith("# cannot hold:") and what in ln)
    return float(line.split("up to ")[1].split(" m/s^2")[0])


def test_imu_calib_holds_the_linear_model(fitted, tmp_path, capsys):
    s, cals = fitted
    out = tmp_path / "imu_calib.yaml"
    rc, _, err = _run(["export", cals["model3"], "--to", "ros", "-o", out], capsys)
    assert rc == 0, err
    y = YAML(typ="safe").load(out.read_text())
    assert set(y) == {"SM", "bias"} and len(y["SM"]) == 9 and len(y["bias"]) == 3  # loadCalib's asserts
    SM, bias = np.reshape(y["SM"], (3, 3)), np.array(y["bias"])
    corrected = (s.accel_g * G0) @ SM.T - bias  # applyCalib: SM * raw - bias, raw in m/s^2
    cal = load_calibration(cals["model3"])
    assert np.max(np.abs(corrected - cal.correct_mps2(s))) < 1e-6
    text = out.read_text()
    assert "SM * raw - bias" in text and "gyro bias" in text
    if cal.gyro is not None and not np.allclose(cal.gyro.matrix, np.eye(3)):
        pct = 100 * np.linalg.norm(np.asarray(cal.gyro.matrix) - np.eye(3), 2)
        assert f"up to {pct:.3g} % rate error" in text


def test_imu_calib_states_the_temperature_loss(fitted, tmp_path, capsys):
    s, cals = fitted
    cal = load_calibration(cals["model3+temp_bias"])
    ex = export_calibration(cal, "ros")
    bound = _stated_mps2(ex.text, "non-linear model terms")
    SM, bias = np.reshape(ex.values["SM"], (3, 3)), np.array(ex.values["bias"])
    err = np.max(np.abs((s.accel_g * G0) @ SM.T - bias - cal.correct_mps2(s)))
    assert 0 < err <= 1.05 * bound  # the session stays inside the calibration's temperature range


@pytest.mark.parametrize("target", ["ardupilot", "px4"])
@pytest.mark.parametrize("rot", ["ROTATION_NONE", "ROTATION_YAW_90", "ROTATION_ROLL_180_YAW_270"])
def test_autopilot_rotated_offsets_reproduce_apply(fitted, tmp_path, capsys, target, rot):
    s, cals = fitted
    out = tmp_path / f"cal.{target}"
    rc, _, err = _run(["export", cals["model2"], "--to", target, "--rotation", rot, "-o", out], capsys)
    assert rc == 0, err
    text = out.read_text()
    assert f"rotated by {rot}" in text
    p = _parm(text) if target == "ardupilot" else _px4(text)
    off, scl = (("INS_ACCOFFS_{}", "INS_ACCSCAL_{}") if target == "ardupilot"
                else ("CAL_ACC0_{}OFF", "CAL_ACC0_{}SCALE"))  # fmt: skip
    o = np.array([p[off.format(a)] for a in "XYZ"])
    k = np.array([p[scl.format(a)] for a in "XYZ"])
    R = rotation(rot)[2]
    corrected = ((s.accel_g * G0) @ R.T - o) * k  # the driver's rotation, then (accel - offset) .* scale
    ref = load_calibration(cals["model2"]).correct_mps2(s) @ R.T
    assert np.max(np.abs(corrected - ref)) < 1e-6


def test_autopilot_off_diagonal_loss_is_stated_and_covers_the_error(fitted, tmp_path, capsys):
    s, cals = fitted
    cal = load_calibration(cals["model3"])
    for rot in ("ROTATION_NONE", "ROTATION_YAW_45"):
        ex = export_calibration(cal, "ardupilot", rotation=rot)
        bound = _stated_mps2(ex.text, "off-diagonal")
        R = rotation(rot)[2]
        o = np.array([ex.values[f"INS_ACCOFFS_{a}"] for a in "XYZ"])
        k = np.array([ex.values[f"INS_ACCSCAL_{a}"] for a in "XYZ"])
        err = np.max(np.linalg.norm(((s.accel_g * G0) @ R.T - o) * k - cal.correct_mps2(s) @ R.T, axis=1))
        assert 0 < err <= 1.02 * bound  # the bound is the largest over all directions at 1 g


def test_sensor_ids(fitted, tmp_path, capsys):
    _, cals = fitted
    cal = load_calibration(cals["model2"])
    ex = export_calibration(cal, "ardupilot")  # the emulator's bus has no number
    assert "INS_ACC_ID" not in ex.values and "INS_ACC_ID not written" in ex.text and "--device-id" in ex.text
    dev = DeviceInfo.from_dict({"who_am_i": 0x71, "i2c_bus": "/dev/i2c-1", "i2c_address": 0x68})
    on_pi = dataclasses.replace(cal, device=dev)
    ap, px = export_calibration(on_pi, "ardupilot"), export_calibration(on_pi, "px4")
    # bus type I2C (1), bus 1 (<< 3), address 0x68 (<< 8), devtype (<< 16)
    assert ap.values["INS_ACC_ID"] == 1 | 1 << 3 | 0x68 << 8 | 0x16 << 16
    assert px.values["CAL_ACC0_ID"] == 1 | 1 << 3 | 0x68 << 8 | 0x24 << 16
    assert "\tCAL_ACC0_ID\t" in px.text and "INS_ACC_ID," in ap.text
    if cal.gyro is not None:
        assert ap.values["INS_GYR_ID"] == 1 | 1 << 3 | 0x68 << 8 | 0x24 << 16
    given = export_calibration(cal, "px4", device_id=2621474)
    assert given.values["CAL_ACC0_ID"] == 2621474 and "given with --device-id" in given.text
    rc, _, err = _run(["export", cals["model2"], "--to", "px4", "--rotation", "ROTATION_YAW_17"], capsys)
    assert rc != 0 and "--rotation ROTATION_YAW_17" in err and len(err.strip().splitlines()) == 1


def test_every_export_states_what_it_cannot_hold(fitted, capsys):
    _, cals = fitted
    for target in ("ros", "px4", "ardupilot", "yaml"):
        rc, out, err = _run(["export", cals["model3+temp_bias"], "--to", target, "--json"], capsys)
        assert rc == 0, err
        d = json.loads(out)
        if target == "ros":
            assert any("temp_bias" in x and "up to" in x for x in d["cannot_hold"]), target
        if target in ("px4", "ardupilot"):  # held: TC_A0_*, INS_TCAL1_* (test_thermal_exports.py)
            assert not any("temp_bias" in x for x in d["cannot_hold"]), target
            assert {"px4": "TC_A0_X1_0", "ardupilot": "INS_TCAL1_ACC1_X"}[target] in d["values"]
        rc, out, _ = _run(["export", cals["model3+temp_bias"], "--to", target], capsys)
        assert "# cannot hold:" in out
