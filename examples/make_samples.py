"""Regenerate the small sample files of examples/ from the emulated MPU-9250 (deterministic seeds):

    python examples/make_samples.py            # writes examples/handheld.csv, imu_bag.mcap, mag_session.mcap

- handheld.csv: a hand-held calibration as another logger would write it (CSV, header row; t in s,
  ax..az in g, temp in degC, gx..gz in deg/s; 100 Hz): 12 orientations (faces, edges, corners) held
  about 12 deg off the nominal ones, no pose labels -> `accellog import csv`, `fit` (orientation-free).
- imu_bag.mcap: a short ROS 2 bag (rosbag2 MCAP, CDR): a six-position table session at 100 Hz on
  /imu/data (sensor_msgs/Imu, m/s^2 and rad/s, frame imu_link) with /imu/temperature at 10 Hz; zstd chunks, as
  `ros2 bag record --storage-preset-profile zstd_fast` writes them ->
  `accellog import ros2 examples/imu_bag.mcap --detect-holds -o s.mcap`.
- mag_session.mcap: an accellog session with the AK8963 magnetometer, simulated from
  examples/mag_scenario.toml (24 orientations, 50 Hz; field (20, 0, -45) uT, hard iron (30, -12, 8) uT,
  a soft-iron matrix) -> `accellog magcal examples/mag_session.mcap`.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from accellog.core.units import STANDARD_GRAVITY_MPS2
from accellog.flows.simulate import Scenario, simulate
from accellog.store.reader import read_session
from accellog.store.ros2_writer import Ros2BagWriter

HERE = Path(__file__).resolve().parent
START_NS = 1_700_000_000_000_000_000
TWELVE = "+x,-x,+y,-y,+z,-z,+x+y,-x+z,+y-z,+x+y+z,-x-y+z,+x-y-z"


def handheld_csv(out: Path, tmp: Path) -> None:
    sc = Scenario(protocol=TWELVE, hold_s=2.5, move_s=1.0, sample_rate_hz=100.0, seed=12,
                  fixture_tilt_deg=(12.0, 4.0))  # fmt: skip
    sc.temperature = {"kind": "ramp", "T0": 24.0, "rate_degC_per_s": 0.05}
    simulate(sc, tmp / "hand.mcap")
    s = read_session(tmp / "hand.mcap")
    cols = np.column_stack([s.t_s, s.accel_g, s.temp_degC, s.gyro_dps])
    head = (
        "# accellog sample: hand-held MPU-9250 (emulated), 100 Hz, no pose labels\nt,ax,ay,az,temp,gx,gy,gz"
    )
    np.savetxt(out, cols, delimiter=",", header=head, comments="",
               fmt=["%.3f", "%.5f", "%.5f", "%.5f", "%.2f", "%.3f", "%.3f", "%.3f"])  # fmt: skip


def ros2_bag(out: Path, tmp: Path) -> None:
    sc = Scenario(
        protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=100.0, seed=13, fixture_tilt_deg=(2.0, 1.0)
    )
    sc.temperature = {"kind": "ramp", "T0": 26.0, "rate_degC_per_s": 0.1}
    simulate(sc, tmp / "six.mcap")
    s = read_session(tmp / "six.mcap")
    stamp = START_NS + np.round(s.t_s * 1e9).astype(np.int64)
    cov_a, cov_g = np.diag([4e-4] * 3).ravel(), np.diag([3e-6] * 3).ravel()
    with Ros2BagWriter(tmp / "plain.mcap", frame_id="imu_link") as w:
        w.write_imu(stamp, s.accel_g * STANDARD_GRAVITY_MPS2, np.deg2rad(s.gyro_dps), cov_a, cov_g)
        w.write_temperature(stamp[::10], s.temp_degC[::10])
    zstd_chunks(tmp / "plain.mcap", out)


def zstd_chunks(src: Path, out: Path) -> None:
    """The same MCAP records (schemas, channels, messages, metadata) with zstd-compressed chunks."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer

    with open(src, "rb") as f, open(out, "wb") as g:
        reader = make_reader(f)
        summary = reader.get_summary()
        w = Writer(g, compression=CompressionType.ZSTD)
        w.start(profile=reader.get_header().profile, library="accellog examples/make_samples.py")
        for sid, sc in summary.schemas.items():
            w.register_schema(sc.name, sc.encoding, sc.data) == sid or sys.exit("schema ids differ")
        for cid, ch in summary.channels.items():
            w.register_channel(ch.topic, ch.message_encoding, ch.schema_id, ch.metadata) == cid or sys.exit(
                "ids"
            )
        for md in reader.iter_metadata():
            w.add_metadata(md.name, md.metadata)
        for _schema, ch, m in reader.iter_messages(log_time_order=False):
            w.add_message(ch.id, m.log_time, m.data, m.publish_time, m.sequence)
        w.finish()


def mag_session(out: Path) -> None:
    """examples/mag_scenario.toml, simulated (the same file `accellog simulate --scenario` reads)."""
    sc = Scenario.from_toml(HERE / "mag_scenario.toml")
    simulate(sc, out, force=True, start_time_unix_ns=START_NS, truth_step_s=0.1)


def main(argv: list[str]) -> int:
    out = Path(argv[0]) if argv else HERE
    with tempfile.TemporaryDirectory() as d:
        handheld_csv(out / "handheld.csv", Path(d))
        ros2_bag(out / "imu_bag.mcap", Path(d))
    mag_session(out / "mag_session.mcap")
    for name in ("handheld.csv", "imu_bag.mcap", "mag_session.mcap"):
        print(f"wrote {out / name} ({(out / name).stat().st_size / 1e3:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
