"""Register-level behaviour of the emulated MPU-9250 / AK8963 (driven by raw bus calls)."""

from __future__ import annotations

import numpy as np
import pytest
from smbus2 import i2c_msg

from accellog.acquire import registers as R
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import RealClock, SimClock
from accellog.acquire.emulator.poses import PoseSequenceMotion
from accellog.acquire.emulator.sensor_model import AccelErrors, SensorModel
from accellog.core.protocol import six_position

A = 0x68
AK = R.AK8963_ADDRESS


def make(**kw) -> tuple[SimClock, EmulatedMpu9250]:
    clock = SimClock()
    model = SensorModel(
        PoseSequenceMotion(six_position(5.0)),
        AccelErrors(noise_density_g_per_rtHz=300e-6),
        seed=1,
        **kw.pop("model_kw", {}),
    )
    return clock, EmulatedMpu9250(model, clock, **kw)


def fifo_on(chip: EmulatedMpu9250, div: int = 0, dlpf: int = 3) -> None:
    chip.write_byte_data(A, R.SMPLRT_DIV, div)
    chip.write_byte_data(A, R.CONFIG, dlpf)
    chip.write_byte_data(A, R.FIFO_EN, 0xF8)
    chip.write_byte_data(A, R.USER_CTRL, R.USER_FIFO_EN | R.USER_FIFO_RST)


def count(chip) -> int:
    hi, lo = chip.read_i2c_block_data(A, R.FIFO_COUNTH, 2)
    return (hi << 8) | lo


def test_reset_values_h_reset_and_self_clearing_bits():
    _clock, chip = make(who_am_i=0x73)
    assert chip.read_byte_data(A, R.PWR_MGMT_1) == 0x01
    assert chip.read_byte_data(A, R.WHO_AM_I) == 0x73
    assert chip.read_byte_data(A, R.CONFIG) == 0
    chip.write_byte_data(A, R.GYRO_CONFIG, 0x18)
    chip.write_byte_data(A, R.PWR_MGMT_1, 0x80)
    assert chip.read_byte_data(A, R.PWR_MGMT_1) == 0x01  # H_RESET self-clears, reset value back
    assert chip.read_byte_data(A, R.GYRO_CONFIG) == 0
    chip.write_byte_data(A, R.USER_CTRL, R.USER_FIFO_EN | R.USER_FIFO_RST)
    assert chip.read_byte_data(A, R.USER_CTRL) == R.USER_FIFO_EN  # FIFO_RST self-clears
    chip.write_byte_data(A, R.WHO_AM_I, 0x00)  # read-only
    assert chip.read_byte_data(A, R.WHO_AM_I) == 0x73


def test_smbus_block_limit_and_naks():
    _clock, chip = make()
    with pytest.raises(ValueError):
        chip.read_i2c_block_data(A, R.FIFO_R_W, 33)
    with pytest.raises(ValueError):
        chip.write_i2c_block_data(A, 0x00, [0] * 33)
    for addr in (0x69, 0x50, AK):
        with pytest.raises(OSError) as e:
            chip.read_byte_data(addr, 0)
        assert e.value.errno == 121
    chip.write_byte_data(A, R.INT_PIN_CFG, R.INT_PIN_BYPASS_EN)
    assert chip.read_byte_data(AK, R.AK_WIA) == 0x48
    chip.write_byte_data(A, R.USER_CTRL, R.USER_I2C_MST_EN)  # master mode hides the AK8963 again
    with pytest.raises(OSError):
        chip.read_byte_data(AK, R.AK_WIA)
    # SMBus words are little-endian: byte-swaps this chip's big-endian WHO_AM_I / next register
    assert chip.read_word_data(A, R.WHO_AM_I) == 0x71


def test_sample_rate_from_dlpf_fchoice_and_divider():
    for div, dlpf, gyro_cfg, rate in [
        (9, 3, 0, 100.0),
        (0, 1, 0, 1000.0),
        (4, 0, 0, 8000.0),
        (0, 3, 1, 32000.0),
    ]:
        clock, chip = make()
        chip.write_byte_data(A, R.GYRO_CONFIG, gyro_cfg)
        fifo_on(chip, div, dlpf)
        assert chip.sample_rate_hz == rate
        clock.advance_ns(round(30 / rate * 1e9))  # 30 periods: 420 bytes (fits)
        assert count(chip) == 30 * 14


def test_clock_error_stretches_the_sample_period():
    clock, chip = make(model_kw={})
    chip.model.accel.clock_error = 0.02
    fifo_on(chip)  # (re)configuring takes the model's clock error
    clock.sleep(10.2)
    assert chip.sample_period_s == pytest.approx(1.02e-3)
    assert chip.fifo_samples_pushed == 10_000


def test_fifo_count_latch_bursts_and_overflow_drop_oldest():
    clock, chip = make()
    fifo_on(chip)
    clock.sleep(0.010)
    assert chip.read_byte_data(A, R.FIFO_COUNTH) == 0
    clock.sleep(0.010)  # 10 more samples arrive between the two byte reads
    assert chip.read_byte_data(A, R.FIFO_COUNTL) == 140  # latched by the COUNTH read
    assert count(chip) == 280
    # FIFO burst (no auto-increment) = the packets in order; the last one equals the data registers
    wr, rd = i2c_msg.write(A, [R.FIFO_R_W]), i2c_msg.read(A, 280)
    chip.i2c_rdwr(wr, rd)
    packets = np.frombuffer(bytes(rd), ">i2").reshape(20, 7)
    latest = np.frombuffer(bytes(chip.read_i2c_block_data(A, R.ACCEL_XOUT_H, 14)), ">i2")
    np.testing.assert_array_equal(packets[-1], latest)
    assert count(chip) == 0
    last = bytes(rd)[-1]
    assert chip.read_i2c_block_data(A, R.FIFO_R_W, 3) == [last] * 3  # empty FIFO repeats its last byte
    # overflow: mode 0 keeps the newest 512 bytes, FIFO_OFLOW set until INT_STATUS is read
    clock.sleep(0.100)
    assert count(chip) == 512
    status = chip.read_byte_data(A, R.INT_STATUS)
    assert status & R.INT_FIFO_OFLOW and not chip.read_byte_data(A, R.INT_STATUS) & R.INT_FIFO_OFLOW
    data = bytes(chip.read_i2c_block_data(A, R.FIFO_R_W, 32))
    for _ in range(15):
        data += bytes(chip.read_i2c_block_data(A, R.FIFO_R_W, 32))
    latest = bytes(chip.read_i2c_block_data(A, R.ACCEL_XOUT_H, 14))
    assert data[-14:] == latest and len(data) == 512  # newest sample last; 512 = 8 + 36 * 14


def test_fifo_mode_one_keeps_the_oldest_data():
    clock, chip = make()
    chip.write_byte_data(A, R.CONFIG, 3 | R.CONFIG_FIFO_MODE)
    fifo_on(chip, dlpf=3 | 0x40)
    clock.sleep(0.002)
    first = bytes(chip.read_i2c_block_data(A, R.FIFO_R_W, 14))
    clock.sleep(0.200)
    assert count(chip) == 512 and chip.read_byte_data(A, R.INT_STATUS) & R.INT_FIFO_OFLOW
    second = bytes(chip.read_i2c_block_data(A, R.FIFO_R_W, 14))
    k = chip.stream_origin_index  # sample 1 of the stream is the oldest one kept
    cfg = chip._sample_kw
    ref = chip.model.sample(chip._sample_time_s(np.array([k, k + 1])), index=np.array([k, k + 1]), **cfg)
    rows = np.concatenate([ref.accel_counts, ref.temp_counts[:, None], ref.gyro_counts], 1).astype(">i2")
    assert first == rows[0].tobytes() and second == rows[1].tobytes()


def test_sleep_stops_the_sample_clock_and_glitch_misaligns():
    clock, chip = make()
    fifo_on(chip)
    clock.sleep(0.005)
    chip.write_byte_data(A, R.PWR_MGMT_1, R.PWR_SLEEP | 1)
    clock.sleep(0.5)
    assert count(chip) == 70
    chip.write_byte_data(A, R.PWR_MGMT_1, 1)
    clock.sleep(0.003)
    assert count(chip) == 112
    chip.inject_fifo_glitch(drop_bytes=5)
    assert count(chip) % 14 == 9


def test_block_writes_auto_increment_and_lazy_generation_is_poll_independent():
    clock, chip = make()
    chip.write_i2c_block_data(A, R.SMPLRT_DIV, [1, 3, 0, 0, 0])  # SMPLRT_DIV, CONFIG, GYRO_, ACCEL_, ..2
    assert chip.sample_rate_hz == 500.0
    # polling often or rarely gives the same data registers at the same time
    clock_b, chip_b = make()
    chip_b.write_i2c_block_data(A, R.SMPLRT_DIV, [1, 3, 0, 0, 0])
    for _ in range(100):
        clock.sleep(0.0013)
        chip.read_byte_data(A, R.INT_STATUS)
    clock_b.sleep(0.13)
    assert chip.read_i2c_block_data(A, 0x3B, 14) == chip_b.read_i2c_block_data(A, 0x3B, 14)


def test_ak8963_asa_drdy_lock_dor_and_modes():
    clock, chip = make(model_kw={"mag_asa": (150, 128, 200)})
    chip.write_byte_data(A, R.INT_PIN_CFG, R.INT_PIN_BYPASS_EN)
    assert chip.read_i2c_block_data(AK, R.AK_ASAX, 3) == [0, 0, 0]  # only in fuse-ROM mode
    chip.write_byte_data(AK, R.AK_CNTL1, R.AK_MODE_FUSE_ROM)
    assert chip.read_i2c_block_data(AK, R.AK_ASAX, 4) == [150, 128, 200, 150]  # wraps 0x12 -> 0x10
    chip.write_byte_data(AK, R.AK_CNTL1, 0)
    chip.write_byte_data(AK, R.AK_CNTL1, R.AK_CNTL1_BIT_16 | R.AK_MODE_CONT_100HZ)
    clock.sleep(0.005)
    assert chip.read_byte_data(AK, R.AK_ST1) & R.AK_ST1_DRDY == 0
    clock.sleep(0.006)
    assert chip.read_byte_data(AK, R.AK_ST1) == R.AK_ST1_DRDY
    first = chip.read_i2c_block_data(AK, R.AK_HXL, 6)  # data read without ST2: locked
    clock.sleep(0.050)
    assert chip.read_i2c_block_data(AK, R.AK_HXL, 6) == first
    assert chip.read_byte_data(AK, R.AK_ST1) & R.AK_ST1_DRDY  # still the old sample, unread ST2
    st2 = chip.read_byte_data(AK, R.AK_ST2)
    assert st2 == R.AK_ST2_BITM  # 16-bit, no overflow
    st1 = chip.read_byte_data(AK, R.AK_ST1)
    assert st1 == R.AK_ST1_DRDY | R.AK_ST1_DOR  # new sample; 4 measurements were skipped
    burst = chip.read_i2c_block_data(AK, R.AK_ST1, 8)
    counts = np.frombuffer(bytes(burst[1:7]), "<i2")
    # identity pose: field (20, 0, -45) uT -> AK axes (0, 20, 45); raw = H / (0.15 * ASA factor)
    factor = (np.array([150, 128, 200]) - 128) / 256 + 1
    np.testing.assert_allclose(counts * 0.15 * factor, [0, 20, 45], atol=1.5)
    assert chip.read_byte_data(AK, R.AK_ST1) == 0  # ST2 in the burst cleared DRDY
    # single measurement: one sample after 7.2 ms, then power-down; 14-bit output clears BITM
    chip.write_byte_data(AK, R.AK_CNTL1, R.AK_MODE_SINGLE)
    clock.sleep(0.008)
    assert chip.read_byte_data(AK, R.AK_ST1) & R.AK_ST1_DRDY
    assert chip.read_byte_data(AK, R.AK_ST2) == 0 and chip.read_byte_data(AK, R.AK_CNTL1) == 0
    chip.write_byte_data(AK, R.AK_CNTL2, R.AK_CNTL2_SRST)
    assert chip.read_byte_data(AK, R.AK_CNTL1) == 0 and chip.read_byte_data(AK, R.AK_WIA) == 0x48


def test_ak8963_magnetic_overflow_flag():
    clock, chip = make(model_kw={"mag_field_uT": (3000.0, 2000.0, 1000.0)})
    chip.write_byte_data(A, R.INT_PIN_CFG, R.INT_PIN_BYPASS_EN)
    chip.write_byte_data(AK, R.AK_CNTL1, R.AK_CNTL1_BIT_16 | R.AK_MODE_CONT_8HZ)
    clock.sleep(0.13)
    burst = chip.read_i2c_block_data(AK, R.AK_ST1, 8)
    assert burst[0] & R.AK_ST1_DRDY and burst[7] & R.AK_ST2_HOFL


def test_injected_errors_are_seeded_and_have_both_errnos():
    def errs(seed):
        _clock, chip = make(i2c_error_rate=0.2, seed=seed)
        out = []
        for _ in range(300):
            try:
                chip.read_byte_data(A, R.WHO_AM_I)
                out.append(0)
            except OSError as e:
                out.append(e.errno)
        return out

    a, b, c = errs(1), errs(1), errs(2)
    assert a == b and a != c
    assert set(a) == {0, 5, 121} and 30 < sum(e != 0 for e in a) < 90


def test_real_clock_runs_the_chip_in_real_time():
    clock = RealClock()
    chip = EmulatedMpu9250(SensorModel(PoseSequenceMotion(six_position(5.0))), clock)
    fifo_on(chip)
    clock.sleep(0.02)
    assert 10 * 14 <= count(chip) <= 36 * 14
