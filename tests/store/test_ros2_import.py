"""ROS 2 in: rosbag2 MCAP bags built with rosbags' writer from the real imucal recording and from the
emulator, imported with `accellog import ros2`, then fitted and diagnosed."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.ros2_bags import START_NS, decode, session_to_bag

from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.importers import import_imucal
from accellog.store.importers.ros2 import import_ros2
from accellog.store.reader import read_session


def _run(argv, capsys):
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def imucal_bag(tmp_path_factory, shared_data):
    """The real imucal Ferraris recording (102.4 Hz, m/s^2 and deg/s) as a rosbag2 MCAP file."""
    s = import_imucal(shared_data / "imucal" / "example_ferraris_session.csv")
    bag = tmp_path_factory.mktemp("ros2") / "ferraris.mcap"
    session_to_bag(s, bag, log_lag_ns=4_000_000)  # the recorder got each message 4 ms after its stamp
    return s, bag


def test_imucal_bag_imports_with_units_stamps_and_provenance(imucal_bag, tmp_path, capsys):
    ref, bag = imucal_bag
    out = tmp_path / "s.mcap"
    rc, stdout, err = _run(["import", "ros2", str(bag), "-o", str(out), "--json"], capsys)
    assert rc == 0, err
    facts = json.loads(stdout)
    assert facts["samples"] == ref.n and facts["source"] == "import:ros2"
    assert "disagree" in facts["notes"]["stamp_warning"] and "4.000" in facts["notes"]["stamp_warning"]
    s = read_session(out)
    assert np.allclose(s.accel_g, ref.accel_g, rtol=1e-14, atol=1e-15)
    assert np.allclose(s.gyro_dps, ref.gyro_dps, rtol=1e-13, atol=1e-13)
    assert np.allclose(s.t_s, ref.t_s - ref.t_s[0], atol=1e-9)
    assert s.meta.start_time_unix_ns == START_NS + round(ref.t_s[0] * 1e9)
    assert s.meta.sample_rate_hz == pytest.approx(102.4, rel=1e-6)
    assert s.meta.extra["ros2_topic"] == "/imu/data" and s.meta.extra["ros2_frame_id"] == "imu_link"
    assert s.meta.extra["source_file"] == "ferraris.mcap"


def test_imucal_bag_goes_through_fit_and_diagnose(imucal_bag, tmp_path, capsys):
    """A bag has no pose labels: --detect-holds labels the six still faces, then fit, diagnose and apply
    --ros2 run (import, calibrate, export back, read with an independent decoder)."""
    _, bag = imucal_bag
    out, cal = tmp_path / "s.mcap", tmp_path / "cal.json"
    assert _run(["import", "ros2", str(bag), "--detect-holds", "-o", str(out)], capsys)[0] == 0
    s = read_session(out)
    assert sorted({p.name for p in s.poses}) == ["+x", "+y", "+z", "-x", "-y", "-z"]
    assert "detected" in s.meta.extra["poses"]
    rc, stdout, err = _run(["fit", str(out), "-o", str(cal), "--json"], capsys)
    assert rc == 0, err
    fit = json.loads(stdout)
    # imucal's own Ferraris result (README): K_a = diag(0.996746, 1.002438, 1.023395) -> scale ~ K_a - 1
    assert fit["n_poses"] == 6
    rc, stdout, err = _run(["diagnose", str(out), "--json"], capsys)
    assert rc == 0, err
    # ... and back out as ROS 2, read with an independent decoder (mcap + mcap-ros2-support)
    cop, back = tmp_path / "copy.mcap", tmp_path / "calibrated.mcap"
    rc, _, err = _run(["apply", str(out), "--cal", str(cal), "-o", str(cop), "--ros2", str(back)], capsys)
    assert rc == 0, err
    imu = decode(back)["/imu/data"]
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in imu])
    assert acc.shape == (s.n, 3)
    still = np.concatenate(
        [np.arange(*s.slice_time(p.start_s + 0.5, p.end_s - 0.5).indices(s.n)) for p in s.poses]
    )
    # calibrated |a| over the still faces: local gravity within 0.5 % (imucal's own result: 9.8096-9.8106)
    assert np.median(np.linalg.norm(acc[still], axis=1)) == pytest.approx(9.81, rel=5e-3)


_TWELVE = "+x,-x,+y,-y,+z,-z,+x+y,-x+z,+y-z,+x+y+z,-x-y+z,+x-y-z"


def test_handheld_bag_orientation_free(tmp_path, capsys):
    """An emulated 12-orientation session (faces, edges, corners) as a bag, no labels: the orientation-free fit."""
    sim = tmp_path / "sim.mcap"
    simulate(Scenario(protocol=_TWELVE, hold_s=2.5, move_s=1.0, sample_rate_hz=200.0, seed=5), sim)
    bag = session_to_bag(read_session(sim), tmp_path / "hand.mcap")
    out, cal = tmp_path / "s.mcap", tmp_path / "cal.json"
    assert _run(["import", "ros2", str(bag), "-o", str(out)], capsys)[0] == 0
    rc, stdout, err = _run(
        [
            "fit",
            str(out),
            "--orientation-free",
            "-m",
            "bias+scale+misalignment_tri",
            "-o",
            str(cal),
            "--json",
        ],
        capsys,
    )
    assert rc == 0, err
    assert json.loads(stdout)["rms_g"] < 5e-3


def test_topics_listed_and_chosen(tmp_path, capsys):
    sim = tmp_path / "sim.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=3), sim)
    s = read_session(sim)
    bag = tmp_path / "two.mcap"
    session_to_bag(s, bag, temp_topic="/imu/temperature", extra_topics=("/camera/imu",))
    rc, stdout, _ = _run(["import", "ros2", str(bag), "--json"], capsys)
    assert rc == 0
    topics = {t["topic"]: t for t in json.loads(stdout)}
    assert topics["/imu/data"]["count"] == s.n and topics["/camera/imu"]["msgtype"] == "sensor_msgs/msg/Imu"
    out = tmp_path / "o.mcap"
    rc, _, err = _run(["import", "ros2", str(bag), "-o", str(out)], capsys)
    assert rc != 0 and "several IMU topics" in err and "/camera/imu (10 messages)" in err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
    rc, _, err = _run(["import", "ros2", str(bag), "--topic", "/nope", "-o", str(out)], capsys)
    assert rc != 0 and "no such topic" in err
    sess = import_ros2(bag, topic="/imu/data", temperature_topic="/imu/temperature")
    par = import_ros2(bag, topic="/imu/data", temperature_topic="/imu/temperature", jobs=3)  # time ranges
    assert np.array_equal(par.t_s, sess.t_s) and np.array_equal(par.accel_g, sess.accel_g)
    assert np.array_equal(par.gyro_dps, sess.gyro_dps) and par.meta.extra == sess.meta.extra
    assert np.array_equal(sess.temp_degC[::10], s.temp_degC[::10])  # 1-in-10 messages, interpolated between
    assert np.all(np.abs(sess.temp_degC - s.temp_degC) < 0.1)
    assert np.allclose(sess.accel_g, s.accel_g, rtol=1e-14, atol=1e-15)


def test_bag_without_imu_messages_says_so(tmp_path, capsys):
    from accellog.store.ros2_writer import Ros2BagWriter

    bag = tmp_path / "temp_only.mcap"
    with Ros2BagWriter(bag) as w:
        w.write_temperature(START_NS + np.arange(5) * 10**9, np.full(5, 25.0))
    rc, _, err = _run(["import", "ros2", str(bag), "-o", str(tmp_path / "o.mcap")], capsys)
    assert rc != 0 and "no sensor_msgs/msg/Imu messages" in err and "/imu/temperature" in err
    rc, _, err = _run(
        ["import", "ros2", str(tmp_path / "missing.mcap"), "-o", str(tmp_path / "o.mcap")], capsys
    )
    assert rc != 0 and "no such file" in err


def test_every_stage_reads_a_bag_directly(imucal_bag, tmp_path, capsys):
    """Stages take the bag itself (load_input: its only Imu topic): `noise` on the bag equals `noise`
    on the same bag imported with `import ros2`."""
    _, bag = imucal_bag
    rc, out, err = _run(["noise", str(bag), "--json"], capsys)
    assert rc == 0, err
    direct = json.loads(out)
    imported = tmp_path / "s.mcap"
    assert _run(["import", "ros2", str(bag), "-o", str(imported)], capsys)[0] == 0
    rc, out, err = _run(["noise", str(imported), "--json"], capsys)
    assert rc == 0, err
    via_import = json.loads(out)
    assert direct["n_samples"] == via_import["n_samples"] > 1000
    assert direct["accel"] == via_import["accel"]
