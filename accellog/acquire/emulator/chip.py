"""Register-level emulated MPU-9250 (+ AK8963) with the smbus2 ``SMBus`` method surface.

The chip keeps a sample clock derived from DLPF_CFG / FCHOICE_B / SMPLRT_DIV: after the last
(re)configuration at motion time t_r with next global sample index k_r, sample k is taken at

    t_k = t_r + (k - k_r + 1) * (1 + eps_clock) / ODR        (s since the clock's start)

Samples are produced lazily whenever the bus is accessed, from the clock: everything due since the
last access goes into the data registers (latest sample, big-endian) and, if enabled, the 512-byte
FIFO (FIFO_MODE 0 drops the oldest bytes, 1 drops new bytes; both set INT_STATUS.FIFO_OFLOW,
which a read clears). Counts come from the ``SensorModel`` computed ahead in vectorised blocks, so a
``SimClock`` session runs as fast as the CPU allows and the result does not depend on how often the
host polls.

Bus behaviour (see /work/shared/reference/mpu9250.md): burst reads at FIFO_R_W (0x74) do not
auto-increment, other bursts do; reading FIFO_COUNTH latches FIFO_COUNTL; an empty FIFO returns
its last byte again; FIFO_RST, H_RESET self-clear; PWR_MGMT_1 resets to 0x01. The AK8963 answers
at 0x0C only while INT_PIN_CFG.BYPASS_EN = 1 and USER_CTRL.I2C_MST_EN = 0 (else OSError 121):
WIA 0x48, ST1 DRDY/DOR, data locked from the first data-register read until ST2 is read, ASA
readable in fuse-ROM mode, CNTL1 single / 8 Hz / 100 Hz modes, 14/16-bit output, ST2.HOFL.
``read_i2c_block_data`` / ``write_i2c_block_data`` refuse more than 32 bytes (ValueError), as
smbus2 does; ``i2c_rdwr`` has no limit. Injected bus errors (errno 121 or 5, seeded) happen with
probability ``i2c_error_rate`` per transaction; an errno-5 FIFO read consumes the bytes it asked
for when ``error_consumes_fifo`` (a transfer that died half way), so the samples are really lost.
"""

from __future__ import annotations

import ctypes
import errno as _errno

import numpy as np

from accellog.acquire import registers as R
from accellog.acquire.emulator.sensor_model import SensorModel
from accellog.core.errors import DeviceError
from accellog.core.session import Truth
from accellog.core.units import ACCEL_LSB_PER_G, GYRO_LSB_PER_DPS

_I2C_FUNC_I2C = 0x00000001
_I2C_FUNC_SMBUS_EMUL = 0x0EFF0008


def _nak() -> OSError:
    return OSError(_errno.EREMOTEIO, "Remote I/O error")


class EmulatedMpu9250:
    """An MPU-9250 on an I2C bus, driven by a SensorModel and a clock (SimClock or RealClock).

    who_am_i: 0x71 (MPU-9250), 0x73 (MPU-9255), 0x70 (MPU-6500 clone), 0x68 (MPU-6050), ...
    has_magnetometer: False for clones without an AK8963 (0x0C never answers).
    support_i2c_rdwr: False makes ``i2c_rdwr`` fail with EOPNOTSUPP (SMBus-only adapters).
    block_samples: samples computed ahead per model call.
    """

    def __init__(
        self,
        model: SensorModel,
        clock,
        *,
        who_am_i: int = R.WHO_AM_I_MPU9250,
        has_magnetometer: bool = True,
        address: int = R.MPU_ADDRESS,
        i2c_error_rate: float = 0.0,
        seed: int = 0,
        support_i2c_rdwr: bool = True,
        error_consumes_fifo: bool = True,
        block_samples: int = 2048,
        honours_fifo_mode: bool = True,
    ) -> None:
        self.model = model
        self.clock = clock
        self._now_ns = clock.now_ns
        self.who_am_i = int(who_am_i)
        self.has_magnetometer = bool(has_magnetometer)
        self.address = int(address)
        self.i2c_error_rate = float(i2c_error_rate)
        self.support_i2c_rdwr = bool(support_i2c_rdwr)
        self.error_consumes_fifo = bool(error_consumes_fifo)
        self.block_samples = int(block_samples)
        self.honours_fifo_mode = bool(honours_fifo_mode)
        """False: a clone that stores CONFIG.FIFO_MODE but always drops the oldest bytes."""
        self._err_rng = np.random.default_rng([int(seed), 0x12C])
        self._t0_ns = int(self._now_ns())
        # statistics
        self.transactions = 0
        self.errors_injected = 0
        self.fifo_bytes_dropped = 0
        self._fifo_pushed = 0
        self._k_next = 0  # global index of the next sample to take
        self._ak_reset()
        self._power_on_reset()

    # ================================================================ state and sample clock
    def _power_on_reset(self) -> None:
        self.regs = bytearray(128)
        self.regs[R.PWR_MGMT_1] = R.PWR_MGMT_1_RESET
        self.regs[R.WHO_AM_I] = self.who_am_i & 0xFF
        self._fifo = bytearray()
        self._fifo_last = 0
        self._int_status = 0
        self._count_latch: int | None = None
        self._latest = bytes(14)
        self._origin_k: int | None = None
        self._origin_pending = False
        self._ptr = {self.address: 0, R.AK8963_ADDRESS: 0}
        self._rebase(self._motion_time_s(self._now_ns()))

    def _motion_time_s(self, now_ns: int) -> float:
        return (now_ns - self._t0_ns) * 1e-9

    @property
    def sample_rate_hz(self) -> float:
        """Nominal output data rate (Hz) for the current registers."""
        return R.sample_rate_hz(self.regs[R.CONFIG], self.regs[R.GYRO_CONFIG], self.regs[R.SMPLRT_DIV])

    @property
    def sample_period_s(self) -> float:
        """Real sample period (s) = (1 + eps_clock) / ODR."""
        return self._period_s

    def _rebase(self, t_now: float) -> None:
        """Restart the sample clock at t_now with the current configuration (drops computed blocks)."""
        self._odr_hz = self.sample_rate_hz
        self._period_s = (1.0 + self.model.clock_error) / self._odr_hz
        self._t_r = t_now
        self._k_r = self._k_next
        self._sleeping = bool(self.regs[R.PWR_MGMT_1] & R.PWR_SLEEP)
        self._next_due_t = t_now + self._period_s
        self._cache_k0 = 0
        self._cache_n = 0
        self._cache_bytes = b""
        self._cache_rows: np.ndarray | None = None
        fs_a = (self.regs[R.ACCEL_CONFIG] & R.ACCEL_FS_MASK) >> R.ACCEL_FS_SHIFT
        fs_g = (self.regs[R.GYRO_CONFIG] & R.GYRO_FS_MASK) >> R.GYRO_FS_SHIFT
        self._sample_kw = dict(
            accel_lsb_per_g=ACCEL_LSB_PER_G[R.ACCEL_RANGES_G[fs_a]],
            gyro_lsb_per_dps=GYRO_LSB_PER_DPS[R.GYRO_RANGES_DPS[fs_g]],
            odr_hz=self._odr_hz,
            accel_bandwidth_hz=R.accel_bandwidth_hz(self.regs[R.ACCEL_CONFIG2]),
            gyro_bandwidth_hz=R.gyro_bandwidth_hz(self.regs[R.CONFIG], self.regs[R.GYRO_CONFIG]),
        )

    def _sample_time_s(self, k: np.ndarray | int | float) -> np.ndarray:
        """Motion time (s) of global sample k (current clock epoch)."""
        return self._t_r + (np.asarray(k, np.float64) - self._k_r + 1.0) * self._period_s

    def _rows(self, k0: int, k1: int) -> tuple[bytes, int]:
        """Packed big-endian 14-byte rows of samples k0..k1-1: (bytes of the cache, offset of k0)."""
        if not (self._cache_k0 <= k0 and k1 <= self._cache_k0 + self._cache_n):
            n = max(self.block_samples, k1 - k0)
            k = np.arange(k0, k0 + n, dtype=np.int64)
            blk = self.model.sample(self._sample_time_s(k), index=k, **self._sample_kw)
            rows = np.empty((n, 7), dtype=">i2")
            rows[:, 0:3] = blk.accel_counts
            rows[:, 3] = blk.temp_counts
            rows[:, 4:7] = blk.gyro_counts
            self._cache_rows = rows
            self._cache_bytes = rows.tobytes()
            self._cache_k0, self._cache_n = k0, n
        return self._cache_bytes, (k0 - self._cache_k0) * R.PACKET_BYTES

    def _fifo_active(self) -> bool:
        return bool(self.regs[R.USER_CTRL] & R.USER_FIFO_EN) and bool(self.regs[R.FIFO_EN] & 0xF8)

    def _packets(self, k0: int, k1: int) -> bytes:
        """FIFO bytes of samples k0..k1-1 for the FIFO_EN selection (register order)."""
        data, off = self._rows(k0, k1)
        sel = self.regs[R.FIFO_EN]
        if sel & 0xF8 == 0xF8:
            return data[off : off + (k1 - k0) * R.PACKET_BYTES]
        cols = []
        if sel & R.FIFO_EN_ACCEL:
            cols += [0, 1, 2]
        if sel & R.FIFO_EN_TEMP:
            cols.append(3)
        cols += [4 + i for i, bit in enumerate((R.FIFO_EN_GX, R.FIFO_EN_GY, R.FIFO_EN_GZ)) if sel & bit]
        i0 = k0 - self._cache_k0
        assert self._cache_rows is not None
        return self._cache_rows[i0 : i0 + (k1 - k0), cols].tobytes()

    def _update(self) -> None:
        """Take every sample due by now: data registers and FIFO (vectorised)."""
        t_now = self._motion_time_s(self._now_ns())
        if t_now < self._next_due_t or self._sleeping:
            return
        k_last = self._k_r - 1 + int(np.floor((t_now - self._t_r) / self._period_s + 1e-9))
        k_first = self._k_next
        if k_last < k_first:
            return
        m = k_last - k_first + 1
        self._k_next = k_last + 1
        self._next_due_t = float(self._sample_time_s(self._k_next))
        fifo_on = self._fifo_active()
        lo = max(k_first, k_last - R.FIFO_SIZE_BYTES // 2) if fifo_on else k_last
        data, off = self._rows(lo, k_last + 1)  # one block covers the FIFO range and the latest
        off += (k_last - lo) * R.PACKET_BYTES
        self._latest = data[off : off + R.PACKET_BYTES]
        self._int_status |= R.INT_RAW_DATA_RDY
        if not fifo_on:
            return
        if self._origin_pending:
            self._origin_k, self._origin_pending = k_first, False
        self._fifo_pushed += m
        sel = self.regs[R.FIFO_EN] & 0xF8
        pkt = 2 * bin(sel).count("1") + (4 if sel & R.FIFO_EN_ACCEL else 0)
        cap = R.FIFO_SIZE_BYTES
        fifo = self._fifo
        if self.regs[R.CONFIG] & R.CONFIG_FIFO_MODE and self.honours_fifo_mode:  # keep old data
            room = cap - len(fifo)
            n_fit = min(m, -(-room // pkt)) if room > 0 else 0
            if n_fit:
                fifo += self._packets(k_first, k_first + n_fit)[:room]
            if m * pkt > room:
                self._int_status |= R.INT_FIFO_OFLOW
                self.fifo_bytes_dropped += m * pkt - max(room, 0)
        else:  # drop the oldest bytes
            n_keep = min(m, cap // pkt + 1)
            fifo += self._packets(k_last + 1 - n_keep, k_last + 1)
            total = len(fifo) - n_keep * pkt + m * pkt
            if len(fifo) > cap:
                del fifo[: len(fifo) - cap]
            if total > cap:
                self._int_status |= R.INT_FIFO_OFLOW
                self.fifo_bytes_dropped += total - cap
        if fifo:
            self._fifo_last = fifo[-1]

    def _fifo_pop(self, n: int) -> bytes:
        fifo = self._fifo
        k = min(n, len(fifo))
        out = bytes(fifo[:k])
        del fifo[:k]
        if k:
            self._fifo_last = out[-1]
        if k < n:  # reading an empty FIFO repeats the last byte
            out += bytes([self._fifo_last]) * (n - k)
        return out

    # ================================================================ MPU register file
    def _mpu_read(self, reg: int, n: int) -> bytes:
        self._update()
        out = bytearray(n)
        r = reg & 0x7F
        for i in range(n):
            if r == R.FIFO_R_W:  # no auto-increment past the FIFO port
                out[i:] = self._fifo_pop(n - i)
                break
            out[i] = self._mpu_read_byte(r)
            r = (r + 1) & 0x7F
        return bytes(out)

    def _mpu_read_byte(self, r: int) -> int:
        if R.ACCEL_XOUT_H <= r < R.ACCEL_XOUT_H + 14:
            return self._latest[r - R.ACCEL_XOUT_H]
        if r == R.INT_STATUS:
            v = self._int_status
            self._int_status = 0
            return v
        if r == R.FIFO_COUNTH:
            self._count_latch = len(self._fifo)
            return (self._count_latch >> 8) & 0x1F
        if r == R.FIFO_COUNTL:
            c = self._count_latch if self._count_latch is not None else len(self._fifo)
            self._count_latch = None
            return c & 0xFF
        return self.regs[r]

    def _mpu_write(self, reg: int, data: bytes) -> None:
        self._update()
        r = reg & 0x7F
        for v in data:
            self._mpu_write_byte(r, v & 0xFF)
            if r != R.FIFO_R_W:
                r = (r + 1) & 0x7F

    def _mpu_write_byte(self, r: int, v: int) -> None:
        t_now = self._motion_time_s(self._now_ns())
        if r == R.PWR_MGMT_1:
            if v & R.PWR_H_RESET:
                self._power_on_reset()
                return
            was_sleeping = self._sleeping
            self.regs[r] = v
            if bool(v & R.PWR_SLEEP) != was_sleeping:
                self._rebase(t_now)
            return
        if r == R.USER_CTRL:
            was_on = bool(self.regs[R.USER_CTRL] & R.USER_FIFO_EN)
            if v & R.USER_FIFO_RST:
                self._fifo.clear()
                self._count_latch = None
            if v & R.USER_FIFO_EN and not was_on:
                self._origin_pending = True
            self.regs[r] = v & ~(R.USER_FIFO_RST | R.USER_I2C_MST_RST | R.USER_SIG_COND_RST)
            return
        if r in (R.SMPLRT_DIV, R.CONFIG, R.GYRO_CONFIG, R.ACCEL_CONFIG, R.ACCEL_CONFIG2):
            self.regs[r] = v
            self._rebase(t_now)
            return
        if r == R.FIFO_R_W:
            if len(self._fifo) < R.FIFO_SIZE_BYTES:
                self._fifo.append(v)
            return
        if r in (R.INT_STATUS, R.WHO_AM_I, R.FIFO_COUNTH, R.FIFO_COUNTL) or (
            R.ACCEL_XOUT_H <= r < R.ACCEL_XOUT_H + 14
        ):
            return  # read-only
        self.regs[r] = v

    # ================================================================ AK8963
    def _ak_reset(self) -> None:
        self.ak_regs = bytearray(0x13)
        self.ak_regs[R.AK_WIA] = R.AK_WIA_VALUE
        self.ak_regs[R.AK_INFO] = 0x9A
        self._ak_mode = R.AK_MODE_POWER_DOWN
        self._ak_t_mode = 0.0
        self._ak_m_done = -1
        self._ak_locked = False
        self._ak_cache: tuple[int, bytes, list[int]] | None = None
        self.mag_measurements = 0

    def _ak_present(self) -> bool:
        return (
            self.has_magnetometer
            and bool(self.regs[R.INT_PIN_CFG] & R.INT_PIN_BYPASS_EN)
            and not self.regs[R.USER_CTRL] & R.USER_I2C_MST_EN
        )

    def _ak_update(self) -> None:
        mode = self._ak_mode
        if mode not in (R.AK_MODE_CONT_8HZ, R.AK_MODE_CONT_100HZ, R.AK_MODE_SINGLE) or self._ak_locked:
            return
        t = self._motion_time_s(self._now_ns())
        if mode == R.AK_MODE_SINGLE:
            period = 0.0072
            m_last = 0 if t >= self._ak_t_mode + period else -1
        else:
            period = 1.0 / R.AK_MODE_RATE_HZ[mode]
            m_last = int(np.floor((t - self._ak_t_mode) / period + 1e-9)) - 1
        if m_last <= self._ak_m_done:
            return
        st1 = self.ak_regs[R.AK_ST1]
        if st1 & R.AK_ST1_DRDY or m_last - self._ak_m_done > 1:
            st1 |= R.AK_ST1_DOR
        self._ak_m_done = m_last
        bits16 = bool(self.ak_regs[R.AK_CNTL1] & R.AK_CNTL1_BIT_16)
        c = self._ak_cache
        if c is None or not c[0] <= m_last < c[0] + len(c[2]):
            # a block of measurements ahead; noise keyed by the measurement time in ms (reproducible)
            m = np.arange(m_last, m_last + (1 if mode == R.AK_MODE_SINGLE else 256))
            t_meas = self._ak_t_mode + (m + 1) * period
            counts, hofl = self.model.mag_sample(
                t_meas, np.round(t_meas * 1000.0).astype(np.int64), bits16=bits16
            )
            st2 = np.where(hofl, R.AK_ST2_HOFL, 0) | (R.AK_ST2_BITM if bits16 else 0)
            c = self._ak_cache = (m_last, counts.astype("<i2").tobytes(), st2.tolist())
        i = m_last - c[0]
        self.ak_regs[R.AK_HXL : R.AK_HXL + 6] = c[1][6 * i : 6 * i + 6]
        self.ak_regs[R.AK_ST2] = c[2][i]
        self.ak_regs[R.AK_ST1] = st1 | R.AK_ST1_DRDY
        self.mag_measurements += 1
        if mode == R.AK_MODE_SINGLE:
            self._ak_mode = R.AK_MODE_POWER_DOWN
            self.ak_regs[R.AK_CNTL1] &= 0xF0

    def _ak_read(self, reg: int, n: int) -> bytes:
        self._ak_update()
        out = bytearray(n)
        r = reg
        for i in range(n):
            if R.AK_HXL <= r < R.AK_ST2:
                v = self.ak_regs[r]
                self._ak_locked = True
            elif r == R.AK_ST2:
                v = self.ak_regs[r]
                self._ak_locked = False
                self.ak_regs[R.AK_ST1] &= ~(R.AK_ST1_DRDY | R.AK_ST1_DOR) & 0xFF
            elif R.AK_ASAX <= r <= R.AK_ASAX + 2:
                v = self.model.mag_asa[r - R.AK_ASAX] if self._ak_mode == R.AK_MODE_FUSE_ROM else 0
            elif r < len(self.ak_regs):
                v = self.ak_regs[r]
            else:
                v = 0
            out[i] = v
            r += 1
            if r == 0x0D:
                r = 0x00
            elif r == 0x13:
                r = 0x10
        return bytes(out)

    def _ak_write(self, reg: int, data: bytes) -> None:
        self._ak_update()
        r = reg
        for v in data:
            if r == R.AK_CNTL1:
                self.ak_regs[r] = v
                self._ak_mode = v & 0x0F
                self._ak_t_mode = self._motion_time_s(self._now_ns())
                self._ak_m_done = -1
                self._ak_locked = False
                self._ak_cache = None
            elif r == R.AK_CNTL2:
                if v & R.AK_CNTL2_SRST:
                    self._ak_reset()
            elif r == R.AK_ASTC:
                self.ak_regs[r] = v & 0x40
            r += 1

    # ================================================================ bus transactions
    def _inject(self, addr: int, fifo_read_n: int = 0) -> None:
        self.transactions += 1
        if self.i2c_error_rate > 0.0 and self._err_rng.random() < self.i2c_error_rate:
            self.errors_injected += 1
            if self._err_rng.random() < 0.5:
                raise OSError(_errno.EREMOTEIO, "Remote I/O error")
            if fifo_read_n and self.error_consumes_fifo:
                self._update()
                self._fifo_pop(fifo_read_n)
            raise OSError(_errno.EIO, "Input/output error")

    def _present(self, addr: int) -> bool:
        return addr == self.address or (addr == R.AK8963_ADDRESS and self._ak_present())

    def _read(self, addr: int, reg: int, n: int, inject: bool = True) -> bytes:
        if not self._present(addr):
            raise _nak()
        if inject:
            self._inject(addr, n if (addr == self.address and reg == R.FIFO_R_W) else 0)
        self._ptr[addr] = reg
        if addr == self.address:
            return self._mpu_read(reg, n)
        return self._ak_read(reg, n)

    def _write(self, addr: int, reg: int, data: bytes, inject: bool = True) -> None:
        if not self._present(addr):
            raise _nak()
        if inject:
            self._inject(addr)
        self._ptr[addr] = reg
        if addr == self.address:
            self._mpu_write(reg, data)
        else:
            self._ak_write(reg, data)

    # ---- smbus2.SMBus surface ----
    @property
    def funcs(self) -> int:
        """I2C_FUNCS mask like smbus2.SMBus.funcs (I2C bit only with i2c_rdwr support)."""
        return _I2C_FUNC_SMBUS_EMUL | (_I2C_FUNC_I2C if self.support_i2c_rdwr else 0)

    fd = None
    force = False

    def open(self, bus=None) -> None:
        return None

    def close(self) -> None:
        return None

    def __enter__(self) -> EmulatedMpu9250:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._read(i2c_addr, register, 1)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._write(i2c_addr, register, bytes([value & 0xFF]))

    def read_word_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        """SMBus word: little-endian (first byte is the low byte)."""
        b = self._read(i2c_addr, register, 2)
        return b[0] | (b[1] << 8)

    def write_word_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._write(i2c_addr, register, bytes([value & 0xFF, (value >> 8) & 0xFF]))

    def write_quick(self, i2c_addr: int, force: bool | None = None) -> None:
        """Address-only probe: NAK (OSError 121) when nothing answers at i2c_addr."""
        if not self._present(i2c_addr):
            raise _nak()
        self._inject(i2c_addr)

    def read_byte(self, i2c_addr: int, force: bool | None = None) -> int:
        return self._read(i2c_addr, self._ptr.get(i2c_addr, 0), 1)[0]

    def write_byte(self, i2c_addr: int, value: int, force: bool | None = None) -> None:
        """Sets the register pointer (a one-byte write)."""
        if not self._present(i2c_addr):
            raise _nak()
        self._inject(i2c_addr)
        self._ptr[i2c_addr] = value & 0xFF

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if length > 32:
            raise ValueError("Desired block length over 32 bytes")
        return list(self._read(i2c_addr, register, length))

    def write_i2c_block_data(
        self, i2c_addr: int, register: int, data: list[int], force: bool | None = None
    ) -> None:
        if len(data) > 32:
            raise ValueError("Data length cannot exceed 32 bytes")
        self._write(i2c_addr, register, bytes(int(v) & 0xFF for v in data))

    def i2c_rdwr(self, *i2c_msgs) -> None:
        """Combined transfer of smbus2.i2c_msg messages: a write sets the register pointer (first
        byte) and writes the rest; a read fills the message buffer from the pointer. One injected
        error per call (before any effect, except an errno-5 FIFO read, see class doc)."""
        if not self.support_i2c_rdwr:
            raise OSError(_errno.EOPNOTSUPP, "Operation not supported")
        msgs = [(int(m.addr), bool(m.flags & 0x0001), int(m.len), m) for m in i2c_msgs]
        ptr = dict(self._ptr)
        fifo_n = 0
        for addr, rd, n, m in msgs:
            if not self._present(addr):
                raise _nak()
            if rd:
                fifo_n += n if (addr == self.address and ptr.get(addr) == R.FIFO_R_W) else 0
            elif n:
                ptr[addr] = ctypes.string_at(m.buf, 1)[0]
        self._inject(msgs[0][0] if msgs else self.address, fifo_n)
        for addr, rd, n, m in msgs:
            if rd:
                data = self._read(addr, self._ptr.get(addr, 0), n, inject=False)
                ctypes.memmove(m.buf, data, n)
            elif n:
                raw = ctypes.string_at(m.buf, n)
                self._ptr[addr] = raw[0]
                if n > 1:
                    self._write(addr, raw[0], raw[1:], inject=False)

    # ================================================================ test / simulation helpers
    def inject_fifo_glitch(self, drop_bytes: int = 1) -> None:
        """Lose ``drop_bytes`` bytes from the head of the FIFO (a spurious read): misaligned packets."""
        self._update()
        self._fifo_pop(min(int(drop_bytes), len(self._fifo)))

    @property
    def fifo_count(self) -> int:
        """Bytes in the FIFO now (after taking due samples)."""
        self._update()
        return len(self._fifo)

    @property
    def fifo_samples_pushed(self) -> int:
        """Samples that entered the FIFO since power-on (including ones later dropped by overflow)."""
        self._update()
        return self._fifo_pushed

    @property
    def samples_taken(self) -> int:
        """Samples the chip has taken since power-on (global index of the next one)."""
        self._update()
        return self._k_next

    @property
    def stream_origin_index(self) -> int | None:
        """Global index of the first sample pushed into the FIFO after it was last enabled (the
        driver's sample index 0), or None before that."""
        return self._origin_k

    def motion_time_s(self, session_t_s: np.ndarray) -> np.ndarray:
        """True (motion) time of session samples from their sensor time index / ODR (s)."""
        if self._origin_k is None:
            raise DeviceError("the emulated chip's FIFO stream has not started (call start() and read)")
        i = np.asarray(session_t_s, float) * self._odr_hz
        return self._sample_time_s(self._origin_k + i)

    def session_time_s(self, motion_t_s: np.ndarray) -> np.ndarray:
        """Inverse of motion_time_s: sensor time (index / ODR) of a true time (s)."""
        if self._origin_k is None:
            raise DeviceError("the emulated chip's FIFO stream has not started (call start() and read)")
        t = np.asarray(motion_t_s, float)
        i = (t - self._t_r) / self._period_s - 1.0 + self._k_r - self._origin_k
        return i / self._odr_hz

    def truth_for_session(self, session_t_s: np.ndarray) -> Truth:
        """Truth evaluated at the real times of session samples, reported on the session time axis."""
        t_sess = np.asarray(session_t_s, float).reshape(-1)
        tr = self.model.truth(self.motion_time_s(t_sess))
        tr.t_s = t_sess
        return tr
