"""ROS 2 flows that finish: a hand-held bag (topic /imu, frame 'imu', its temperature on
/imu/temperature) -> `import ros2 --detect-holds` -> `fit` (orientation-free, said in a note) ->
`apply --ros2`, which keeps the topic, frame, stamps and temperature; read back with an independent
decoder (mcap + mcap-ros2-support)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.ros2_bags import START_NS, decode, handheld_session, session_to_bag

from accellog.calibrate.calfile.calibration import load_calibration
from accellog.cli import main
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session


def _run(argv, capsys):
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.fixture(scope="module")
def handheld_bag(tmp_path_factory):
    d = tmp_path_factory.mktemp("rt")
    s = handheld_session(d / "sim.mcap")
    bag = session_to_bag(s, d / "hand.mcap", topic="/imu", temp_topic="/imu/temperature", frame_id="imu")
    return s, bag


def _vec(msgs, field):
    return np.array([[getattr(m, field).x, getattr(m, field).y, getattr(m, field).z] for m in msgs])


@pytest.mark.slow
def test_handheld_bag_import_fit_apply_keeps_topic_frame_stamps_temperature(handheld_bag, tmp_path, capsys):
    ref, bag = handheld_bag
    ses, cal, cop, back = (tmp_path / n for n in ("s.mcap", "cal.json", "copy.mcap", "back.mcap"))
    rc, out, err = _run(
        ["import", "ros2", bag, "--topic", "/imu", "--detect-holds", "-o", ses, "--json"], capsys
    )
    assert rc == 0, err
    facts = json.loads(out)
    assert facts["poses"] == []  # held 12 deg off the faces: no labels fit would refuse
    s = read_session(ses)
    assert "not a table protocol" in s.meta.extra["poses"]
    assert s.meta.extra["ros2_temperature_topic"] == "/imu/temperature"  # found without a flag
    assert np.array_equal(s.temp_degC[::10], ref.temp_degC[::10])  # the bag's 1-in-10 messages, exact
    assert np.all(np.abs(s.temp_degC - ref.temp_degC) < 0.1)  # between them, interpolated
    rc, out, err = _run(["fit", ses, "-o", cal, "--json"], capsys)
    assert rc == 0, err
    assert "no pose labels: fitted orientation-free" in err and "misalignment_tri" in err
    assert json.loads(out)["rms_g"] < 5e-3
    rc, _, err = _run(["apply", ses, "--cal", cal, "-o", cop, "--ros2", back], capsys)
    assert rc == 0, err
    msgs = decode(back)
    assert set(msgs) == {"/imu", "/imu/temperature"}
    imu = msgs["/imu"]
    assert {m.header.frame_id for m in imu} == {"imu"}
    stamp = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in imu])
    assert np.array_equal(stamp, START_NS + np.round(ref.t_s * 1e9).astype(np.int64))  # to the ns
    assert np.array_equal(_vec(imu, "linear_acceleration"), load_calibration(cal).correct_mps2(s))
    temp = msgs["/imu/temperature"]
    t_stamp = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in temp])
    t_val = np.array([m.temperature for m in temp])
    assert len(temp) > 100 and {m.header.frame_id for m in temp} == {"imu"}
    k = np.searchsorted(stamp, t_stamp)
    assert np.array_equal(stamp[k], t_stamp) and np.array_equal(t_val, s.temp_degC[k])  # the session's values


def test_apply_topic_and_frame_override(handheld_bag, tmp_path, capsys):
    ref, bag = handheld_bag
    ses, cal = tmp_path / "s.mcap", tmp_path / "cal.json"
    assert _run(["import", "ros2", bag, "-o", ses], capsys)[0] == 0
    assert _run(["fit", ses, "-o", cal], capsys)[0] == 0
    back = tmp_path / "b.mcap"
    argv = ["apply", ses, "--cal", cal, "-o", tmp_path / "c.mcap", "--ros2", back]
    rc, _, err = _run([*argv, "--topic", "/robot/imu/data", "--frame-id", "base_imu"], capsys)
    assert rc == 0, err
    msgs = decode(back)
    assert set(msgs) == {"/robot/imu/data", "/robot/imu/temperature"}
    assert {m.header.frame_id for m in msgs["/robot/imu/data"]} == {"base_imu"}
    assert len(msgs["/robot/imu/data"]) == ref.n


def test_table_bag_detect_holds_labels_fit_accepts(tmp_path, capsys):
    """A six-position table session (faces within a few degrees) gets face labels that fit takes."""
    sim = tmp_path / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=200.0, seed=8,
                      fixture_tilt_deg=(3.0, 2.0)), sim)  # fmt: skip
    bag = session_to_bag(read_session(sim), tmp_path / "six_bag.mcap", topic="/imu/data_raw")
    ses, cal = tmp_path / "s.mcap", tmp_path / "cal.json"
    assert _run(["import", "ros2", bag, "--detect-holds", "-o", ses], capsys)[0] == 0
    assert sorted(p.name for p in read_session(ses).poses) == ["+x", "+y", "+z", "-x", "-y", "-z"]
    rc, out, err = _run(["fit", ses, "-o", cal, "--json"], capsys)
    assert rc == 0, err
    assert "orientation-free" not in err and json.loads(out)["n_poses"] == 6


def test_temperature_topic_found_by_namespace(tmp_path):
    """Two Temperature topics: the one in the IMU topic's namespace is taken; none when ambiguous."""
    from accellog.store.importers.ros2 import import_ros2
    from accellog.store.ros2_writer import Ros2BagWriter

    n = 50
    stamp = START_NS + np.arange(n) * 10_000_000
    bag = tmp_path / "two_temps.mcap"
    with Ros2BagWriter(bag) as w:
        w.write_imu(stamp, np.tile([0, 0, 9.8], (n, 1)), np.zeros((n, 3)), np.zeros(9), np.zeros(9),
                    topic="/cam/imu")  # fmt: skip
        w.write_temperature(stamp, np.full(n, 31.0), topic="/cam/temperature")
        w.write_temperature(stamp, np.full(n, 55.0), topic="/cpu/temperature")
    s = import_ros2(bag)
    assert s.meta.extra["ros2_temperature_topic"] == "/cam/temperature" and np.all(s.temp_degC == 31.0)
    s = import_ros2(bag, temperature_topic="/cpu/temperature")
    assert np.all(s.temp_degC == 55.0)


@pytest.mark.parametrize("frame", ["imu_link", "imu", "a", "", "base_imu_frame_long"])
def test_imu_cdr_is_rosbags_serialization_byte_for_byte(frame):
    """The numpy CDR encoder writes exactly what rosbags' serialize_cdr writes (every alignment case)."""
    from rosbags.typesys import Stores, get_typestore

    from accellog.store.ros2_writer import _NO_ORIENTATION, imu_cdr

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    rng = np.random.default_rng(3)
    n = 20
    stamp = START_NS + np.arange(n, dtype=np.int64) * 4_999_999 - 1_800_000_000 * 10**9 * (np.arange(n) % 2)
    acc, gyr, ca, cg = (rng.normal(size=(n, k)) for k in (3, 3, 9, 9))
    rows = imu_cdr(stamp, frame, acc, gyr, ca, cg)
    for i in range(n):
        st = int(stamp[i])
        m = T["sensor_msgs/msg/Imu"](
            header=T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=st // 10**9, nanosec=st % 10**9), frame_id=frame
            ),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=_NO_ORIENTATION,
            angular_velocity=T["geometry_msgs/msg/Vector3"](x=gyr[i, 0], y=gyr[i, 1], z=gyr[i, 2]),
            angular_velocity_covariance=cg[i].copy(),
            linear_acceleration=T["geometry_msgs/msg/Vector3"](x=acc[i, 0], y=acc[i, 1], z=acc[i, 2]),
            linear_acceleration_covariance=ca[i].copy(),
        )
        assert rows[i].tobytes() == bytes(ts.serialize_cdr(m, "sensor_msgs/msg/Imu"))
