"""The vectorised sensor_msgs/msg/Imu CDR decoder against rosbags' own deserialize_cdr."""

from __future__ import annotations

import numpy as np
import pytest
from support.ros2_bags import START_NS

from accellog.store.importers.ros2_cdr import decode_imu
from accellog.store.ros2_writer import imu_cdr


def _rows(frame: str, n: int = 30, seed: int = 4):
    rng = np.random.default_rng(seed)
    stamp = START_NS + np.arange(n, dtype=np.int64) * 4_999_999 - 1_800_000_000 * 10**9 * (np.arange(n) % 2)
    acc, gyr, ca, cg = (rng.normal(size=(n, k)) for k in (3, 3, 9, 9))
    return [bytes(r) for r in imu_cdr(stamp, frame, acc, gyr, ca, cg)]


@pytest.mark.parametrize("frame", ["imu_link", "imu", "a", "", "base_imu_frame_long", "ünï"])
def test_decode_imu_equals_rosbags(frame):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    raws = _rows(frame)
    stamp, acc, gyr, frames, cov_a, cov_g = decode_imu(raws)
    assert frames == {frame}
    for i, raw in enumerate(raws):
        m = ts.deserialize_cdr(raw, "sensor_msgs/msg/Imu")
        assert stamp[i] == m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
        la, av = m.linear_acceleration, m.angular_velocity
        assert acc[i].tolist() == [la.x, la.y, la.z] and gyr[i].tolist() == [av.x, av.y, av.z]
    first = ts.deserialize_cdr(raws[0], "sensor_msgs/msg/Imu")
    assert cov_a.tolist() == first.linear_acceleration_covariance.tolist()
    assert cov_g.tolist() == first.angular_velocity_covariance.tolist()


def test_several_frame_ids_of_one_length_are_all_named():
    raws = _rows("imu_a", 5) + _rows("imu_b", 5)
    assert decode_imu(raws)[3] == {"imu_a", "imu_b"}


def test_blocks_it_cannot_take_are_left_to_rosbags():
    """Mixed lengths, big-endian CDR, a frame_id without its NUL, a short message: None."""
    assert decode_imu(_rows("imu", 3) + _rows("imu_link", 3)) is None
    big = [b"\x00\x00" + r[2:] for r in _rows("imu", 3)]
    assert decode_imu(big) is None
    no_nul = [r[:19] + b"x" + r[20:] for r in _rows("imu", 3)]  # 'imu' + NUL: the NUL at byte 19
    assert decode_imu(no_nul) is None
    assert decode_imu([b"\x00\x01\x00\x00"]) is None and decode_imu([]) is None


def test_bag_with_two_frame_id_lengths_imports_like_rosbags(tmp_path):
    """A bag whose frame_id changes length mid-stream: that block is decoded by rosbags, same arrays."""
    from accellog.store.importers import ros2
    from accellog.store.ros2_writer import Ros2BagWriter

    n = 40
    stamp = START_NS + np.arange(n, dtype=np.int64) * 10_000_000
    acc = np.tile([0.1, 0.2, 9.8], (n, 1)) + np.arange(n)[:, None] * 1e-3
    bag = tmp_path / "frames.mcap"
    with Ros2BagWriter(bag, frame_id="imu") as w:
        w.write_imu(stamp[:20], acc[:20], acc[:20] * 0.01, np.eye(3), np.eye(3) * 1e-3)
        w.frame_id = "imu_long_name"
        w.write_imu(stamp[20:], acc[20:], acc[20:] * 0.01, np.eye(3), np.eye(3) * 1e-3)
    s = ros2.import_ros2(bag)
    assert s.meta.extra["ros2_frame_id"] == "imu,imu_long_name" and s.n == n
    assert np.array_equal(s.accel_g, acc / 9.80665) and np.array_equal(s.gyro_dps, np.rad2deg(acc * 0.01))
    assert np.array_equal(s.t_s, (stamp - stamp[0]) / 1e9)
