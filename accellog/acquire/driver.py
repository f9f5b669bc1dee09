"""MPU-9250 driver over any object with the smbus2 ``SMBus`` method surface (real bus or emulator).

Reads go through the 512-byte FIFO in 14-byte packets (accel xyz, temp, gyro xyz; big-endian
int16). Every sample gets an index in the session's sample stream and a sensor time

    t_ns = index * 1e9 / ODR

(the chip's own clock: a chip whose oscillator runs slow still gets t = index / ODR, which is what
the recorded data are). Samples that never reach the host are accounted for, never hidden: on a
FIFO overflow, a misaligned count, or a bus error that outlives ``max_retries`` the driver resets
the FIFO, estimates the lost samples from the host clock,

    lost = round((t_host_reset - t_host_last_count) * rate_est) - received_since_then

(rate_est = the chip's measured rate over the last clean stretch >= 2 s, else the nominal ODR),
records an ``Event`` ('fifo_overflow' / 'misaligned' / 'i2c_error') with ``lost_samples`` and
advances the index by that estimate, so later timestamps stay right (a gap in ``sample_index``).
Retried transfers (errno 121 NAK, 5 EIO) are recorded as 'retry' events.

The FIFO runs with CONFIG.FIFO_MODE = 1 (register map §4.6: when full, new writes are dropped, the
oldest data kept). Its head therefore stays on a packet boundary, and an overflow costs only the
samples that did not fit: the whole packets in it are read before the reset. (FIFO_MODE = 0 drops
the oldest *bytes*, so the head is misaligned and the whole FIFO must be thrown away: a read 45 ms
late at 1 kHz lost 45 samples, now 9; bench_record_load.py.)

FIFO bursts use ``i2c_rdwr`` (one transfer, no 32-byte limit); if the adapter lacks it (no
``i2c_rdwr`` attribute, I2C_FUNCS without the I2C bit, EOPNOTSUPP) the driver falls back to
28-byte ``read_i2c_block_data`` reads at FIFO_R_W (two whole packets per transfer).
"""

from __future__ import annotations

import errno as _errno
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from accellog.acquire import registers as R
from accellog.core.errors import DeviceError, InputError
from accellog.core.session import Event
from accellog.core.units import ACCEL_LSB_PER_G, GYRO_LSB_PER_DPS, MAG_UT_PER_LSB_14BIT, MAG_UT_PER_LSB_16BIT

_RETRY_ERRNOS = (_errno.EREMOTEIO, _errno.EIO)  # 121 NAK, 5 bus error
KEPT_TEMP_TOL_COUNTS = 64
"""Largest temperature step (counts; 333.87 per degC: 0.19 degC) between the last packet read and
the packets a full FIFO kept (about 40-100 ms later): the sensor's noise is a few counts, a
misaligned packet's 'temperature' is made of other fields' bytes."""
_UNSUPPORTED_ERRNOS = (_errno.EOPNOTSUPP, _errno.ENOTTY, _errno.ENOSYS)
_FALLBACK_CHUNK_PACKETS = 2  # 28 bytes <= 32 (SMBus block limit), whole packets per transfer
_CHIP_NAMES = {
    R.WHO_AM_I_MPU9250: ("MPU-9250", True),
    R.WHO_AM_I_MPU9255: ("MPU-9255", True),
    R.WHO_AM_I_MPU6500: ("MPU-6500", False),
}
_KNOWN_OTHERS = {
    0x68: "an MPU-6050/9150",
    0x74: "an MPU-6515",
    0x75: "an unidentified MPU-9250 clone without magnetometer",
    0x00: "nothing sensible (0x00: device held in reset or bus stuck low)",
    0xFF: "nothing sensible (0xFF: no device driving the bus)",
}


@dataclass(frozen=True)
class ChipInfo:
    """What ``probe`` found: WHO_AM_I byte, model name, magnetometer present, warning (clones)."""

    who_am_i: int
    model: str
    has_magnetometer: bool
    warning: str = ""


@dataclass(frozen=True)
class DriverConfig:
    """Configuration written by ``configure`` (ODR in Hz, bandwidths in Hz, sensitivities in LSB)."""

    sample_rate_hz: float
    accel_range_g: int
    gyro_range_dps: int
    accel_lsb_per_g: float
    gyro_lsb_per_dps: float
    dlpf_cfg: int
    a_dlpf_cfg: int
    sample_rate_div: int
    accel_bandwidth_hz: float
    gyro_bandwidth_hz: float
    packet_bytes: int = R.PACKET_BYTES


@dataclass
class FifoBatch:
    """Samples of one ``read``: indices first_index .. first_index + n - 1 of the session stream.

    t_ns: (n,) int64 sensor time = index * 1e9 / ODR (ns). accel/gyro_counts: (n,3) int16 raw.
    temp_counts: (n,) int16 raw (degC = counts / 333.87 + 21). host_time_ns: host clock after the
    read, ns since ``start``. events: everything that happened since the previous batch (gaps with
    lost_samples, retries, errors).
    """

    first_index: int
    t_ns: np.ndarray
    accel_counts: np.ndarray
    temp_counts: np.ndarray
    gyro_counts: np.ndarray
    host_time_ns: int
    events: list[Event] = field(default_factory=list)

    @property
    def n(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class MagReading:
    """One AK8963 sample: raw counts (3,) int16 in AK8963 axes, uT = counts * asa_factor * ut_per_lsb.

    t_ns: estimated sensor time (ns since ``start``) of the read; host_time_ns: host clock (ns since
    ``start``). st1/st2: status bytes; hofl: magnetic overflow (|X|+|Y|+|Z| >= 4912 uT, data
    invalid); dor: data overrun (a measurement was skipped since the previous read).
    """

    t_ns: int
    host_time_ns: int
    counts: np.ndarray
    uT: np.ndarray
    asa_factor: np.ndarray
    ut_per_lsb: float
    st1: int
    st2: int
    hofl: bool
    dor: bool


class _BusFailure(Exception):
    """A transfer still failing after max_retries (internal)."""

    def __init__(self, what: str, exc: OSError) -> None:
        super().__init__(f"{what}: errno {exc.errno} ({exc.strerror or exc})")
        self.errno = exc.errno


class _SkipRead(Exception):
    """The FIFO could not be reset after a failure: read nothing this time (internal)."""


class _FifoLost(Exception):
    """A FIFO read failed part way (internal): ``good`` holds the whole packets read before it."""

    def __init__(self, good: bytes, why: str) -> None:
        super().__init__(why)
        self.good = good


class Mpu9250:
    """Driver for an MPU-9250 (or 9255 / 6500) on ``bus`` (smbus2.SMBus or anything with its methods).

    clock_ns: host clock in ns (default ``time.monotonic_ns``); pass the emulator's clock in
    simulation. sleep: how to wait (s); default the clock's own ``sleep`` when clock_ns is a bound
    method of an object that has one (SimClock, RealClock), else ``time.sleep``.
    """

    def __init__(
        self,
        bus,
        address: int = R.MPU_ADDRESS,
        *,
        clock_ns: Callable[[], int] | None = None,
        max_retries: int = 3,
        sleep: Callable[[float], None] | None = None,
    ) -> None:
        self.bus = bus
        self.address = int(address)
        self.clock_ns = clock_ns or time.monotonic_ns
        if sleep is None:
            owner = getattr(clock_ns, "__self__", None)
            sleep = getattr(owner, "sleep", None) if owner is not None else None
        self.sleep = sleep or time.sleep
        self.max_retries = int(max_retries)
        self.info: ChipInfo | None = None
        self.config: DriverConfig | None = None
        self._pending: list[Event] = []
        self._started = False
        self._last_temp: int | None = None  # temperature count of the last packet read
        self._mag_asa: np.ndarray | None = None
        self.ak8963_wia: int | None = None
        """AK8963 WIA read by enable_magnetometer (device identity)."""
        funcs = getattr(bus, "funcs", None)
        self._use_rdwr = hasattr(bus, "i2c_rdwr") and (not isinstance(funcs, int) or bool(funcs & 0x1))
        self.start_host_ns = 0
        self._next_index = 0
        self.retries = 0
        self.lost_samples = 0

    # ================================================================ low-level transfers
    def _t_sensor_s(self, index: int) -> float:
        return index / self.config.sample_rate_hz if self.config else 0.0

    def _retry(self, what: str, fn: Callable, *args):
        """Call fn(*args); retry errno 121/5 up to max_retries (a 'retry' event each)."""
        attempt = 0
        while True:
            try:
                return fn(*args)
            except OSError as exc:
                if exc.errno not in _RETRY_ERRNOS:
                    raise DeviceError(
                        f"I2C {what} at 0x{self.address:02X} failed: errno {exc.errno} ({exc.strerror or exc})"
                    ) from None
                if attempt >= self.max_retries:
                    raise _BusFailure(what, exc) from None
                attempt += 1
                self.retries += 1
                self._pending.append(
                    Event(
                        self._t_sensor_s(self._next_index),
                        "retry",
                        f"{what}: errno {exc.errno} ({exc.strerror or exc}), attempt {attempt + 1}",
                        self._next_index,
                    )
                )

    def _device_error(self, exc: _BusFailure) -> DeviceError:
        hint = (
            "no device answers (NAK): check wiring, power, pull-ups and the address (0x68/0x69)"
            if exc.errno == _errno.EREMOTEIO
            else "bus error: check wiring, pull-ups and cable length"
        )
        return DeviceError(
            f"I2C at 0x{self.address:02X}: {exc} after {self.max_retries + 1} attempts; {hint}"
        )

    def _rd(self, reg: int, addr: int | None = None) -> int:
        a = self.address if addr is None else addr
        return int(self._retry(f"read reg 0x{reg:02X}", self.bus.read_byte_data, a, reg))

    def _rd_block(self, reg: int, n: int, addr: int | None = None) -> bytes:
        a = self.address if addr is None else addr
        return bytes(self._retry(f"read {n} B at 0x{reg:02X}", self.bus.read_i2c_block_data, a, reg, n))

    def _wr(self, reg: int, value: int, addr: int | None = None) -> None:
        a = self.address if addr is None else addr
        self._retry(f"write reg 0x{reg:02X}", self.bus.write_byte_data, a, reg, value & 0xFF)

    def _setup(self, fn: Callable, *args):
        """Run a configuration step; persistent bus failures become a DeviceError."""
        try:
            return fn(*args)
        except _BusFailure as exc:
            raise self._device_error(exc) from None

    # ================================================================ identity and configuration
    def probe(self) -> ChipInfo:
        """Read WHO_AM_I: 0x71 MPU-9250, 0x73 MPU-9255, 0x70 MPU-6500 (no magnetometer, warned);
        anything else raises DeviceError naming what it is."""
        who = self._setup(self._rd, R.WHO_AM_I)
        if who in _CHIP_NAMES:
            name, has_mag = _CHIP_NAMES[who]
            warning = ""
            if not has_mag:
                warning = (
                    f"WHO_AM_I=0x{who:02X}: this is an {name} (accelerometer + gyro only, no AK8963 "
                    "magnetometer); accel/gyro recording works"
                )
                warnings.warn(warning, stacklevel=2)
            self.info = ChipInfo(who, name, has_mag, warning)
            return self.info
        what = _KNOWN_OTHERS.get(who, "an unknown device")
        raise DeviceError(
            f"WHO_AM_I=0x{who:02X} at 0x{self.address:02X}: this is {what}, not an MPU-9250 "
            "(expected 0x71 MPU-9250, 0x73 MPU-9255 or 0x70 MPU-6500)"
        )

    def configure(
        self,
        accel_range_g: int = 2,
        gyro_range_dps: int = 250,
        dlpf_cfg: int = 3,
        a_dlpf_cfg: int = 3,
        sample_rate_div: int = 0,
    ) -> DriverConfig:
        """Reset and wake the chip (PLL clock), set full scales, DLPFs, SMPLRT_DIV and FIFO_EN =
        accel + temp + gyro (14-byte packets). ODR = 1 kHz / (1 + div) for DLPF_CFG 1..6, else 8 kHz.
        Resets the bypass, so call ``enable_magnetometer`` afterwards."""
        if accel_range_g not in R.ACCEL_RANGES_G:
            raise InputError(f"accel range {accel_range_g} g: use 2, 4, 8 or 16")
        if gyro_range_dps not in R.GYRO_RANGES_DPS:
            raise InputError(f"gyro range {gyro_range_dps} deg/s: use 250, 500, 1000 or 2000")
        if not 0 <= dlpf_cfg <= 7 or not 0 <= a_dlpf_cfg <= 7:
            raise InputError(f"DLPF_CFG {dlpf_cfg} / A_DLPFCFG {a_dlpf_cfg}: use 0..7")
        if not 0 <= sample_rate_div <= 255:
            raise InputError(f"SMPLRT_DIV {sample_rate_div}: use 0..255")
        if self.info is None:
            self.probe()
        fs_a = R.ACCEL_RANGES_G.index(accel_range_g)
        fs_g = R.GYRO_RANGES_DPS.index(gyro_range_dps)
        want = {
            R.SMPLRT_DIV: sample_rate_div,
            R.CONFIG: dlpf_cfg | R.CONFIG_FIFO_MODE,  # a full FIFO keeps its oldest packets (module doc)
            R.GYRO_CONFIG: fs_g << R.GYRO_FS_SHIFT,  # FCHOICE_B = 00: DLPF in use
            R.ACCEL_CONFIG: fs_a << R.ACCEL_FS_SHIFT,
            R.ACCEL_CONFIG2: a_dlpf_cfg,
        }

        def steps() -> None:
            self._wr(R.PWR_MGMT_1, R.PWR_H_RESET)
            self.sleep(0.1)
            self._wr(R.PWR_MGMT_1, R.PWR_CLKSEL_PLL)
            self._wr(R.PWR_MGMT_2, 0x00)
            self.sleep(0.05)
            for reg, val in want.items():
                self._wr(reg, val)
            self._wr(R.FIFO_EN, 0x00)
            self._wr(R.USER_CTRL, 0x00)
            self._wr(R.INT_ENABLE, 0x00)
            back = self._rd_block(R.SMPLRT_DIV, 5)
            for i, reg in enumerate(sorted(want)):
                if back[i] != want[reg]:
                    raise DeviceError(
                        f"register 0x{reg:02X} reads 0x{back[i]:02X} after writing 0x{want[reg]:02X}: "
                        "the chip ignores writes (wrong device, or held in reset)"
                    )
            self._wr(R.FIFO_EN, R.FIFO_EN_ACCEL_TEMP_GYRO)

        self._setup(steps)
        self._mag_asa = None
        self._started = False
        self.config = DriverConfig(
            sample_rate_hz=R.sample_rate_hz(dlpf_cfg, fs_g << R.GYRO_FS_SHIFT, sample_rate_div),
            accel_range_g=int(accel_range_g),
            gyro_range_dps=int(gyro_range_dps),
            accel_lsb_per_g=ACCEL_LSB_PER_G[accel_range_g],
            gyro_lsb_per_dps=GYRO_LSB_PER_DPS[gyro_range_dps],
            dlpf_cfg=int(dlpf_cfg),
            a_dlpf_cfg=int(a_dlpf_cfg),
            sample_rate_div=int(sample_rate_div),
            accel_bandwidth_hz=R.accel_bandwidth_hz(a_dlpf_cfg),
            gyro_bandwidth_hz=R.gyro_bandwidth_hz(dlpf_cfg, 0),
        )
        return self.config

    # ================================================================ FIFO stream
    def start(self) -> None:
        """Reset and enable the FIFO; the next sample is index 0 of the session (t = 0)."""
        if self.config is None:
            raise DeviceError("configure() the MPU-9250 before start()")
        ctrl = self._setup(self._rd, R.USER_CTRL) & R.USER_I2C_MST_EN

        def steps() -> None:
            self._wr(R.USER_CTRL, ctrl)
            self._wr(R.USER_CTRL, ctrl | R.USER_FIFO_RST)
            self._rd(R.INT_STATUS)  # clear a stale FIFO_OFLOW
            self._wr(R.USER_CTRL, ctrl | R.USER_FIFO_EN)

        self._setup(steps)
        now = int(self.clock_ns())
        self.start_host_ns = now
        self._next_index = 0
        self._last_count_ns = now
        self._span = (now, 0)
        self._rate_est = self.config.sample_rate_hz
        self._need_reset = False
        self._started = True
        self.lost_samples = 0
        self._last_temp = None

    @property
    def rate_estimate_hz(self) -> float:
        """The chip's sample rate measured against the host clock (nominal until >= 2 s of data)."""
        return self._rate_est

    @property
    def next_index(self) -> int:
        """Index the next sample read will get."""
        return self._next_index

    def _fifo_reset(self) -> None:
        ctrl = self._rd(R.USER_CTRL)
        self._wr(R.USER_CTRL, (ctrl | R.USER_FIFO_EN | R.USER_FIFO_RST) & 0xFF)
        self._rd(R.INT_STATUS)  # a FIFO_OFLOW from before the reset is stale

    def _gap(self, kind: str, detail: str, received: int, events: list[Event]) -> None:
        """Reset the FIFO, account for the samples lost since the last count, advance the index."""
        try:
            self._retry("FIFO reset", self._fifo_reset)
            self._need_reset = False
        except _BusFailure as exc:
            self._need_reset = True
            detail += f"; FIFO reset failed ({exc}), retried next read"
        now = int(self.clock_ns())
        expected = round((now - self._last_count_ns) * 1e-9 * self._rate_est)
        lost = max(0, expected - received)
        idx = self._next_index
        events.append(Event(self._t_sensor_s(idx), kind, detail, idx, lost))
        self._next_index += lost
        self.lost_samples += lost
        self._last_count_ns = now
        self._span = (now, self._next_index)

    def _read_fifo_bytes(self, n_packets: int, count_bytes: int) -> bytes:
        """Read n whole packets in bursts; a failed burst is retried after re-reading the count.

        Raises _FifoLost, holding the packets read before, when a failed burst consumed FIFO bytes or a
        transfer still fails after max_retries.
        """
        pkt = R.PACKET_BYTES
        out = bytearray()
        left = n_packets
        while left:
            k = left if self._use_rdwr else min(left, _FALLBACK_CHUNK_PACKETS)
            attempt = 0
            while True:
                try:
                    out += self._burst(k * pkt)
                    break
                except OSError as exc:
                    if exc.errno not in _RETRY_ERRNOS:
                        raise DeviceError(
                            f"I2C FIFO read failed: errno {exc.errno} ({exc.strerror})"
                        ) from None
                    what = f"FIFO read of {k * pkt} B: errno {exc.errno} ({exc.strerror or exc})"
                    if attempt >= self.max_retries:
                        raise _FifoLost(bytes(out), f"{what} after {attempt + 1} attempts") from None
                    attempt += 1
                    self.retries += 1
                    idx = self._next_index + len(out) // pkt
                    self._pending.append(
                        Event(self._t_sensor_s(idx), "retry", f"{what}, attempt {attempt + 1}", idx)
                    )
                    # did the failed burst take data with it?
                    try:
                        taken = self._fifo_count() < count_bytes - len(out)
                    except _BusFailure as bf:
                        raise _FifoLost(bytes(out), f"{bf} after {self.max_retries + 1} attempts") from None
                    if taken:
                        raise _FifoLost(bytes(out), "a failed FIFO read consumed data") from None
            left -= k
        return bytes(out)

    def _burst(self, n: int) -> bytes:
        if self._use_rdwr:
            from smbus2 import i2c_msg

            wr, rd = i2c_msg.write(self.address, [R.FIFO_R_W]), i2c_msg.read(self.address, n)
            try:
                self.bus.i2c_rdwr(wr, rd)
                return bytes(rd)
            except (NotImplementedError, AttributeError):
                self._use_rdwr = False
            except OSError as exc:
                if exc.errno not in _UNSUPPORTED_ERRNOS:
                    raise
                self._use_rdwr = False
        out = bytearray()
        step = _FALLBACK_CHUNK_PACKETS * R.PACKET_BYTES
        for o in range(0, n, step):
            out += bytes(self.bus.read_i2c_block_data(self.address, R.FIFO_R_W, min(step, n - o)))
        return bytes(out)

    def _read_kept(self, n_packets: int) -> tuple[bytes, str]:
        """(the whole packets a full FIFO kept, why some were dropped or ""). A read that fails part
        way keeps what it got and says why. The packets are kept only when their temperature field
        runs on from the last read's (within KEPT_TEMP_TOL_COUNTS): a chip that ignored FIFO_MODE = 1
        and dropped its oldest bytes leaves a misaligned head, whose temperature field is another
        axis; it is dropped unless that axis happens to read within the tolerance of the temperature
        count (a check that catches the misaligned heads seen in tests, not a proof)."""
        if not n_packets:
            return b"", ""
        why = ""
        try:
            data = self._read_fifo_bytes(n_packets, n_packets * R.PACKET_BYTES)
        except _FifoLost as exc:
            data, why = exc.good, f" (the read failed part way: {exc})"
        if not data:
            return b"", why
        temp = np.frombuffer(data, dtype=">i2").reshape(-1, 7)[:, 3].astype(np.int64)
        ref = temp[0] if self._last_temp is None else self._last_temp
        if np.abs(temp - ref).max() > KEPT_TEMP_TOL_COUNTS:
            return (
                b"",
                why + " (its packets did not continue the last read's temperature: misaligned, dropped)",
            )
        return data, why

    def _fifo_count(self) -> int:
        hi, lo = self._rd_block(R.FIFO_COUNTH, 2)
        return ((hi & 0x1F) << 8) | lo

    def read(self) -> FifoBatch:
        """Drain the FIFO: every whole packet now in it, with indices, sensor times and events."""
        if not self._started or self.config is None:
            raise DeviceError("start() the FIFO before read()")
        events, self._pending = self._pending, []
        pkt = R.PACKET_BYTES
        data = b""
        first = self._next_index
        try:
            if self._need_reset:
                self._gap("i2c_error", "FIFO reset after an earlier bus failure", 0, events)
                if self._need_reset:  # still not reset: its content is already counted as lost
                    raise _SkipRead
            status = self._rd(R.INT_STATUS)
            t_count = int(self.clock_ns())
            count = self._fifo_count()
            if status & R.INT_FIFO_OFLOW or count >= R.FIFO_SIZE_BYTES:
                data, why = self._read_kept(count // pkt)  # the oldest whole packets (FIFO_MODE = 1)
                first = self._next_index
                self._next_index += len(data) // pkt
                detail = f"FIFO overflow (count {count} B): {len(data) // pkt} whole packets kept, reset{why}"
                self._gap("fifo_overflow", detail, len(data) // pkt, events)
            elif count % pkt:
                self._gap("misaligned", f"FIFO count {count} B is not whole packets: reset", 0, events)
            elif count:
                first = self._next_index
                try:
                    data = self._read_fifo_bytes(count // pkt, count)
                except _FifoLost as exc:  # keep the packets read before the failure, then reset
                    data = exc.good
                    self._next_index += len(data) // pkt
                    self._gap("i2c_error", f"{exc}: reset", len(data) // pkt, events)
                else:
                    self._last_count_ns = t_count
                    self._next_index += count // pkt
        except _BusFailure as exc:
            self._gap("i2c_error", f"{exc} after {self.max_retries + 1} attempts", 0, events)
        except _SkipRead:
            pass
        events.extend(self._pending)
        self._pending = []
        n = len(data) // pkt
        if not n:
            first = self._next_index
        rows = np.frombuffer(data, dtype=">i2").reshape(n, 7).astype(np.int16)
        if n:
            self._last_temp = int(rows[-1, 3])
        idx = first + np.arange(n, dtype=np.int64)
        t_ns = np.round(idx * (1e9 / self.config.sample_rate_hz)).astype(np.int64)
        host = int(self.clock_ns())
        self._update_rate()
        return FifoBatch(
            first_index=first,
            t_ns=t_ns,
            accel_counts=rows[:, 0:3],
            temp_counts=rows[:, 3],
            gyro_counts=rows[:, 4:7],
            host_time_ns=host - self.start_host_ns,
            events=events,
        )

    def _update_rate(self) -> None:
        """rate_est = samples / host time over the current gap-free stretch (>= 2 s, within +-10 %)."""
        t0, i0 = self._span
        dt_s = (self._last_count_ns - t0) * 1e-9
        if dt_s >= 2.0:
            r = (self._next_index - i0) / dt_s
            if self.config is None:
                raise RuntimeError("samples counted before the chip was configured")
            nominal = self.config.sample_rate_hz
            if abs(r / nominal - 1.0) < 0.1:
                self._rate_est = r

    # ================================================================ magnetometer
    def enable_magnetometer(self, mode_hz: int = 100) -> np.ndarray:
        """Pass-through to the AK8963 (BYPASS_EN = 1, I2C_MST_EN = 0), check WIA = 0x48, read the
        fuse-ROM ASA bytes, start 16-bit continuous mode at 8 or 100 Hz. Returns the ASA factors
        (ASA - 128) * 0.5 / 128 + 1 (3,)."""
        if mode_hz not in (8, 100):
            raise InputError(f"magnetometer mode {mode_hz} Hz: use 8 or 100")
        if self.info is None:
            self.probe()
        info = self.info
        assert info is not None  # probe() sets it or raises
        if not info.has_magnetometer:
            raise DeviceError(f"{info.model} (WHO_AM_I=0x{info.who_am_i:02X}) has no AK8963 magnetometer")
        ak = R.AK8963_ADDRESS

        def steps() -> np.ndarray:
            ctrl = self._rd(R.USER_CTRL)
            self._wr(R.USER_CTRL, ctrl & ~R.USER_I2C_MST_EN)
            self._wr(R.INT_PIN_CFG, self._rd(R.INT_PIN_CFG) | R.INT_PIN_BYPASS_EN)
            self.sleep(0.01)
            try:
                wia = self._rd(R.AK_WIA, ak)
            except _BusFailure:
                raise DeviceError(
                    "no AK8963 answers at 0x0C with bypass enabled: this board has no magnetometer "
                    f"({info.model} clone reporting WHO_AM_I=0x{info.who_am_i:02X}?)"
                ) from None
            if wia != R.AK_WIA_VALUE:
                raise DeviceError(f"AK8963 WIA=0x{wia:02X} (expected 0x48): not an AK8963 magnetometer")
            self.ak8963_wia = wia
            self._wr(R.AK_CNTL1, R.AK_MODE_POWER_DOWN, ak)
            self.sleep(0.01)
            self._wr(R.AK_CNTL1, R.AK_MODE_FUSE_ROM, ak)
            self.sleep(0.01)
            asa = np.frombuffer(self._rd_block(R.AK_ASAX, 3, ak), np.uint8).astype(float)
            self._wr(R.AK_CNTL1, R.AK_MODE_POWER_DOWN, ak)
            self.sleep(0.01)
            mode = R.AK_MODE_CONT_100HZ if mode_hz == 100 else R.AK_MODE_CONT_8HZ
            self._wr(R.AK_CNTL1, R.AK_CNTL1_BIT_16 | mode, ak)
            return (asa - 128.0) * 0.5 / 128.0 + 1.0

        self._mag_asa = self._setup(steps)
        return self._mag_asa

    def read_mag(self) -> MagReading | None:
        """Read ST1..ST2 (0x02..0x09, one burst; reading ST2 releases the data lock). None when
        ST1.DRDY is clear or the bus fails (an 'i2c_error' event is queued for the next batch)."""
        if self._mag_asa is None:
            raise DeviceError("enable_magnetometer() before read_mag()")
        try:
            raw = self._rd_block(R.AK_ST1, 8, R.AK8963_ADDRESS)
        except _BusFailure as exc:
            self._pending.append(
                Event(
                    self._t_sensor_s(self._next_index), "i2c_error", f"magnetometer: {exc}", self._next_index
                )
            )
            return None
        st1, st2 = raw[0], raw[7]
        if not st1 & R.AK_ST1_DRDY:
            return None
        counts = np.frombuffer(raw[1:7], dtype="<i2").astype(np.int16)
        lsb = MAG_UT_PER_LSB_16BIT if st2 & R.AK_ST2_BITM else MAG_UT_PER_LSB_14BIT
        host = int(self.clock_ns()) - self.start_host_ns
        t_ns = host
        if self._started and self.config is not None:
            since = (int(self.clock_ns()) - self._last_count_ns) * 1e-9 * self._rate_est
            t_ns = round((self._next_index + since) * 1e9 / self.config.sample_rate_hz)
        return MagReading(
            t_ns=int(t_ns),
            host_time_ns=host,
            counts=counts,
            uT=counts * self._mag_asa * lsb,
            asa_factor=self._mag_asa.copy(),
            ut_per_lsb=lsb,
            st1=int(st1),
            st2=int(st2),
            hofl=bool(st2 & R.AK_ST2_HOFL),
            dor=bool(st1 & R.AK_ST1_DOR),
        )
