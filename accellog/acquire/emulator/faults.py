"""Fault injection for rehearsing a flaky setup: bus errors, FIFO glitches, host stalls, disconnects.

A ``FaultPlan`` holds the scenario keys (all off by default):

    i2c_error_rate      probability per I2C transaction of errno 121 (NAK) or 5 (EIO)   [0, 1)
    fifo_glitch_rate    probability per FIFO drain that one byte was lost since the last   [0, 1)
                        (a spurious read: the packets are misaligned until the FIFO is reset)
    host_stall_s        the host stops for this long (s) ...                               >= 0
    host_stall_every_s  ... every this many seconds of host time (0: never)                >= 0
    disconnect_at_s     the bus is cut at this host time (s after the chip powers up) ...  >= 0
    disconnect_s        ... for this long (s): every transaction NAKs (errno 121)          >= 0

A plan that could never finish is refused up front (InputError naming the key): a rate of 1 (every
read fails, the recorder retries forever), a stall as long as its period (the host never runs) and,
once the session's length is known (``check_session``), a disconnect longer than the session.

``FaultyBus`` wraps an emulated chip (the smbus2 method surface) and applies glitches and the
disconnect window; ``stalling_sleep`` wraps the host's sleep with the stalls; the chip itself
draws the I2C errors (``EmulatedMpu9250(i2c_error_rate=...)``). Every sample lost to a fault is
counted by the driver as an Event ('i2c_error', 'misaligned', 'fifo_overflow') with lost_samples.
"""

from __future__ import annotations

import errno as _errno
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from accellog.acquire import registers as R
from accellog.core.errors import InputError

FAULT_HELP = {
    "i2c_error_rate": "probability per I2C transaction of errno 121/5, 0 <= p < 1",
    "fifo_glitch_rate": "probability per FIFO read of losing one byte (misaligned packets), 0 <= p < 1",
    "host_stall_s": "host pause (s), every host_stall_every_s (shorter than that period)",
    "host_stall_every_s": "seconds of host time between stalls (0: none)",
    "disconnect_at_s": "host time (s) at which the bus is cut",
    "disconnect_s": "how long the bus stays cut (s; 0: no disconnect)",
}


@dataclass(frozen=True)
class FaultPlan:
    """What goes wrong during a simulated recording (see the module docstring for the keys)."""

    i2c_error_rate: float = 0.0
    fifo_glitch_rate: float = 0.0
    host_stall_s: float = 0.0
    host_stall_every_s: float = 0.0
    disconnect_at_s: float = 0.0
    disconnect_s: float = 0.0

    @classmethod
    def names(cls) -> list[str]:
        return [f.name for f in fields(cls)]

    @classmethod
    def from_mapping(cls, values: dict[str, Any], where: str = "scenario") -> FaultPlan:
        """FaultPlan from {key: number}; InputError naming the key for unknown keys, non-numbers,
        rates outside [0, 1), negative times or a stall as long as its period (see check_plan)."""
        kw: dict[str, float] = {}
        for key, v in values.items():
            if key not in cls.names():
                raise InputError(f"unknown fault key {key!r}; known: {', '.join(cls.names())}", where=where)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"fault key {key!r} must be a finite number, got {v!r}", where=where)
            if key.endswith("_rate") and not 0.0 <= v < 1.0:
                raise InputError(
                    f"fault key {key!r} = {v:g} must be a probability in 0 <= p < 1 "
                    "(at 1 every read fails and the recording never ends)",
                    where=where,
                )
            if v < 0:
                raise InputError(f"fault key {key!r} = {v:g} must be >= 0 (s)", where=where)
            kw[key] = float(v)
        plan = cls(**kw)
        plan.check_plan(where)
        return plan

    def check_plan(self, where: str = "scenario") -> None:
        """InputError when the stalls leave the host no time to run: host_stall_s >= host_stall_every_s."""
        if self.host_stall_every_s > 0 and self.host_stall_s >= self.host_stall_every_s:
            raise InputError(
                f"fault key 'host_stall_s' = {self.host_stall_s:g} s must be shorter than "
                f"'host_stall_every_s' = {self.host_stall_every_s:g} s (else the host never runs)",
                where=where,
            )

    def check_session(self, session_s: float, where: str = "scenario") -> None:
        """InputError when the disconnect outlasts a session of session_s (s): disconnect_s > session_s."""
        if self.disconnect_s > session_s:
            raise InputError(
                f"fault key 'disconnect_s' = {self.disconnect_s:g} s is longer than the session "
                f"({session_s:g} s): the recording would never end",
                where=where,
            )

    @property
    def active(self) -> bool:
        return any(v for v in asdict(self).values())

    @property
    def bus_faults(self) -> bool:
        return self.fifo_glitch_rate > 0 or self.disconnect_s > 0

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


class FaultyBus:
    """The smbus2 surface of `chip` with FIFO glitches and a disconnect window (see FaultPlan).

    Host time is `clock_ns()` since this object was created. Counters: glitches, disconnected_calls.
    """

    _CALLS = ("read_byte_data", "write_byte_data", "read_i2c_block_data", "write_i2c_block_data", "i2c_rdwr")

    def __init__(self, chip, plan: FaultPlan, clock_ns: Callable[[], int], seed: int = 0) -> None:
        self._chip = chip
        self._plan = plan
        self._clock_ns = clock_ns
        self._t0_ns = int(clock_ns())
        self._rng = np.random.default_rng([int(seed), 0xFA17])
        self.glitches = 0
        self.disconnected_calls = 0

    def __getattr__(self, name: str):
        attr = getattr(self._chip, name)
        if name not in self._CALLS:
            return attr

        def call(*args, **kw):
            self._before(name, args)
            return attr(*args, **kw)

        return call

    def _host_s(self) -> float:
        return (int(self._clock_ns()) - self._t0_ns) * 1e-9

    def _before(self, name: str, args: tuple) -> None:
        p = self._plan
        if p.disconnect_s > 0 and p.disconnect_at_s <= self._host_s() < p.disconnect_at_s + p.disconnect_s:
            self.disconnected_calls += 1
            raise OSError(_errno.EREMOTEIO, "Remote I/O error (bus disconnected)")
        glitch = p.fifo_glitch_rate > 0 and self._is_count_read(name, args)
        if glitch and self._rng.random() < p.fifo_glitch_rate:
            self.glitches += 1
            self._chip.inject_fifo_glitch(1)  # lost since the last drain: the count is misaligned

    @staticmethod
    def _is_count_read(name: str, args: tuple) -> bool:
        """The FIFO_COUNTH read that starts every FIFO drain."""
        return name == "read_i2c_block_data" and len(args) >= 2 and args[1] == R.FIFO_COUNTH
        return False


def stalling_sleep(sleep: Callable[[float], None], clock_ns: Callable[[], int], plan: FaultPlan):
    """`sleep` plus, every host_stall_every_s of host time, an extra pause of host_stall_s."""
    if not (plan.host_stall_s > 0 and plan.host_stall_every_s > 0):
        return sleep
    t0 = int(clock_ns())
    state = {"next_s": plan.host_stall_every_s, "stalls": 0}

    def wrapped(seconds: float) -> None:
        sleep(seconds)
        now_s = (int(clock_ns()) - t0) * 1e-9
        if now_s >= state["next_s"]:
            state["next_s"] = now_s + plan.host_stall_every_s
            state["stalls"] += 1
            sleep(plan.host_stall_s)

    wrapped.state = state  # type: ignore[attr-defined]
    return wrapped
