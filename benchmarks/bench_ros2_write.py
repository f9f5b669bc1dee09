"""*inner*: writing sensor_msgs/Imu messages for `accellog apply --ros2`: accellog's numpy CDR encoder
(accellog.store.ros2_writer.imu_cdr, all rows at once) against rosbags' per-message path (one Imu
object per sample, ``serialize_cdr``), the baseline, in the same run; both write the same bytes to a
rosbag2 MCAP bag with rosbags' writer. CPU time (process time), median of --repeat runs.

    python benchmarks/bench_ros2_write.py [--n 100000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from accellog.store.ros2_writer import _NO_ORIENTATION, Ros2BagWriter


def rosbags_path(w: Ros2BagWriter, stamp, acc, gyr, ca, cg) -> None:
    """The baseline: one message object per sample, serialised by rosbags."""
    T = w.ts.types
    Imu, Header, Time = T["sensor_msgs/msg/Imu"], T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    V3, Q = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    conn = w._conn("/imu/data", "sensor_msgs/msg/Imu")
    q0 = Q(x=0.0, y=0.0, z=0.0, w=1.0)
    for i, ns in enumerate(stamp.tolist()):
        m = Imu(
            header=Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=w.frame_id),
            orientation=q0,
            orientation_covariance=_NO_ORIENTATION,
            angular_velocity=V3(x=gyr[i, 0], y=gyr[i, 1], z=gyr[i, 2]),
            angular_velocity_covariance=cg[i],
            linear_acceleration=V3(x=acc[i, 0], y=acc[i, 1], z=acc[i, 2]),
            linear_acceleration_covariance=ca[i],
        )
        w._w.write(conn, ns, w.ts.serialize_cdr(m, "sensor_msgs/msg/Imu"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100_000, help="messages")
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    stamp = 1_700_000_000_000_000_000 + np.arange(a.n, dtype=np.int64) * 1_000_000
    acc, gyr = rng.normal(size=(a.n, 3)), rng.normal(size=(a.n, 3))
    ca, cg = np.abs(rng.normal(size=(a.n, 9))), np.abs(rng.normal(size=(a.n, 9)))
    cpu: dict[str, list[float]] = {"rosbags serialize_cdr": [], "accellog imu_cdr": []}
    with tempfile.TemporaryDirectory() as d:
        for k in range(a.repeat):
            for name in cpu:  # interleaved
                out = Path(d) / f"{name.split()[0]}_{k}.mcap"
                t0 = time.process_time()
                with Ros2BagWriter(out) as w:
                    if name.startswith("rosbags"):
                        rosbags_path(w, stamp, acc, gyr, ca, cg)
                    else:
                        w.write_imu(stamp, acc, gyr, ca, cg)
                cpu[name].append(time.process_time() - t0)
    base = statistics.median(cpu["rosbags serialize_cdr"])
    print(f"{a.n} sensor_msgs/Imu messages to a rosbag2 MCAP file, CPU s (median of {a.repeat})")
    for name, v in cpu.items():
        m = statistics.median(v)
        print(f"  {name:24s} {m:7.2f} s  {1e6 * m / a.n:6.1f} us/msg  {m / base:5.2f}x the baseline")


if __name__ == "__main__":
    main()
