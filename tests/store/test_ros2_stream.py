"""The streamed `import ros2` (ros2_stream.import_ros2_to_mcap) writes what the in-memory import writes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.ros2_bags import START_NS, session_to_bag

from accellog.cli import main
from accellog.core.errors import InputError
from accellog.flows.simulate import Scenario, simulate
from accellog.store.importers import ros2
from accellog.store.importers.ros2_stream import import_ros2_to_mcap
from accellog.store.reader import read_session
from accellog.store.ros2_writer import Ros2BagWriter
from accellog.store.writer import write_session


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    d = tmp_path_factory.mktemp("stream")
    sc = Scenario(protocol="six", hold_s=2.0, move_s=1.0, sample_rate_hz=200.0, seed=7)
    sc.magnetometer = {"field_uT": [20.0, 0.0, -40.0]}
    simulate(sc, d / "sim.mcap")
    s = read_session(d / "sim.mcap")
    return session_to_bag(s, d / "bag.mcap", temp_topic="/imu/temperature", mag_topic="/imu/mag",
                          log_lag_ns=2_000_000)  # fmt: skip


def test_streamed_file_reads_back_as_the_in_memory_import(bag, tmp_path, monkeypatch):
    monkeypatch.setattr(ros2, "_BLOCK", 300)  # several blocks, each whole batches of 7
    streamed, ref = tmp_path / "streamed.mcap", tmp_path / "ref.mcap"
    facts = import_ros2_to_mcap(bag, streamed, batch_size=7)
    write_session(ref, ros2.import_ros2(bag), batch_size=7)
    a, b = read_session(streamed), read_session(ref)
    for k in ("t_s", "sample_index", "accel_g", "gyro_dps", "temp_degC", "mag_t_s", "mag_uT"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert dataclasses.asdict(a.meta) == dataclasses.asdict(b.meta)
    assert a.meta.extra["ros2_mag_topic"] == "/imu/mag" and a.meta.sample_rate_hz > 0
    assert facts["samples"] == b.n and facts["duration_s"] == float(b.t_s[-1] - b.t_s[0])


def test_stamps_out_of_order_are_refused_naming_topic_and_message(tmp_path, capsys):
    """As CSV's import refuses a backward step: one line naming the topic and message, nothing written."""
    n = 50
    stamp = START_NS + np.arange(n, dtype=np.int64) * 10_000_000
    stamp[[10, 11]] = stamp[[11, 10]]
    bag, out = tmp_path / "swap.mcap", tmp_path / "o.mcap"
    with Ros2BagWriter(bag) as w:
        w.write_imu(stamp, np.tile([0, 0, 9.8], (n, 1)), np.zeros((n, 3)), np.zeros(9), np.zeros(9),
                    log_ns=START_NS + np.arange(n) * 10_000_000)  # fmt: skip
    with pytest.raises(InputError, match=r"/imu/data message 11: time goes backwards"):
        import_ros2_to_mcap(bag, out)
    assert list(tmp_path.iterdir()) == [bag]  # no temporary left
    assert main(["import", "ros2", str(bag), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("accellog: error: ") and "message 11" in err and "\n" not in err
    assert list(tmp_path.iterdir()) == [bag]


def test_one_message_is_refused_and_nothing_written(tmp_path):
    bag, out = tmp_path / "one.mcap", tmp_path / "o.mcap"
    with Ros2BagWriter(bag) as w:
        w.write_imu([START_NS], [[0, 0, 9.8]], [[0, 0, 0]], np.zeros(9), np.zeros(9))
    with pytest.raises(InputError, match="1 IMU message"):
        import_ros2_to_mcap(bag, out)
    assert list(tmp_path.iterdir()) == [bag]
