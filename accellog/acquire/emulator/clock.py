"""Clocks for the emulated chip and the driver: a simulated clock that jumps, and the real one.

Both expose ``now_ns() -> int`` (ns since an arbitrary origin, monotonic) and ``sleep(s)``. The
emulated chip derives its sample clock from ``now_ns``; with ``SimClock`` a sleep advances time
instantly, so a simulated session runs as fast as the CPU allows.
"""

from __future__ import annotations

import time


class SimClock:
    """Simulated time: ``now_ns`` only moves when someone calls ``sleep`` or ``advance_ns``."""

    def __init__(self, start_ns: int = 0) -> None:
        self._t_ns = int(start_ns)

    def now_ns(self) -> int:
        """Current simulated time (ns)."""
        return self._t_ns

    def now_s(self) -> float:
        """Current simulated time (s)."""
        return self._t_ns * 1e-9

    def sleep(self, seconds: float) -> None:
        """Advance simulated time by ``seconds`` (s), instantly; negative values are ignored."""
        if seconds > 0:
            self._t_ns += round(seconds * 1e9)

    def advance_ns(self, dt_ns: int) -> None:
        """Advance simulated time by dt_ns (ns, >= 0)."""
        if dt_ns > 0:
            self._t_ns += int(dt_ns)


class RealClock:
    """Host monotonic time (``time.monotonic_ns``) and a real ``time.sleep``, same interface."""

    def __init__(self) -> None:
        self._origin_ns = time.monotonic_ns()

    def now_ns(self) -> int:
        """Monotonic host time (ns) since this clock was created."""
        return time.monotonic_ns() - self._origin_ns

    def now_s(self) -> float:
        return self.now_ns() * 1e-9

    def sleep(self, seconds: float) -> None:
        """Really wait ``seconds`` (s)."""
        if seconds > 0:
            time.sleep(seconds)
