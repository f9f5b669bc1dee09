"""Kernel-level stand-in: make the real ``smbus2.SMBus(N)`` talk to an emulated chip.

Inside ``with emulated_i2c_bus(chip, bus_number=1):`` the smbus2 module's ``os.open`` /
``os.close`` (for the path /dev/i2c-N only) and its ``ioctl`` (for that file descriptor only)
are replaced, as smbus2's own test suite does. The ioctls are decoded from smbus2's ctypes
structures, exactly as the Linux i2c-dev driver would receive them:

    I2C_FUNCS 0x0705 (c_ulong out), I2C_SLAVE 0x0703 / I2C_SLAVE_FORCE 0x0706 (address),
    I2C_SMBUS 0x0720 (i2c_smbus_ioctl_data: read_write, command, size 0/1/2/3/8, data union),
    I2C_RDWR 0x0707 (i2c_rdwr_ioctl_data: msgs[nmsgs]), I2C_PEC 0x0708 (ignored)

so all of smbus2's own code (argument checks, the 32-byte block limit, i2c_msg buffers) runs
unchanged. Every other file and descriptor goes to the real ``os`` / ``fcntl``.
"""

from __future__ import annotations

import errno as _errno
import itertools
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

I2C_SLAVE = 0x0703
I2C_FUNCS = 0x0705
I2C_SLAVE_FORCE = 0x0706
I2C_RDWR = 0x0707
I2C_PEC = 0x0708
I2C_SMBUS = 0x0720
_SMBUS_READ = 1
_QUICK, _BYTE, _BYTE_DATA, _WORD_DATA, _I2C_BLOCK_DATA = 0, 1, 2, 3, 8

_fd_counter = itertools.count(0x7E000)


class _OsShim:
    """Forwards everything to the wrapped ``os`` module except open/close of the emulated bus."""

    def __init__(self, real_os: Any, path: str, fd: int) -> None:
        self._real, self._path, self._fd = real_os, path, fd

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)

    def open(self, path, flags, *args, **kwargs):
        if str(path) == self._path:
            return self._fd
        return self._real.open(path, flags, *args, **kwargs)

    def close(self, fd):
        if fd == self._fd:
            return None
        return self._real.close(fd)


class _Adapter:
    """The i2c-dev file of one emulated bus: current slave address and the ioctl decoder."""

    def __init__(self, chip: Any, fd: int, real_ioctl: Any) -> None:
        self.chip, self.fd, self._real_ioctl = chip, fd, real_ioctl
        self.address: int | None = None
        self.ioctl_calls = 0

    def ioctl(self, fd, request, arg=0, mutate_flag=True):
        if fd != self.fd:
            return self._real_ioctl(fd, request, arg, mutate_flag)
        self.ioctl_calls += 1
        if request == I2C_FUNCS:
            arg.value = int(getattr(self.chip, "funcs", 0x0EFF0009))
            return 0
        if request in (I2C_SLAVE, I2C_SLAVE_FORCE):
            self.address = int(arg)
            return 0
        if request == I2C_PEC:
            return 0
        if request == I2C_SMBUS:
            self._smbus(arg)
            return 0
        if request == I2C_RDWR:
            msgs = [arg.msgs[i] for i in range(arg.nmsgs)]
            self.chip.i2c_rdwr(*msgs)
            return 0
        raise OSError(_errno.ENOTTY, "Inappropriate ioctl for device")

    def _smbus(self, msg) -> None:
        chip, addr = self.chip, self.address
        if addr is None:
            raise OSError(_errno.EINVAL, "Invalid argument (no slave address set)")
        rd, cmd, size = msg.read_write == _SMBUS_READ, int(msg.command), int(msg.size)
        if size in (_BYTE_DATA, _WORD_DATA, _I2C_BLOCK_DATA) or (size == _BYTE and rd):
            if not msg.data:  # a transfer that moves data without a buffer: the kernel's answer
                raise OSError(_errno.EFAULT, "Bad address")
            data = msg.data.contents
        if size == _BYTE_DATA:
            if rd:
                data.byte = chip.read_byte_data(addr, cmd)
            else:
                chip.write_byte_data(addr, cmd, int(data.byte))
        elif size == _WORD_DATA:
            if rd:
                data.word = chip.read_word_data(addr, cmd)
            else:
                chip.write_word_data(addr, cmd, int(data.word))
        elif size == _I2C_BLOCK_DATA:
            n = int(data.block[0])
            if rd:
                vals = chip.read_i2c_block_data(addr, cmd, n)
                for i, v in enumerate(vals):
                    data.block[1 + i] = v
            else:
                chip.write_i2c_block_data(addr, cmd, list(data.block[1 : n + 1]))
        elif size == _BYTE:
            if rd:
                data.byte = chip.read_byte(addr)
            else:
                chip.write_byte(addr, cmd)
        elif size == _QUICK:
            chip.write_quick(addr)
        else:  # SMBus block / process calls: unsupported, as on most pure-I2C adapters
            raise OSError(_errno.EOPNOTSUPP, "Operation not supported")


@contextmanager
def emulated_i2c_bus(chip: Any, bus_number: int = 1) -> Iterator[_Adapter]:
    """Within the block, ``smbus2.SMBus(bus_number)`` opens a bus on which ``chip`` answers.

    Yields the adapter (its ``ioctl_calls`` counts the ioctls that reached the emulator).
    """
    import smbus2.smbus2 as sm

    path = f"/dev/i2c-{int(bus_number)}"
    fd = next(_fd_counter)
    # smbus2's stubs do not declare the module globals ``os`` and ``ioctl`` that are swapped here
    old_os, old_ioctl = sm.os, sm.ioctl  # type: ignore[attr-defined]
    adapter = _Adapter(chip, fd, old_ioctl)
    sm.os = _OsShim(old_os, path, fd)  # type: ignore[attr-defined]
    sm.ioctl = adapter.ioctl  # type: ignore[attr-defined]
    try:
        yield adapter
    finally:
        sm.os, sm.ioctl = old_os, old_ioctl  # type: ignore[attr-defined]
