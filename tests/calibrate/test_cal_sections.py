"""Typed calibration sections (temperature, fit, sensor, gyro): the JSON file format is unchanged.

tests/data/calibration_v1/ holds calibration files written by main before the sections were typed
(commit d593e79; how in its README.md): each must load into the typed form and be written back byte
for byte; files of older versions (keys missing, other key order, ints, unknown keys) too.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.calibrate.calfile.noise_section import NoiseSection
from accellog.calibrate.calfile.sections import (
    DetectedInterval,
    DeviceInfo,
    FitInfo,
    SensorInfo,
    SourceFile,
    TemperatureInfo,
)
from accellog.calibrate.gyro.model import GyroCalibration
from accellog.calibrate.mag.magnetometer import MagCalibration
from accellog.cli import main
from accellog.core.device import DeviceKey
from accellog.core.errors import InputError
from accellog.core.jsonio import dumps
from accellog.flows.simulate import Scenario, simulate

FIXTURES = Path(__file__).resolve().parents[1] / "data" / "calibration_v1"
FILES = sorted(FIXTURES.glob("*.json"))


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_main_written_files_round_trip_byte_identical(path, tmp_path):
    cal = load_calibration(path)
    assert isinstance(cal.temperature, TemperatureInfo) and isinstance(cal.fit, FitInfo)
    assert isinstance(cal.sensor, SensorInfo) and (cal.gyro is None or isinstance(cal.gyro, GyroCalibration))
    assert dumps(cal.to_dict()) + "\n" == path.read_text()
    cal.save(tmp_path / "again.json")
    assert (tmp_path / "again.json").read_bytes() == path.read_bytes()


def test_sections_read_as_attributes():
    lab = load_calibration(FIXTURES / "labelled_noise.json")
    raw = json.loads((FIXTURES / "labelled_noise.json").read_text())
    f = lab.fit
    assert (f.method, f.weighted, f.uncertainty) == ("labelled", True, "between_hold")
    assert f.chi2_dof == raw["fit"]["chi2_dof"] and f.dof == 6 and f.n_obs == 6
    assert f.between_hold_g == tuple(raw["fit"]["between_hold_g"]) and len(f.sigma_scaled) == 12
    assert f.warnings[0].startswith("residuals are") and f.detected_intervals is None
    t = lab.temperature
    assert t.t_ref_degC == 25.0 and t.range_degC == (
        raw["temperature"]["min_degC"],
        raw["temperature"]["max_degC"],
    )
    assert lab.sensor == SensorInfo(chip="emulated MPU-9250", accel_range_g=2.0, accel_lsb_per_g=16384.0)
    assert lab.device.id == "vm/emulator/0x68" and lab.device.key == DeviceKey(
        who_am_i=0x71, i2c_bus="emulator", i2c_address=0x68, host="vm"
    )
    src = lab.sources[0]
    assert isinstance(src, SourceFile) and (src.path, src.kind) == ("six.mcap", "emulator")
    assert src.sha256 == raw["sources"][0]["sha256"] and src.recovered is None
    n = lab.noise
    assert isinstance(n, NoiseSection) and n.version == 1 and n.rate_hz == raw["noise"]["rate_hz"]
    assert n.gyro.units["white"] == "rad/s/sqrt(Hz)" and n.kalibr == raw["noise"]["kalibr"]
    white = [raw["noise"]["accel"]["axes"][a]["white"]["value"] for a in "xyz"]
    np.testing.assert_array_equal(n.white_noise("accel"), white)
    assert 1e-3 < white[0] < 1e-2  # m/s^2/sqrt(Hz): the emulated MPU-9250's white noise
    g = lab.gyro
    assert g.effects == ["bias", "temp_bias", "scale", "cross_axis"] and g.n_holds == 6
    np.testing.assert_array_equal(g.matrix, raw["gyro"]["matrix"])
    hand = load_calibration(FIXTURES / "handheld.json")
    iv = hand.fit.detected_intervals
    assert len(iv) == 18 and all(isinstance(x, DetectedInterval) and x.n > 400 for x in iv)
    assert iv[0].up_sensor == tuple(
        json.loads((FIXTURES / "handheld.json").read_text())["fit"]["detected_intervals"][0]["up_sensor"]
    )
    assert hand.temperature.range_degC is not None and np.isnan(hand.gyro.temp_bias_sigma_dps_per_degC).all()
    table = load_calibration(FIXTURES / "posetable_mag.json")
    assert table.sensor == SensorInfo.empty() and table.sensor.to_dict() == {} and table.gyro is None
    mag = table.magnetometer
    assert (
        isinstance(mag, MagCalibration)
        and mag.form == "sym"
        and [t.driver for t in mag.trends] == ["time", "temperature", "rotation rate"]
    )
    raw_mag = json.loads((FIXTURES / "posetable_mag.json").read_text())["magnetometer"]
    assert json.loads(dumps(mag.to_dict())) == raw_mag


def _older(tmp_path) -> tuple[Path, dict]:
    """A file as an older version (or a later one) might have written it: fit without the uncertainty
    keys (before `fit --uncertainty`), no sensor/device facts, keys reordered, an int where this
    version writes a float, keys this version does not know in every section."""
    d = json.loads((FIXTURES / "handheld.json").read_text())
    for k in ("uncertainty", "between_hold_g"):
        del d["fit"][k]
    d["fit"] = {"lab_note": {"by": "rig 3"}, **dict(reversed(list(d["fit"].items())))}
    d["fit"]["detected_intervals"][0]["quality"] = 0.93
    d["temperature"] = {"max_degC": 26, "t_ref_degC": 25, "chamber": "off"}
    d["sensor"] = {"board": "GY-9250"}
    d["device"] = {}
    d["sources"][0]["note"] = "copied from the lab share"
    d["gyro"] = {"firmware": "1.2", **d["gyro"], "t_ref_degC": 25}
    p = tmp_path / "older.json"
    p.write_text(dumps(d) + "\n")
    return p, d


def test_older_files_and_unknown_keys_round_trip(tmp_path):
    p, _ = _older(tmp_path)
    cal = load_calibration(p)
    assert cal.fit.uncertainty is None and cal.fit.between_hold_g is None
    assert cal.fit.extra == {"lab_note": {"by": "rig 3"}} and cal.fit.detected_intervals[0].extra == {
        "quality": 0.93
    }
    assert cal.temperature.t_ref_degC == 25 and cal.temperature.mean_degC is None
    assert cal.temperature.extra == {"chamber": "off"} and cal.sensor.chip is None
    assert cal.sensor.extra == {"board": "GY-9250"} and cal.gyro.t_ref_degC == 25.0
    assert cal.device == DeviceInfo.empty() and cal.device.key == DeviceKey()
    assert cal.sources[0].extra == {"note": "copied from the lab share"}
    cal.save(tmp_path / "again.json")
    assert (tmp_path / "again.json").read_text() == p.read_text()


def test_changed_sections_keep_unknown_keys(tmp_path):
    p, d = _older(tmp_path)
    cal = load_calibration(p)
    cal.fit = dataclasses.replace(cal.fit, uncertainty="jackknife", detected_intervals=None)
    cal.temperature = dataclasses.replace(cal.temperature, mean_degC=25.5)
    cal.gyro = dataclasses.replace(cal.gyro, n_holds=17)
    out = cal.to_dict()
    assert list(out["fit"])[:3] == ["lab_note", "detected_intervals", "sigma_scaled"]
    assert out["fit"]["detected_intervals"] is None  # a key read is written (null when cleared)
    assert out["fit"]["uncertainty"] == "jackknife" and "between_hold_g" not in out["fit"]
    assert out["temperature"] == {"max_degC": 26, "t_ref_degC": 25, "chamber": "off", "mean_degC": 25.5}
    assert out["gyro"]["n_holds"] == 17 and out["gyro"]["firmware"] == "1.2"
    assert out["gyro"]["bias_dps"] == d["gyro"]["bias_dps"] and out["sensor"] == {"board": "GY-9250"}


def test_noise_command_keeps_the_other_sections(tmp_path):
    """`accellog noise --cal OLD --out NEW` re-saves a calibration: every section but noise unchanged."""
    p, d = _older(tmp_path)
    sim = tmp_path / "still.mcap"
    simulate(Scenario(protocol="+z", hold_s=20.0, move_s=1.0, sample_rate_hz=200.0, seed=2), sim)
    out = tmp_path / "with_noise.json"
    assert main(["noise", str(sim), "--cal", str(p), "--out", str(out), "--json"]) in (0, None)
    new = json.loads(out.read_text())
    assert new.pop("noise")["version"] == 1
    assert new == d


@pytest.mark.parametrize(
    ("section", "key", "value", "message"),
    [
        ("fit", "chi2_dof", "small", r"fit.chi2_dof = 'small' is not a number"),
        ("fit", "dof", 6.5, r"fit.dof = '6.5' is not an integer"),
        ("fit", "warnings", "one", r"fit.warnings = 'one' is not a list of strings"),
        ("temperature", "t_ref_degC", [25], r"temperature.t_ref_degC = '\[25\]'"),
        ("sensor", "chip", 9250, r"sensor.chip = '9250' is not a string"),
        ("device", "i2c_address", "0x68", r"device.i2c_address = '0x68' is not an integer"),
        ("gyro", "bias_dps", [1.0, 2.0], r"gyro calibration 'bias_dps' has shape \(2,\)"),
        (
            "noise",
            "kalibr",
            {"accelerometer_noise_density": "low"},
            r"noise.kalibr = .* is not an object of numbers",
        ),
        ("noise", "version", 2, r"calibration 'noise' section version 2 is newer than this accellog"),
    ],
)
def test_malformed_section_is_one_line_naming_the_file(tmp_path, section, key, value, message):
    d = json.loads((FIXTURES / "labelled_noise.json").read_text())
    d[section][key] = value
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=rf"bad.json: (calibration field )?{message}"):
        load_calibration(p)


def test_fresh_fit_writes_the_keys_main_wrote(tmp_path):
    """A calibration made now has the sections (keys, order, JSON types) of the one main wrote."""
    sim = tmp_path / "six.mcap"
    # 2 s moves: 180 deg in 1 s would clip the gyro (337 deg/s at 250 full scale), leaving those moves out
    sc = Scenario(protocol="six", hold_s=3.0, move_s=2.0, sample_rate_hz=200.0, seed=7)
    sc.temperature = {"kind": "ramp", "T0": 20.0, "rate_degC_per_s": 0.2}
    simulate(sc, sim)
    new = tmp_path / "cal.json"
    assert main(["fit", str(sim), "--model", "model3", "--uncertainty", "between_hold", "-o", str(new)]) in (
        0,
        None,
    )
    ref = json.loads((FIXTURES / "labelled_noise.json").read_text())
    got = json.loads(new.read_text())

    def shape(x):
        if isinstance(x, dict):
            return {k: shape(v) for k, v in x.items()}
        if isinstance(x, list):
            return [shape(v) for v in x[:1]]
        return type(x).__name__

    def same(a, b) -> bool:  # an empty list matches any list (a fit may have no warnings)
        if isinstance(a, list) and isinstance(b, list):
            return not a or not b or same(a[0], b[0])
        if isinstance(a, dict) and isinstance(b, dict):
            return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
        return a == b

    for sec in ("temperature", "fit", "sensor", "device", "gyro"):
        assert list(got[sec]) == list(ref[sec]) and same(shape(got[sec]), shape(ref[sec])), sec
    assert list(got) == [k for k in ref if k != "noise"]
