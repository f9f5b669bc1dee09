"""`accellog record --bus N`, the real-hardware path, end to end through the real smbus2 package:
smbus2.SMBus(1) opens /dev/i2c-1, whose ioctls reach the register-level emulated chip (patched
the way smbus2's own tests do). The chip runs in real time, like hardware."""

from __future__ import annotations

import numpy as np

from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import RealClock
from accellog.acquire.emulator.i2c_dev import emulated_i2c_bus
from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, SensorModel
from accellog.cli import main
from accellog.core.protocol import parse_protocol
from accellog.store.reader import read_session


def test_record_from_bus_through_real_smbus2(tmp_path, capsys):
    # the operator (the motion) holds each pose 3.5 s: the recorder waits ~1 s for stillness, holds 1.5 s
    motion = PoseSequenceMotion(parse_protocol("+z,-z", 3.5), move_s=1.5, start_delay_s=0.5)
    model = SensorModel(motion, accel=AccelErrors.datasheet(3), seed=3)
    chip = EmulatedMpu9250(model, RealClock(), seed=3)
    out = tmp_path / "hw.mcap"
    with emulated_i2c_bus(chip, bus_number=1) as adapter:
        rc = main(
            ["record", "--bus", "1", "--protocol", "+z,-z", "--hold", "1.5", "--rate", "200", "-o", str(out)]
        )
    assert rc == 0, capsys.readouterr().err
    assert adapter.ioctl_calls > 100  # every register access went through smbus2's ioctls
    s = read_session(out)
    assert s.meta.source == "hardware" and s.meta.who_am_i == 0x71 and s.meta.sample_rate_hz == 200.0
    assert [p.name for p in s.poses] == ["+z", "-z"]
    assert s.lost_samples() == 0 and np.array_equal(s.sample_index, np.arange(s.n))
    # each labelled hold reads its pose: +z up, then -z up (bias < 0.1 g)
    for p, sign in zip(s.poses, (1.0, -1.0), strict=True):
        z = s.accel_g[s.slice_time(p.start_s, p.end_s), 2]
        assert z.size >= 0.9 * 1.5 * 200 and abs(z.mean() - sign) < 0.1
    assert s.mag_uT is not None and s.mag_uT.shape[0] > 10  # AK8963 through bypass mode
