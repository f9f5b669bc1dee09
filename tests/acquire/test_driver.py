"""Mpu9250 driver against the register-level emulator: identity, configuration, FIFO stream with
overflow / misalignment / bus errors (every lost sample accounted), fallback reads, magnetometer."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from accellog.acquire import registers as R
from accellog.acquire.driver import FifoBatch, Mpu9250
from accellog.acquire.emulator.chip import EmulatedMpu9250
from accellog.acquire.emulator.clock import SimClock
from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
from accellog.core.errors import DeviceError, InputError
from accellog.core.kinematics import Kinematics


class WobbleMotion:
    """A fast-changing specific force (not physical, only distinctive): every sample's value tells
    its true time, so a sample index that is off by one is visible (~30 counts at 1 kHz)."""

    duration_s = 600.0
    local_gravity_mps2 = 9.80665

    def kinematics(self, t_s):
        t = np.asarray(t_s, float)
        f = np.stack(
            [0.5 * np.sin(2 * np.pi * 0.7 * t), 0.3 * np.cos(2 * np.pi * 1.3 * t), 0.9 + 0.05 * np.sin(t)], 1
        )
        w = np.stack([20 * np.sin(2 * np.pi * 0.4 * t), np.zeros_like(t), 5 * np.cos(t)], 1)
        q = np.tile([1.0, 0.0, 0.0, 0.0], (t.size, 1))
        z = np.zeros((t.size, 3))
        return Kinematics(t, f, w, z, z.copy(), q)

    def labels(self):
        return []


def make(
    *, who=0x71, mag=True, rate=0.0, retries=3, clock_error=0.0, noise=False, seed=0, **chip_kw
) -> tuple[SimClock, EmulatedMpu9250, Mpu9250]:
    clock = SimClock()
    accel = AccelErrors(clock_error=clock_error, noise_density_g_per_rtHz=300e-6 if noise else 0.0)
    model = SensorModel(WobbleMotion(), accel, GyroErrors.perfect(), seed=seed, temp_noise_degC=0.0)
    chip = EmulatedMpu9250(
        model, clock, who_am_i=who, has_magnetometer=mag, i2c_error_rate=rate, seed=seed, **chip_kw
    )
    return clock, chip, Mpu9250(chip, clock_ns=clock.now_ns, max_retries=retries)


def expected_counts(chip: EmulatedMpu9250, index: np.ndarray) -> np.ndarray:
    """Accel counts a perfect sensor gives at the true times of session samples ``index``."""
    tr = chip.model.truth(chip.motion_time_s(index / 1000.0))
    return np.clip(np.rint(tr.specific_force_g * 16384), -32768, 32767)


def run(clock, drv, reads: int, dt_s: float = 0.025) -> list[FifoBatch]:
    out = []
    for _ in range(reads):
        clock.sleep(dt_s)
        out.append(drv.read())
    return out


def check_alignment(chip, batches: list[FifoBatch], tol_counts: int = 1) -> None:
    """Every received sample has exactly the value of its true time: the indices (incl. gaps) are right."""
    idx = np.concatenate([b.first_index + np.arange(b.n) for b in batches])
    acc = np.concatenate([b.accel_counts for b in batches]).astype(float)
    assert np.all(np.diff(idx) > 0)
    err = np.abs(acc - expected_counts(chip, idx)).max()
    assert err <= tol_counts, f"samples do not match their indices (max error {err} counts)"


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("who", "model", "has_mag"),
    [(0x71, "MPU-9250", True), (0x73, "MPU-9255", True), (0x70, "MPU-6500", False)],
)
def test_probe_accepts_9250_9255_and_warns_for_6500(who, model, has_mag):
    _, _, drv = make(who=who, mag=has_mag)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        info = drv.probe()
    assert (info.who_am_i, info.model, info.has_magnetometer) == (who, model, has_mag)
    assert bool(w) == (not has_mag) and bool(info.warning) == (not has_mag)


@pytest.mark.parametrize(("who", "words"), [(0x68, "MPU-6050/9150"), (0x74, "MPU-6515"), (0x12, "unknown")])
def test_probe_rejects_other_chips_with_clear_message(who, words):
    _, _, drv = make(who=who)
    with pytest.raises(DeviceError, match=rf"WHO_AM_I=0x{who:02X}.*{words}.*not an MPU-9250"):
        drv.probe()


def test_probe_wrong_address_is_a_device_error():
    clock, chip, _ = make()
    drv = Mpu9250(chip, address=0x69, clock_ns=clock.now_ns)
    with pytest.raises(DeviceError, match="NAK"):
        drv.probe()


def test_configure_writes_registers_and_reports_config():
    _, chip, drv = make()
    cfg = drv.configure(accel_range_g=8, gyro_range_dps=1000, dlpf_cfg=2, a_dlpf_cfg=4, sample_rate_div=4)
    regs = chip.regs
    assert regs[R.PWR_MGMT_1] == 0x01 and regs[R.PWR_MGMT_2] == 0
    assert (regs[R.SMPLRT_DIV], regs[R.CONFIG], regs[R.GYRO_CONFIG]) == (4, 2 | R.CONFIG_FIFO_MODE, 2 << 3)
    assert (regs[R.ACCEL_CONFIG], regs[R.ACCEL_CONFIG2], regs[R.FIFO_EN]) == (2 << 3, 4, 0xF8)
    assert cfg.sample_rate_hz == 200.0 and chip.sample_rate_hz == 200.0
    assert (cfg.accel_lsb_per_g, cfg.gyro_lsb_per_dps) == (4096.0, 32.8)
    assert (cfg.gyro_bandwidth_hz, cfg.accel_bandwidth_hz) == (92.0, 21.2)
    assert drv.config is cfg
    for bad in (dict(accel_range_g=3), dict(gyro_range_dps=300), dict(dlpf_cfg=8), dict(sample_rate_div=256)):
        with pytest.raises(InputError):
            drv.configure(**bad)


def test_read_before_start_is_refused():
    _, _, drv = make()
    drv.configure()
    with pytest.raises(DeviceError, match="start"):
        drv.read()


def test_continuous_stream_indices_times_and_values():
    clock, chip, drv = make()
    drv.configure()
    drv.start()
    batches = run(clock, drv, 200, 0.025)
    assert sum(b.n for b in batches) == 5000
    assert all(not b.events for b in batches)
    idx = np.concatenate([b.first_index + np.arange(b.n) for b in batches])
    np.testing.assert_array_equal(idx, np.arange(5000))
    t_ns = np.concatenate([b.t_ns for b in batches])
    np.testing.assert_array_equal(t_ns, np.arange(5000) * 1_000_000)
    assert batches[0].t_ns.dtype == np.int64 and batches[0].accel_counts.dtype == np.int16
    assert batches[0].accel_counts.shape == (25, 3) and batches[0].temp_counts.shape == (25,)
    assert batches[-1].host_time_ns == 200 * 25_000_000
    check_alignment(chip, batches, tol_counts=0)
    # gyro and temperature come through too (perfect sensor, 25 degC)
    tr = chip.model.truth(chip.motion_time_s(np.arange(25) / 1000.0))
    np.testing.assert_array_equal(batches[0].gyro_counts, np.rint(tr.omega_dps * 131.0))
    np.testing.assert_array_equal(batches[0].temp_counts, np.full(25, round(4 * 333.87)))


def test_overflow_is_detected_reset_and_accounted():
    clock, chip, drv = make()
    drv.configure()
    drv.start()
    batches = run(clock, drv, 20)
    clock.sleep(0.4573)  # stop reading: ~480 samples arrive, the FIFO holds 36
    batches += run(clock, drv, 40)
    events = [e for b in batches for e in b.events]
    assert [e.kind for e in events] == ["fifo_overflow"]
    ev = events[0]
    received = sum(b.n for b in batches)
    # everything the chip took is either received, lost (in events) or still in the FIFO
    in_fifo = chip.fifo_count // 14
    assert abs(received + ev.lost_samples + in_fifo - chip.fifo_samples_pushed) <= 1
    # FIFO_MODE = 1: the 36 whole packets the full FIFO kept are read (aligned), only the rest is lost
    assert 434 <= ev.lost_samples <= 449
    assert ev.sample_index == 536 and ev.t_s == pytest.approx(0.536)
    check_alignment(chip, batches)


def test_overflow_keeps_the_whole_packets_the_full_fifo_held():
    clock, chip, drv = make()
    drv.configure()
    assert chip.regs[R.CONFIG] & R.CONFIG_FIFO_MODE
    drv.start()
    batches = run(clock, drv, 4)
    clock.sleep(0.2)
    b = drv.read()
    assert [e.kind for e in b.events] == ["fifo_overflow"]
    assert "36 whole packets kept" in b.events[0].detail
    assert b.n == 36 and b.first_index == 100 and b.events[0].lost_samples == 164
    check_alignment(chip, [*batches, b], tol_counts=0)


def test_a_clone_that_ignores_fifo_mode_stores_no_misaligned_packet():
    # the chip stores FIFO_MODE = 1 but drops its oldest bytes: the head is misaligned; the driver sees
    # the kept packets' temperature jump and drops them (the pre-FIFO_MODE loss, never garbage)
    clock = SimClock()
    model = SensorModel(WobbleMotion(), AccelErrors(), GyroErrors.perfect(), seed=0)  # temperature noise on
    chip = EmulatedMpu9250(model, clock, honours_fifo_mode=False)
    drv = Mpu9250(chip, clock_ns=clock.now_ns)
    drv.configure()
    drv.start()
    batches = run(clock, drv, 4)
    clock.sleep(0.2)
    b = drv.read()
    assert [e.kind for e in b.events] == ["fifo_overflow"] and "misaligned, dropped" in b.events[0].detail
    assert b.n == 0 and b.events[0].lost_samples == 200
    batches += [b, *run(clock, drv, 4)]
    check_alignment(chip, batches, tol_counts=40)  # temperature-noise model: counts within noise


def test_misaligned_fifo_is_reset_and_accounted():
    clock, chip, drv = make()
    drv.configure()
    drv.start()
    batches = run(clock, drv, 10)
    clock.sleep(0.010)
    chip.inject_fifo_glitch(drop_bytes=3)
    batches += run(clock, drv, 10)
    events = [e for b in batches for e in b.events]
    assert [e.kind for e in events] == ["misaligned"]
    assert events[0].lost_samples == 35 and events[0].sample_index == 250
    assert drv.next_index == 250 + 35 + 9 * 25
    check_alignment(chip, batches, tol_counts=0)


def test_injected_bus_errors_are_retried_without_loss():
    clock, chip, drv = make(rate=0.05, retries=5, error_consumes_fifo=False)
    drv.configure()
    drv.start()
    batches = run(clock, drv, 400)
    events = [e for b in batches for e in b.events]
    assert chip.errors_injected > 20
    assert {e.kind for e in events} <= {"retry"} and len(events) >= 20
    assert sum(e.lost_samples for e in events) == 0
    assert drv.next_index == 10_000
    check_alignment(chip, batches, tol_counts=0)


def test_persistent_bus_errors_lose_samples_that_are_all_accounted():
    clock, chip, drv = make(rate=0.25, retries=1, seed=3)
    drv.configure()
    drv.start()
    batches = run(clock, drv, 600)
    events = [e for b in batches for e in b.events]
    kinds = {e.kind for e in events}
    assert {"retry", "i2c_error"} <= kinds
    lost = sum(e.lost_samples for e in events)
    received = sum(b.n for b in batches)
    assert lost > 100
    # every sample the chip produced is received, accounted as lost or still in the FIFO
    assert received + lost + chip.fifo_count // 14 == pytest.approx(chip.fifo_samples_pushed, abs=3)
    assert drv.lost_samples == lost
    check_alignment(chip, batches)


def test_failed_fallback_read_keeps_the_packets_read_before_it():
    """SMBus-only reads (28-byte bursts): a burst that fails for good or eats FIFO bytes costs the
    samples from there on (accounted), not the packets already read in the same drain."""
    clock, chip, drv = make(retries=0, seed=5, support_i2c_rdwr=False)
    drv.configure()
    drv.start()
    chip.i2c_error_rate = 0.02  # every error is final (max_retries = 0); half of them eat FIFO bytes
    batches = run(clock, drv, 400)
    errors = [(b, e) for b in batches for e in b.events if e.kind == "i2c_error"]
    assert len(errors) > 5
    # a drain cut short keeps its first packets: samples right up to the event's index
    partial = [b for b, e in errors if b.n and e.sample_index == b.first_index + b.n]
    assert len(partial) >= 3
    lost = sum(e.lost_samples for b in batches for e in b.events)
    received = sum(b.n for b in batches)
    assert received + lost + chip.fifo_count // 14 == pytest.approx(chip.fifo_samples_pushed, abs=3)
    check_alignment(chip, batches)


def test_gap_estimate_uses_measured_rate_with_clock_error():
    clock, chip, drv = make(clock_error=0.02)  # chip runs 2 % slow: 980.4 samples per host second
    drv.configure()
    drv.start()
    batches = run(clock, drv, 200)  # 5 s
    assert drv.rate_estimate_hz == pytest.approx(1000 / 1.02, rel=1e-3)
    clock.sleep(3.0)
    batches += run(clock, drv, 10)
    (ev,) = [e for b in batches for e in b.events]
    assert ev.kind == "fifo_overflow"
    true_lost = chip.fifo_samples_pushed - sum(b.n for b in batches) - chip.fifo_count // 14
    assert abs(true_lost - 3025) > 50  # the nominal ODR would misplace the rest of the session
    assert abs(ev.lost_samples - true_lost) <= 1


class SmbusOnly:
    """A bus object with the SMBus byte/block calls only (no i2c_rdwr attribute)."""

    def __init__(self, chip):
        self._chip = chip
        self.block_reads: list[int] = []

    def read_byte_data(self, a, r, force=None):
        return self._chip.read_byte_data(a, r)

    def write_byte_data(self, a, r, v, force=None):
        self._chip.write_byte_data(a, r, v)

    def read_i2c_block_data(self, a, r, n, force=None):
        self.block_reads.append(n)
        return self._chip.read_i2c_block_data(a, r, n)

    def write_i2c_block_data(self, a, r, d, force=None):
        self._chip.write_i2c_block_data(a, r, d)


@pytest.mark.parametrize("kind", ["eopnotsupp", "no_attribute"])
def test_fallback_block_reads_give_identical_stream(kind):
    clock_a, _, drv_a = make(noise=True, seed=5)
    clock_b, chip_b, _ = make(noise=True, seed=5, support_i2c_rdwr=kind != "eopnotsupp")
    bus = SmbusOnly(chip_b) if kind == "no_attribute" else chip_b
    drv_b = Mpu9250(bus, clock_ns=clock_b.now_ns)
    for d in (drv_a, drv_b):
        d.configure()
        d.start()
    a = run(clock_a, drv_a, 40)
    b = run(clock_b, drv_b, 40)
    np.testing.assert_array_equal(
        np.concatenate([x.accel_counts for x in a]), np.concatenate([x.accel_counts for x in b])
    )
    np.testing.assert_array_equal(
        np.concatenate([x.gyro_counts for x in a]), np.concatenate([x.gyro_counts for x in b])
    )
    if kind == "no_attribute":
        assert max(bus.block_reads) == 28  # two whole packets per SMBus block transfer


def test_magnetometer_bypass_asa_and_readings():
    clock, chip, drv = make()
    drv.configure()
    with pytest.raises(OSError) as exc:
        chip.read_byte_data(R.AK8963_ADDRESS, R.AK_WIA)
    assert exc.value.errno == 121
    asa = drv.enable_magnetometer(100)
    assert chip.regs[R.INT_PIN_CFG] & R.INT_PIN_BYPASS_EN and not chip.regs[R.USER_CTRL] & R.USER_I2C_MST_EN
    np.testing.assert_allclose(asa, (np.array(chip.model.mag_asa) - 128) / 256 + 1)
    drv.start()
    assert drv.read_mag() is None  # no measurement finished yet
    clock.sleep(0.0105)
    m = drv.read_mag()
    assert m is not None and not m.hofl and not m.dor and m.ut_per_lsb == 0.15
    # world field (20, 0, -45) uT, identity pose; AK8963 axes (y_s, x_s, -z_s) = (0, 20, 45)
    np.testing.assert_allclose(m.uT, [0.0, 20.0, 45.0], atol=1.5)
    np.testing.assert_allclose(m.uT, m.counts * m.asa_factor * 0.15)
    assert drv.read_mag() is None  # DRDY cleared by the ST2 read
    clock.sleep(0.035)
    m2 = drv.read_mag()
    assert m2 is not None and m2.dor  # measurements were skipped


def test_magnetometer_refused_without_ak8963():
    _, _, drv = make(who=0x70, mag=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        drv.probe()
    drv.configure()
    with pytest.raises(DeviceError, match="no AK8963"):
        drv.enable_magnetometer()
    _, _, drv = make(who=0x71, mag=False)  # claims to be a 9250, but 0x0C never answers
    drv.configure()
    with pytest.raises(DeviceError, match="no AK8963 answers at 0x0C"):
        drv.enable_magnetometer()
    with pytest.raises(InputError):
        drv.enable_magnetometer(mode_hz=50)


def test_an_overflow_on_the_first_read_whose_kept_burst_fails_is_counted_not_a_crash():
    from accellog.acquire import driver as drv_mod

    clock, _chip, drv = make()
    drv.configure()
    drv.start()
    clock.sleep(0.2)  # the first read finds the FIFO overflowed

    def failing(n_packets, n_bytes):
        raise drv_mod._FifoLost(b"", "burst failed after 3 attempts")

    drv._read_fifo_bytes = failing
    b = drv.read()
    assert b.n == 0 and [e.kind for e in b.events] == ["fifo_overflow"]
    assert "0 whole packets kept" in b.events[0].detail and "burst failed" in b.events[0].detail
    assert b.events[0].lost_samples == 200
