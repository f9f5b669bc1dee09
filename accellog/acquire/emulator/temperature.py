"""Die temperature as a function of time: the input of the temperature effects of the sensor model."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from accellog.core.errors import InputError


class TemperaturePath:
    """Die temperature T(t) (degC) over time since session start t (s), vectorised.

    Build with ``constant(T)``, ``warmup(T_start, T_end, tau_s)`` (T = T_end + (T_start - T_end)
    exp(-t/tau)), ``ramp(T0, rate)`` (T = T0 + rate t) or ``points(t_s, T)`` (piecewise linear,
    held constant outside the points).
    """

    def __init__(self, fn: Callable[[np.ndarray], np.ndarray], description: str) -> None:
        self._fn = fn
        self.description = description

    def degC(self, t_s: np.ndarray) -> np.ndarray:
        """Die temperature (degC) at times t_s (s); same shape as t_s."""
        t = np.asarray(t_s, dtype=float)
        return np.broadcast_to(self._fn(t), t.shape).astype(float)

    def rate_degC_per_s(self, t_s: np.ndarray, dt_s: float = 0.05) -> np.ndarray:
        """dT/dt (degC/s) at t_s by a central difference over +-dt_s (exact for the piecewise paths
        away from their corners)."""
        t = np.asarray(t_s, dtype=float)
        return (self.degC(t + dt_s) - self.degC(t - dt_s)) / (2.0 * dt_s)

    def play_degC(self, t_s: np.ndarray, width_degC: float, end_s: float, step_s: float = 0.05) -> np.ndarray:
        """Play (backlash) operator of T(t) of width w (degC) at t_s: P starts at T(0) and follows T
        only when |T - P| would exceed w/2, so P = T - w/2 while heating, T + w/2 while cooling.
        Evaluated on a fixed grid from 0 to end_s (step_s), so any split of t_s gives the same values."""
        if not width_degC > 0:
            raise InputError(f"hysteresis width {width_degC:g} degC must be > 0")
        key = (float(width_degC), float(end_s), float(step_s))
        cache = self.__dict__.setdefault("_play", {})
        if key not in cache:
            grid = np.arange(0.0, float(end_s) + 2 * step_s, step_s)
            T = self.degC(grid)
            P = np.empty_like(T)
            p, h = float(T[0]), 0.5 * float(width_degC)
            for k, Tk in enumerate(T.tolist()):  # sequential by nature: y_k = clip(y_k-1, T_k - h, T_k + h)
                p = min(max(p, Tk - h), Tk + h)
                P[k] = p
            cache[key] = (grid, P)
        grid, P = cache[key]
        return np.interp(np.asarray(t_s, dtype=float), grid, P)

    def __repr__(self) -> str:
        return f"TemperaturePath({self.description})"

    @classmethod
    def constant(cls, T_degC: float = 25.0) -> TemperaturePath:
        """T(t) = T_degC."""
        T = float(T_degC)
        return cls(lambda t: np.full(t.shape, T), f"constant {T:g} degC")

    @classmethod
    def warmup(cls, T_start_degC: float, T_end_degC: float, tau_s: float) -> TemperaturePath:
        """Self-heating after power-on: T = T_end + (T_start - T_end) exp(-t / tau_s)."""
        if tau_s <= 0:
            raise InputError(f"warm-up time constant tau_s={tau_s:g} must be > 0 s")
        T0, T1, tau = float(T_start_degC), float(T_end_degC), float(tau_s)
        return cls(
            lambda t: T1 + (T0 - T1) * np.exp(-np.maximum(t, 0.0) / tau),
            f"warmup {T0:g} -> {T1:g} degC, tau {tau:g} s",
        )

    @classmethod
    def ramp(cls, T0_degC: float, rate_degC_per_s: float) -> TemperaturePath:
        """Linear ramp: T = T0 + rate t."""
        T0, r = float(T0_degC), float(rate_degC_per_s)
        return cls(lambda t: T0 + r * t, f"ramp {T0:g} degC + {r:g} degC/s")

    @classmethod
    def points(cls, t_s: Sequence[float], T_degC: Sequence[float]) -> TemperaturePath:
        """Piecewise-linear through (t_s[i], T_degC[i]); constant before the first / after the last."""
        tp = np.asarray(t_s, dtype=float)
        Tp = np.asarray(T_degC, dtype=float)
        if tp.ndim != 1 or tp.shape != Tp.shape or tp.size == 0:
            raise InputError("temperature points need equal-length, non-empty t_s and T lists")
        if np.any(np.diff(tp) <= 0):
            raise InputError("temperature point times t_s must be strictly increasing")
        return cls(lambda t: np.interp(t, tp, Tp), f"points ({tp.size})")

    piecewise = points
