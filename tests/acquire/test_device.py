"""Device identity (issue 15 item 1): the DeviceKey travels with sessions (MCAP metadata) and
calibrations (JSON), old files without it still read, and `apply` refuses a calibration of another
device unless told to warn."""

from __future__ import annotations

import json

import pytest

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.core.device import DeviceKey, check_serial
from accellog.core.errors import InputError
from accellog.flows.apply import OtherDeviceWarning, run_apply
from accellog.flows.simulate import Scenario, simulate
from accellog.flows.stages import run_fit
from accellog.store.layout import meta_to_metadata, metadata_to_meta
from accellog.store.reader import read_session

SHORT = dict(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0)


@pytest.fixture(scope="module")
def two_devices(tmp_path_factory):
    d = tmp_path_factory.mktemp("dev")
    simulate(Scenario(**SHORT, chip_seed=1, seed=1), d / "a.mcap", serial="IMU-A")
    simulate(Scenario(**SHORT, chip_seed=2, seed=2), d / "b.mcap", serial="IMU-B")
    simulate(Scenario(**SHORT, chip_seed=1, seed=3), d / "a2.mcap", serial="IMU-A")
    cal = run_fit(d / "a.mcap", "model3").cal
    cal.save(d / "cal_a.json")
    return d


def test_key_conflicts_and_unknowns():
    a = DeviceKey(who_am_i=0x71, serial="IMU-1", i2c_bus="/dev/i2c-1", i2c_address=0x68, host="pi")
    assert a.id == "IMU-1" and a.known
    assert a.conflicts(DeviceKey(who_am_i=0x71, serial="IMU-2")) == ["serial IMU-1 != IMU-2"]
    assert a.conflicts(DeviceKey(who_am_i=0x73, serial="IMU-1")) == ["who_am_i 0x71 != 0x73"]
    # a named sensor may move to another computer; unknown facts never conflict
    assert a.conflicts(DeviceKey(serial="IMU-1", host="other", i2c_address=0x69)) == []
    assert a.conflicts(DeviceKey()) == []
    # without serials the location identifies the unit
    b = DeviceKey(who_am_i=0x71, i2c_bus="/dev/i2c-1", i2c_address=0x68, host="pi")
    assert b.id == "pi//dev/i2c-1/0x68"
    assert b.conflicts(DeviceKey(who_am_i=0x71, i2c_bus="/dev/i2c-1", i2c_address=0x69, host="pi")) == [
        "i2c_address 0x68 != 0x69"
    ]
    assert DeviceKey.from_dict(a.to_dict()) == a and DeviceKey.from_dict(None) == DeviceKey()
    with pytest.raises(InputError, match="serial"):
        check_serial("bad/name")


def test_session_and_calibration_carry_the_key(two_devices):
    s = read_session(two_devices / "a.mcap")
    k = s.meta.device
    assert (k.serial, k.who_am_i, k.i2c_bus, k.i2c_address) == ("IMU-A", 0x71, "emulator", 0x68)
    assert k.host  # the recording computer
    cal = load_calibration(two_devices / "cal_a.json")
    assert cal.device.key == k and cal.device.id == "IMU-A"
    # files written before device keys existed: metadata without the fields -> unknown key
    md = {
        k2: v
        for k2, v in meta_to_metadata(s.meta).items()
        if k2 not in ("serial", "i2c_bus", "i2c_address", "ak8963_wia")
    }
    old = metadata_to_meta(md)
    assert old.serial == "" and old.i2c_address is None and old.device.conflicts(k) == []
    d = json.loads((two_devices / "cal_a.json").read_text())
    del d["device"]
    (two_devices / "old_cal.json").write_text(json.dumps(d))
    old_cal = load_calibration(two_devices / "old_cal.json")
    assert old_cal.device.key == DeviceKey() and old_cal.device.to_dict() == {}


def test_apply_refuses_another_device(two_devices, tmp_path, capsys):
    cal = two_devices / "cal_a.json"
    run_apply(two_devices / "a2.mcap", cal, tmp_path / "ok.mcap")  # same device, later session
    assert (tmp_path / "ok.mcap").exists()
    with pytest.raises(InputError, match="calibration is for device IMU-A, session is from IMU-B"):
        run_apply(two_devices / "b.mcap", cal, tmp_path / "no.mcap")
    assert not list(tmp_path.glob("*no.mcap*"))  # nothing half-written
    with pytest.warns(OtherDeviceWarning, match="serial IMU-A != IMU-B"):
        run_apply(two_devices / "b.mcap", cal, tmp_path / "warned.mcap", other_device="warn")
    # a calibration without a device key (older file) applies anywhere
    d = json.loads(cal.read_text())
    del d["device"]
    (tmp_path / "old_cal.json").write_text(json.dumps(d))
    run_apply(two_devices / "b.mcap", tmp_path / "old_cal.json", tmp_path / "old.mcap")
    assert (tmp_path / "old.mcap").exists()
    # CLI: one line, non-zero; --other-device warn prints a warning and writes
    rc = main(["apply", str(two_devices / "b.mcap"), "--cal", str(cal), "-o", str(tmp_path / "c.mcap")])
    err = capsys.readouterr().err
    assert (
        rc != 0
        and err.startswith("accellog: error: ")
        and err.count("\n") == 1
        and "--other-device warn" in err
    )
    rc = main(
        [
            "apply",
            str(two_devices / "b.mcap"),
            "--cal",
            str(cal),
            "-o",
            str(tmp_path / "c.mcap"),
            "--other-device",
            "warn",
        ]
    )
    printed = capsys.readouterr()
    assert rc == 0 and "warning: calibration is for device IMU-A" in " ".join(
        (printed.out + printed.err).split()
    )
    assert read_session(tmp_path / "c.mcap").meta.serial == "IMU-B"  # the session keeps its own key


def test_report_shows_the_device(two_devices, capsys):
    assert main(["report", str(two_devices / "cal_a.json")]) == 0
    out = capsys.readouterr()
    assert "device IMU-A (WHO_AM_I 0x71" in out.out + out.err


def test_record_serial_option(tmp_path):
    out = tmp_path / "r.mcap"
    rc = main(
        [
            "record",
            "--sim",
            "--fast",
            "--hold",
            "1",
            "--rate",
            "100",
            "--serial",
            "BENCH-7",
            "-o",
            str(out),
            "--wait",
            "auto",
        ]
    )
    assert rc == 0
    k = read_session(out).meta.device
    assert k.serial == "BENCH-7" and k.ak8963_wia == 0x48 and k.i2c_address == 0x68
