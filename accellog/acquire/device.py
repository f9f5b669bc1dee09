"""Device set-up shared by `record` and `simulate`: open a bus (real smbus2 or the emulated chip), probe, configure.

rate_hz = 1000 / (1 + SMPLRT_DIV)      (DLPF on: the chip's internal 1 kHz sample clock)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from accellog.acquire.driver import ChipInfo, DriverConfig, Mpu9250
from accellog.core.errors import DeviceError, InputError


def sample_rate_div(rate_hz: float) -> int:
    """SMPLRT_DIV N for an output data rate of 1000/(1+N) Hz; InputError for rates the chip cannot make."""
    if not rate_hz > 0:
        raise InputError(f"--rate {rate_hz:g}: must be positive; the chip supports 1000/(1+N) Hz, N = 0..255")
    div = 1000.0 / rate_hz - 1
    if abs(div - round(div)) > 1e-9 or not 0 <= round(div) <= 255:
        raise InputError(f"--rate {rate_hz:g}: the chip supports 1000/(1+N) Hz, N = 0..255")
    return round(div)


def parse_address(address: str | int) -> int:
    """I2C address from '0x68' / '104' / 0x68; InputError otherwise."""
    if isinstance(address, int):
        return address
    try:
        return int(address, 0)
    except ValueError:
        raise InputError(f"--address {address!r} is not a number (use 0x68 or 0x69)") from None


def open_hardware_bus(bus: int):
    """smbus2.SMBus on /dev/i2c-<bus>; DeviceError (one line) if it cannot be opened."""
    import smbus2

    try:
        return smbus2.SMBus(bus)
    except (OSError, FileNotFoundError, PermissionError) as exc:
        raise DeviceError(f"cannot open /dev/i2c-{bus}: {exc.strerror or exc}") from None


@dataclass
class ConfiguredDevice:
    """A probed, configured driver and what it reported."""

    driver: Mpu9250
    info: ChipInfo
    config: DriverConfig
    read_mag: bool
    notes: list[str]


def configure_device(
    bus: Any,
    *,
    address: int = 0x68,
    clock_ns: Callable[[], int] | None = None,
    sleep: Callable[[float], None] | None = None,
    accel_range_g: int = 2,
    gyro_range_dps: int = 250,
    dlpf_cfg: int = 3,
    sample_rate_div: int = 0,
    mag: bool = True,
) -> ConfiguredDevice:
    """Probe the chip on ``bus`` (smbus2-like), configure it and enable the AK8963 when asked and present.

    clock_ns / sleep: the clock the driver stamps reads with and waits on (a simulated clock's, or
    the host's by default)."""
    driver = Mpu9250(bus, address=address, clock_ns=clock_ns, sleep=sleep)
    info = driver.probe()
    cfg = driver.configure(
        accel_range_g=accel_range_g,
        gyro_range_dps=gyro_range_dps,
        dlpf_cfg=dlpf_cfg,
        a_dlpf_cfg=dlpf_cfg,
        sample_rate_div=sample_rate_div,
    )
    notes = []
    read_mag = mag and info.has_magnetometer
    if mag and not info.has_magnetometer:
        notes.append(f"{info.model} (WHO_AM_I=0x{info.who_am_i:02X}) has no magnetometer: not recorded")
    if read_mag:
        driver.enable_magnetometer()
    return ConfiguredDevice(driver, info, cfg, read_mag, notes)
