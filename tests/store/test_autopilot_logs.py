"""`accellog import ulog|dataflash`: real logs from pyulog's and pymavlink's test folders
(tests/data/autopilot_logs/README.md) import with temperature, device id and the formats' units;
foreign files, a missing --imu and a log without temperature say so in one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from accellog.cli import main
from accellog.core import notices
from accellog.core.errors import InputError
from accellog.store.importers import import_file
from accellog.store.importers.autopilot_log import log_session
from accellog.store.importers.csv_checks import UnitsError
from accellog.store.reader import read_session

DATA = Path(__file__).parents[1] / "data" / "autopilot_logs"
ULG = DATA / "px4_sample_log_small_head.ulg"
BIN = DATA / "ardupilot_pymavlink_test.BIN"


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize(
    ("imu", "device_id", "temp_degC"), [(0, 2424842, 40.0), (1, 3670050, 28.3), (2, 2621474, 29.6)]
)
def test_ulog_instances_import_with_temperature_and_device_id(imu, device_id, temp_degC):
    s = import_file("ulog", ULG, imu=imu)
    assert s.meta.source == "import:ulog" and s.n == 3
    assert s.meta.extra["accel_device_id"] == str(device_id) == s.meta.extra["gyro_device_id"]
    assert s.meta.serial == f"ulog-device-{device_id}"
    assert abs(np.mean(s.temp_degC) - temp_degC) < 0.5
    assert np.allclose(np.linalg.norm(s.accel_g, axis=1), 1.0, atol=0.05)  # at rest: 1 g after / g0
    assert np.all(np.abs(s.gyro_dps) < 5.0)  # rad/s -> deg/s of a board at rest
    assert abs(s.meta.sample_rate_hz - 1.0) < 0.01


@pytest.mark.parametrize(("imu", "acc_id", "temp_degC"), [(0, 1246730, 44.4), (1, 1442826, 39.9)])
def test_dataflash_instances_import_with_temperature_and_device_id(imu, acc_id, temp_degC):
    s = import_file("dataflash", BIN, imu=imu)
    assert s.meta.source == "import:dataflash" and s.n == 45
    assert s.meta.extra["accel_device_id"] == str(acc_id)
    assert abs(np.mean(s.temp_degC) - temp_degC) < 0.2
    assert abs(float(np.median(np.linalg.norm(s.accel_g, axis=1))) - 1.0) < 0.05
    assert abs(s.meta.sample_rate_hz - 50.0) < 1.0


def test_cli_writes_a_session_that_reads_back(tmp_path, capsys):
    for kind, src in (("ulog", ULG), ("dataflash", BIN)):
        out = tmp_path / f"{kind}.mcap"
        rc, stdout, err = _run(["import", kind, src, "--imu", "1", "-o", out, "--json"], capsys)
        assert rc == 0, err
        facts = json.loads(stdout)
        assert facts["temperature"] is True and facts["source"] == f"import:{kind}"
        back = read_session(out)
        want = import_file(kind, src, imu=1)
        assert np.allclose(back.accel_g, want.accel_g, atol=1e-6) and np.allclose(
            back.temp_degC, want.temp_degC
        )


def test_missing_instance_and_foreign_files_are_one_line(tmp_path, capsys):
    for argv, says in (
        (["import", "ulog", ULG, "--imu", "3"], "sensor_accel instances [0, 1, 2]"),
        (["import", "dataflash", BIN, "--imu", "2"], "IMU instances [0, 1]"),
        (["import", "dataflash", ULG], "not a DataFlash log"),
        (["import", "ulog", BIN], "not a readable ULog file"),
    ):
        rc, out, err = _run([*argv, "-o", tmp_path / "x.mcap"], capsys)
        assert rc == 2 and says in err and len(err.strip().splitlines()) == 1, err
        assert out == ""


def test_a_log_without_temperature_says_so_in_one_line(tmp_path):
    notices.take()
    t_us = np.arange(0, 2_000_000, 10_000)
    acc = np.tile([0.0, 0.0, 9.80665], (t_us.size, 1))
    s = log_session(tmp_path / "a.ulg", "ulog", t_us, acc, np.zeros_like(acc), np.full(t_us.size, np.nan),
                    accel_id=1, gyro_id=1, extra={"imu": "sensor_accel 0"})  # fmt: skip
    assert s.temp_degC is None
    said = notices.take()
    assert len(said) == 1 and "no IMU temperature" in said[0]


def test_units_are_checked_at_the_door(tmp_path):
    """Values in g where the format states m/s^2 are refused, naming the IMU and what to check."""
    t_us = np.arange(0, 2_000_000, 10_000)
    acc = np.tile([0.0, 0.0, 1.0], (t_us.size, 1))
    with pytest.raises(UnitsError, match=r"sensor_accel 0: .*m/s\^2.*another --imu"):
        log_session(tmp_path / "a.ulg", "ulog", t_us, acc, None, None, accel_id=None, gyro_id=None,
                    extra={"imu": "sensor_accel 0"})  # fmt: skip
    with pytest.raises(InputError, match="need at least two"):
        log_session(tmp_path / "a.ulg", "ulog", t_us[:1], acc[:1], None, None, accel_id=None, gyro_id=None,
                    extra={})  # fmt: skip


def test_every_stage_reads_an_autopilot_log_directly(capsys):
    """A .ulg or .BIN given to a stage is read by its importer (instance 0), as import would."""
    from accellog.store.source import read_whole

    for kind, src in (("ulog", ULG), ("dataflash", BIN)):
        s = read_whole(src)
        want = import_file(kind, src)
        assert s.meta.source == f"import:{kind}" and np.array_equal(s.accel_g, want.accel_g)
        rc, out, err = _run(["doctor", src, "--json"], capsys)
        assert rc == 0, err
        facts = json.loads(out)
        assert facts["source"] == f"import:{kind}" and facts["samples"] == len(want.t_s)
