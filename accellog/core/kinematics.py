"""Truth motion of a (simulated) sensor: the interface between motion scenarios and the emulator.

A Motion gives, for any array of times, the exact kinematics of the sensor. The emulator's sensor
model turns them into readings (with errors); evaluation compares tracks with them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from accellog.core.session import PoseLabel


@dataclass
class Kinematics:
    """Exact motion at times t_s (n,).

    specific_force_g: (n,3) what a perfect accelerometer reads, sensor frame, in g
        (= R^T (a_world - g_world) / g0 with g_world = (0, 0, -g_local)).
    omega_dps: (n,3) angular rate of the sensor frame w.r.t. the world, in the sensor frame (deg/s).
    position_m, velocity_mps: (n,3) world frame (z up). q_sensor_to_world: (n,4) w,x,y,z.
    """

    t_s: np.ndarray
    specific_force_g: np.ndarray
    omega_dps: np.ndarray
    position_m: np.ndarray
    velocity_mps: np.ndarray
    q_sensor_to_world: np.ndarray


class Motion(Protocol):
    """What the emulator needs from a motion scenario (held poses, a driving robot, ...)."""

    @property
    def duration_s(self) -> float:
        """Length of the scenario (s)."""
        ...

    def kinematics(self, t_s: np.ndarray) -> Kinematics:
        """Vectorised exact kinematics at times t_s (s, any order, within [0, duration_s])."""
        ...

    def labels(self) -> list[PoseLabel]:
        """The static holds of the scenario with their nominal up vectors (may be empty)."""
        ...
