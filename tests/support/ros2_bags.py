"""Build rosbag2 MCAP bags for tests with rosbags' writer (the ROS 2 message definitions it ships),
and read bags back with an independent decoder (mcap-ros2-support)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from accellog.core.session import Session
from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.store.ros2_writer import Ros2BagWriter

START_NS = 1_700_000_000_123_456_789


def session_to_bag(
    s: Session,
    out: Path,
    *,
    topic: str = "/imu/data",
    temp_topic: str | None = None,
    mag_topic: str | None = None,
    log_lag_ns: int = 0,
    extra_topics: tuple[str, ...] = (),
    frame_id: str = "imu_link",
) -> Path:
    """Write a Session as sensor_msgs/Imu (m/s^2, rad/s) stamped START_NS + t; log time = stamp + lag."""
    stamp = START_NS + np.round(s.t_s * 1e9).astype(np.int64)
    cov_a = np.diag([1e-4, 1e-4, 1e-4]).reshape(9)
    cov_g = np.diag([1e-6, 1e-6, 1e-6]).reshape(9)
    gyro = np.zeros((s.n, 3)) if s.gyro_dps is None else np.deg2rad(s.gyro_dps)
    with Ros2BagWriter(out, frame_id=frame_id) as w:
        w.write_imu(
            stamp,
            s.accel_g * STANDARD_GRAVITY_MPS2,
            gyro,
            cov_a,
            cov_g,
            topic=topic,
            log_ns=stamp + log_lag_ns,
        )
        for t in extra_topics:
            w.write_imu(stamp[:10], s.accel_g[:10] * STANDARD_GRAVITY_MPS2, gyro[:10], cov_a, cov_g, topic=t)
        if temp_topic and s.temp_degC is not None:
            k = slice(None, None, 10)  # a slower temperature stream, as drivers publish it
            w.write_temperature(stamp[k], s.temp_degC[k], topic=temp_topic)
        if mag_topic and s.mag_t_s is not None:
            w.write_mag(
                START_NS + np.round(s.mag_t_s * 1e9).astype(np.int64), s.mag_uT * 1e-6, topic=mag_topic
            )
    return out


def decode(path: Path) -> dict[str, list]:
    """{topic: [message]} decoded with mcap + mcap-ros2-support (a CDR decoder independent of rosbags)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, _message, msg in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append(msg)
    return out


def handheld_session(out: Path, *, tilt_deg: float = 12.0, seed: int = 5) -> Session:
    """An emulated hand-held session: 12 orientations (faces, edges, corners) held tilt_deg off the
    nominal ones, 2.5 s each at 200 Hz, temperature rising 0.1 degC/s; written to ``out`` (MCAP)."""
    from accellog.flows.simulate import Scenario, simulate
    from accellog.store.reader import read_session

    sc = Scenario(protocol=TWELVE, hold_s=2.5, move_s=1.0, sample_rate_hz=200.0, seed=seed,
                  fixture_tilt_deg=(tilt_deg, 0.0))  # fmt: skip
    sc.temperature = {"kind": "ramp", "T0": 20.0, "rate_degC_per_s": 0.1}
    simulate(sc, out)
    return read_session(out)


TWELVE = "+x,-x,+y,-y,+z,-z,+x+y,-x+z,+y-z,+x+y+z,-x-y+z,+x-y-z"
"""Six faces, three edges and three corners: enough directions for an orientation-free fit."""
