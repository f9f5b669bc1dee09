"""Device identity: which physical sensor a session (or a calibration) came from.

An MPU-9250 has no factory serial number readable over I2C: WHO_AM_I (0x71 MPU-9250, 0x73
MPU-9255, 0x70 MPU-6500) and the AK8963's WIA (0x48) name the *kind* of chip, not the unit. The
key therefore combines what the chip says with where it sits and what the user calls it:

    DeviceKey = (WHO_AM_I, AK8963 WIA, user serial/name, I2C bus, I2C address, host)

``id`` is the name used to group a fleet: the user serial when given (it must then be unique in
the fleet), else ``host/bus/0xADDR`` (one sensor per bus address per computer). ``conflicts``
lists the facts two keys disagree on; unknown facts (None / '') never conflict, so files
recorded before device keys existed still match.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import Any

from accellog.core.errors import InputError


@dataclass(frozen=True)
class DeviceKey:
    """What identifies one physical sensor (see module docstring)."""

    who_am_i: int | None = None
    """WHO_AM_I register (0x75) of the MPU (None: not read, e.g. imported data)."""
    ak8963_wia: int | None = None
    """WIA register of the AK8963 magnetometer (0x48), None when the magnetometer was not read."""
    serial: str = ""
    """User-given serial or name (accellog record/simulate --serial)."""
    i2c_bus: str = ""
    """Bus the chip was read on (e.g. '/dev/i2c-1', 'emulator')."""
    i2c_address: int | None = None
    """7-bit I2C address (0x68 or 0x69)."""
    host: str = ""
    """Host name of the computer that recorded."""

    @property
    def id(self) -> str:
        """Fleet grouping name: the serial, else 'host/bus/0xADDR', else 'unknown'."""
        if self.serial:
            return self.serial
        parts = [self.host, self.i2c_bus, "" if self.i2c_address is None else f"0x{self.i2c_address:02X}"]
        return "/".join(p for p in parts if p) or "unknown"

    @property
    def known(self) -> bool:
        """True when the key names a unit (a serial, or host + address), not only a chip kind."""
        return bool(self.serial) or (bool(self.host) and self.i2c_address is not None)

    def conflicts(self, other: DeviceKey) -> list[str]:
        """Facts that differ between two keys ('serial IMU-1 != IMU-2', ...); unknown facts never differ.
        The location (bus, address, host) is compared only when neither key has a serial: a named
        sensor may move to another computer."""
        names = ["who_am_i", "ak8963_wia", "serial"]
        if not (self.serial or other.serial):
            names += ["i2c_bus", "i2c_address", "host"]
        out = []
        for n in names:
            a, b = getattr(self, n), getattr(other, n)
            if a in (None, "") or b in (None, ""):
                continue
            if a != b:
                out.append(f"{n} {_fmt(n, a)} != {_fmt(n, b)}")
        return out

    def describe(self) -> str:
        """One line: 'IMU-0001 (WHO_AM_I 0x71, AK8963 0x48, emulator 0x68 on host)'."""
        facts = []
        if self.who_am_i is not None:
            facts.append(f"WHO_AM_I 0x{self.who_am_i:02X}")
        if self.ak8963_wia is not None:
            facts.append(f"AK8963 0x{self.ak8963_wia:02X}")
        where = " ".join(
            p for p in (self.i2c_bus, "" if self.i2c_address is None else f"0x{self.i2c_address:02X}") if p
        )
        if where:
            facts.append(where + (f" on {self.host}" if self.host else ""))
        elif self.host:
            facts.append(f"on {self.host}")
        return self.id + (f" ({', '.join(facts)})" if facts else "")

    def to_dict(self) -> dict[str, Any]:
        return {"id": self.id, **dataclasses.asdict(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> DeviceKey:
        """Inverse of to_dict (unknown keys ignored; None/{} gives the empty key)."""
        d = d or {}
        kw: dict[str, Any] = {}
        for f in dataclasses.fields(cls):
            if f.name in d and d[f.name] is not None:
                kw[f.name] = int(d[f.name]) if f.name in _INT_FIELDS else str(d[f.name])
        return cls(**kw)

    @classmethod
    def from_meta(cls, meta: Any) -> DeviceKey:
        """The key of a SessionMeta (fields of the same names)."""
        kw: dict[str, Any] = {f.name: getattr(meta, f.name, f.default) for f in dataclasses.fields(cls)}
        return cls(**kw)


_INT_FIELDS = {"who_am_i", "ak8963_wia", "i2c_address"}
_SERIAL_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.:-]{0,63}$")


def _fmt(name: str, v: Any) -> str:
    return f"0x{v:02X}" if name in _INT_FIELDS else str(v)


def check_serial(serial: str) -> str:
    """A serial usable as a file/directory name (letters, digits, '_.:-', <= 64); InputError otherwise."""
    if serial and not _SERIAL_RE.match(serial):
        raise InputError(f"serial {serial!r}: use letters, digits and _ . : - (at most 64 characters)")
    return serial
