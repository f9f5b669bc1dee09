"""Write IMU data as a ROS 2 bag (rosbag2, MCAP storage, CDR) with ``rosbags``' writer and the ROS 2
message definitions it ships: sensor_msgs/msg/Imu, Temperature and MagneticField, readable by
``ros2 bag``, Foxglove and PlotJuggler.

sensor_msgs/msg/Imu messages are encoded by ``imu_cdr`` with numpy, all rows at once (the same bytes as
rosbags' serialize_cdr); Temperature and MagneticField through rosbags' message classes.

Units (REP 103): linear_acceleration m/s^2, angular_velocity rad/s, temperature degC, magnetic field
tesla. Covariances are row-major 3x3 (x, y, z). Orientation is not estimated:
``orientation_covariance[0] = -1`` as sensor_msgs/Imu requires for "no orientation".

Output: a path ending in ``.mcap`` gets the single MCAP file (the bag directory is built beside it
and its metadata.yaml dropped; ``ros2 bag`` and Foxglove open a bare .mcap); any other path gets a
rosbag2 directory (metadata.yaml + <name>_0.mcap). Written under a temporary name, renamed at the end.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.store.atomic import remove_stale

IMU_TOPIC = "/imu/data"
TEMP_TOPIC = "/imu/temperature"
MAG_TOPIC = "/imu/mag"
_NO_ORIENTATION = np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0])


_CDR_LE = b"\x00\x01\x00\x00"  # CDR encapsulation: little endian, plain CDR


def imu_cdr(stamp_ns, frame_id: str, accel_mps2, gyro_radps, accel_cov, gyro_cov) -> np.ndarray:
    """(n, L) uint8: each row one sensor_msgs/msg/Imu serialised as CDR, byte for byte what
    ``rosbags``' serialize_cdr writes (tests/flows/test_ros2_roundtrip.py), built with numpy for all rows at
    once. Layout after the 4-byte encapsulation (alignment counted from there): stamp sec int32,
    nanosec uint32, frame_id (uint32 length with the NUL, bytes, NUL), padding to 8, then 37 float64:
    orientation (0, 0, 0, 1), orientation_covariance (-1, 0 ...), angular_velocity, its covariance,
    linear_acceleration, its covariance."""
    stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
    n = stamp_ns.shape[0]
    name = frame_id.encode() + b"\0"
    head = 12 + len(name)
    start = (head + 7) // 8 * 8
    f64 = np.empty((n, 37))
    f64[:, :4] = (0.0, 0.0, 0.0, 1.0)
    f64[:, 4:13] = _NO_ORIENTATION
    f64[:, 13:16] = gyro_radps
    f64[:, 16:25] = _cov9(gyro_cov, n)
    f64[:, 25:28] = accel_mps2
    f64[:, 28:37] = _cov9(accel_cov, n)
    out = np.zeros((n, 4 + start + 37 * 8), dtype=np.uint8)
    out[:, :4] = np.frombuffer(_CDR_LE, dtype=np.uint8)
    words = np.empty((n, 3), dtype="<u4")
    words[:, 0] = (stamp_ns // 1_000_000_000).astype("<i4").view("<u4")
    words[:, 1] = stamp_ns % 1_000_000_000
    words[:, 2] = len(name)
    out[:, 4:16] = words.view(np.uint8).reshape(n, 12)
    out[:, 16 : 4 + head] = np.frombuffer(name, dtype=np.uint8)
    out[:, 4 + start :] = f64.astype("<f8").view(np.uint8).reshape(n, 37 * 8)
    return out


def _cov9(c, n: int) -> np.ndarray:
    """(9,) or (3,3) -> broadcast (n,9); (n,9)/(n,3,3) kept."""
    a = np.asarray(c, dtype=np.float64)
    if a.size == 9:
        return np.broadcast_to(a.reshape(9), (n, 9))
    return a.reshape(n, 9)


class Ros2BagWriter:
    """Context manager: ``write_imu``, ``write_temperature``, ``write_mag`` (arrays), then close."""

    def __init__(
        self, out: str | Path, *, frame_id: str = "imu_link", metadata: dict[str, str] | None = None
    ):
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.out = Path(out)
        if self.out.is_dir():
            raise InputError("output exists and is a directory", where=str(self.out))
        if not self.out.parent.exists():
            raise InputError("output folder does not exist", where=str(self.out))
        self.single = self.out.suffix == ".mcap"
        self._tmp = self.out.with_name(f".{self.out.stem}.{os.getpid()}.bagtmp")
        shutil.rmtree(self._tmp, ignore_errors=True)
        # the temporary bags of killed writers of this output (their PID is not running)
        remove_stale(self.out.parent, f".{self.out.stem}.", r"bagtmp", "temporary bag folder")
        self.ts = get_typestore(Stores.ROS2_HUMBLE)
        self.frame_id = frame_id
        self._tmp.mkdir()
        self._bag = self._tmp / self.out.stem  # the bag's files are named after its folder
        try:
            self._w = Writer(self._bag, version=9, storage_plugin=StoragePlugin.MCAP)
            for k, v in (metadata or {}).items():
                self._w.set_custom_data(k, str(v))
            self._w.open()
        except BaseException:  # no .bagtmp left when the writer cannot even start
            shutil.rmtree(self._tmp, ignore_errors=True)
            raise
        self._conns: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        T = self.ts.types
        self._Header, self._Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
        self._V3 = T["geometry_msgs/msg/Vector3"]

    def _conn(self, topic: str, msgtype: str):
        c = self._conns.get(topic)
        if c is None:
            c = self._w.add_connection(topic, msgtype, typestore=self.ts)
            self._conns[topic] = c
            self.counts[topic] = 0
        return c

    def _header(self, ns: int):
        return self._Header(stamp=self._Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000)),
                            frame_id=self.frame_id)  # fmt: skip

    def _put(self, topic: str, msgtype: str, msgs, log_ns) -> None:
        """Serialize and write; log_ns: the bag's log (receive) time of each message."""
        conn = self._conn(topic, msgtype)
        ser = self.ts.serialize_cdr
        for ns, m in zip(log_ns, msgs, strict=True):
            self._w.write(conn, int(ns), ser(m, msgtype))
        self.counts[topic] += len(log_ns)

    def write_imu(
        self, stamp_ns, accel_mps2, gyro_radps, accel_cov, gyro_cov, *, topic: str = IMU_TOPIC, log_ns=None
    ) -> None:
        """n samples: stamps (ns, Unix), accel (n,3) m/s^2, gyro (n,3) rad/s, covariances (9,) or (n,9);
        log_ns: the bag's log times (default the stamps)."""
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        rows = imu_cdr(stamp_ns, self.frame_id, accel_mps2, gyro_radps, accel_cov, gyro_cov)
        conn = self._conn(topic, "sensor_msgs/msg/Imu")
        log = stamp_ns if log_ns is None else np.asarray(log_ns, dtype=np.int64)
        for ns, row in zip(log.tolist(), rows, strict=True):
            self._w.write(conn, ns, row.tobytes())
        self.counts[topic] += rows.shape[0]

    def write_temperature(
        self, stamp_ns, temp_degC, variance: float = 0.0, *, topic: str = TEMP_TOPIC
    ) -> None:
        """Temperature messages (degC; variance degC^2, 0 = unknown)."""
        T = self.ts.types["sensor_msgs/msg/Temperature"]
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        msgs = [
            T(header=self._header(int(s)), temperature=float(v), variance=float(variance))
            for s, v in zip(stamp_ns, np.asarray(temp_degC, float).tolist(), strict=True)
        ]
        self._put(topic, "sensor_msgs/msg/Temperature", msgs, stamp_ns)

    def write_mag(self, stamp_ns, mag_T, cov=None, *, topic: str = MAG_TOPIC) -> None:
        """MagneticField messages: (m,3) tesla; covariance (9,) T^2 (zeros = unknown)."""
        M = self.ts.types["sensor_msgs/msg/MagneticField"]
        stamp_ns = np.asarray(stamp_ns, dtype=np.int64)
        c = np.zeros(9) if cov is None else np.asarray(cov, float).reshape(9)
        msgs = [
            M(
                header=self._header(int(s)),
                magnetic_field=self._V3(x=v[0], y=v[1], z=v[2]),
                magnetic_field_covariance=c,
            )
            for s, v in zip(stamp_ns, np.asarray(mag_T, float).tolist(), strict=True)
        ]
        self._put(topic, "sensor_msgs/msg/MagneticField", msgs, stamp_ns)

    def close(self) -> Path:
        """Finish the bag and move it into place; returns the output path."""
        self._w.close()
        if self.single:
            (mcap,) = self._bag.glob("*.mcap")
            os.replace(mcap, self.out)
            shutil.rmtree(self._tmp)
        else:
            if self.out.exists():  # never delete a bag that is already there
                self.abort()
                raise InputError(
                    "the ROS 2 bag folder already exists; choose another name", where=str(self.out)
                )
            os.replace(self._bag, self.out)
            shutil.rmtree(self._tmp)
        return self.out

    def abort(self) -> None:
        try:
            self._w.close()
        except Exception:  # the bag is being thrown away: a writer that cannot close must not keep it
            pass
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> Ros2BagWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
