"""End to end through the real smbus2: SMBus(1) -> (patched os.open/ioctl) -> emulated chip."""

from __future__ import annotations

import numpy as np
import pytest
import smbus2
from smbus2 import SMBus, i2c_msg

from accellog.acquire.driver import Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.emulator.i2c_dev import emulated_i2c_bus
from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
from accellog.core.protocol import six_position


def _chip(clock: SimClock, seed: int = 2) -> EmulatedMpu9250:
    model = SensorModel(
        PoseSequenceMotion(six_position(2.0), move_s=1.0),
        AccelErrors.datasheet(4),
        GyroErrors.datasheet(4),
        seed=seed,
    )
    return EmulatedMpu9250(model, clock, seed=seed)


def test_driver_through_real_smbus2_end_to_end():
    clock = SimClock()
    chip = _chip(clock)
    with emulated_i2c_bus(chip, bus_number=1) as adapter, SMBus(1) as bus:
        assert isinstance(bus, smbus2.SMBus) and bus.funcs & smbus2.I2cFunc.I2C
        # smbus2's own argument checks still apply, bus errors come back as OSError 121
        with pytest.raises(ValueError):
            bus.read_i2c_block_data(0x68, 0x74, 33)
        with pytest.raises(OSError) as exc:
            bus.read_byte_data(0x0C, 0x00)
        assert exc.value.errno == 121
        drv = Mpu9250(bus, clock_ns=clock.now_ns)
        info = drv.probe()
        cfg = drv.configure(accel_range_g=4, sample_rate_div=1)
        asa = drv.enable_magnetometer(100)
        drv.start()
        batches, mags = [], []
        for _ in range(200):
            clock.sleep(0.03)
            batches.append(drv.read())
            m = drv.read_mag()
            if m is not None:
                mags.append(m)
        assert adapter.ioctl_calls > 1000
    assert (info.model, cfg.sample_rate_hz, cfg.accel_lsb_per_g) == ("MPU-9250", 500.0, 8192.0)
    np.testing.assert_allclose(asa, (np.array(chip.model.mag_asa) - 128) / 256 + 1)
    assert all(not b.events for b in batches)
    assert sum(b.n for b in batches) == 3000 and batches[-1].first_index + batches[-1].n == 3000
    # the emulator's own bytes, read over the emulated i2c-dev ioctls, decode to the model's counts
    idx = np.concatenate([b.first_index + np.arange(b.n) for b in batches])
    acc = np.concatenate([b.accel_counts for b in batches])
    k = chip.stream_origin_index + idx
    ref = chip.model.sample(
        chip._sample_time_s(k),
        index=k,
        accel_lsb_per_g=8192.0,
        gyro_lsb_per_dps=131.0,
        odr_hz=500.0,
        accel_bandwidth_hz=cfg.accel_bandwidth_hz,
        gyro_bandwidth_hz=cfg.gyro_bandwidth_hz,
    )
    np.testing.assert_array_equal(acc, ref.accel_counts)
    # first hold: +z up, so z reads about +1 g (plus the chip's bias and scale errors)
    assert abs(acc[:500, 2].mean() / 8192.0 - 1.0) < 0.2
    assert len(mags) == 200 and all(abs(np.linalg.norm(m.uT) - np.hypot(20, 45)) < 3 for m in mags[:30])


def test_smbus2_i2c_rdwr_and_fallback_through_ioctls():
    clock = SimClock()
    chip = _chip(clock)
    with emulated_i2c_bus(chip, bus_number=3), SMBus(3) as bus:
        drv = Mpu9250(bus, clock_ns=clock.now_ns)
        drv.configure()
        drv.start()
        clock.sleep(0.02)
        wr, rd = i2c_msg.write(0x68, [0x72]), i2c_msg.read(0x68, 2)
        bus.i2c_rdwr(wr, rd)
        assert list(rd) == [(20 * 14) >> 8, (20 * 14) & 0xFF]  # FIFO_COUNTH, FIFO_COUNTL
        # a burst at 0x3B auto-increments over the data registers (latest sample, big-endian)
        regs = bytes(bus.read_i2c_block_data(0x68, 0x3B, 14))
        chip.support_i2c_rdwr = False  # adapter without plain-I2C transfers: EOPNOTSUPP
        b = drv.read()
        assert b.n == 20 and not drv._use_rdwr
        assert (
            bytes(
                np.concatenate([b.accel_counts[-1], b.temp_counts[-1:], b.gyro_counts[-1]])
                .astype(">i2")
                .tobytes()
            )
            == regs
        )
