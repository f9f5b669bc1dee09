"""Truth motion of a guided static-pose protocol: hold each pose, turn smoothly to the next.

Timeline: the sensor sits in the first pose for ``start_delay_s`` (unlabelled, while the recorder
starts), then holds pose k for its ``hold_s`` and turns to pose k+1 in ``move_s``. A turn is a
rotation about one body-fixed axis n by angle theta (q_{k+1} = q_k * rot(n, theta), shortest
path), traversed with the quintic profile s(u) = 10u^3 - 15u^4 + 6u^5, u = (t - t_k) / move_s:

    q_nominal(t) = q_k * rot(n, s(u) theta),     omega_sensor = s'(u) / move_s * theta * n

(s' and s'' vanish at both ends, so the rate and the angular acceleration are continuous). The
sensor turns about its own origin: position and velocity stay zero.

Fixture tilt: the real orientation is q_tilt * q_nominal with q_tilt = q_y(tilt_y) * q_x(tilt_x)
(world axes, deg); the labels keep the nominal up vector and orientation (the operator believes
the fixture is level), the truth (kinematics) uses the real one:

    f = R(q_tilt q_nominal)^T (0, 0, g_local / g0)   (g)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from accellog.core.errors import InputError
from accellog.core.kinematics import Kinematics
from accellog.core.protocol import PoseSpec
from accellog.core.rotations import quat_conjugate, quat_from_axis_angle, quat_multiply, rotate_inverse
from accellog.core.session import PoseLabel, quat4, vec3
from accellog.core.units import STANDARD_GRAVITY_MPS2


def _smootherstep(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """s(u) = 10u^3 - 15u^4 + 6u^5 and ds/du = 30u^2 (1 - u)^2 for u in [0, 1]."""
    u = np.clip(u, 0.0, 1.0)
    s = u * u * u * (10.0 + u * (-15.0 + 6.0 * u))
    ds = 30.0 * u * u * (1.0 - u) ** 2
    return s, ds


class PoseSequenceMotion:
    """Motion protocol (accellog.core.kinematics.Motion) for a list of static poses."""

    def __init__(
        self,
        poses: Sequence[PoseSpec],
        move_s: float = 3.0,
        start_delay_s: float = 1.0,
        fixture_tilt_deg: tuple[float, float] = (0.0, 0.0),
        local_gravity_mps2: float = STANDARD_GRAVITY_MPS2,
    ) -> None:
        if not poses:
            raise InputError("a pose sequence needs at least one pose")
        if move_s <= 0:
            raise InputError(f"move_s={move_s:g}: the move between poses must take > 0 s")
        if start_delay_s < 0:
            raise InputError(f"start_delay_s={start_delay_s:g} must be >= 0 s")
        for p in poses:
            if p.hold_s <= 0:
                raise InputError(f"pose {p.name}: hold_s={p.hold_s:g} must be > 0 s")
        self.poses = list(poses)
        self.move_s = float(move_s)
        self.start_delay_s = float(start_delay_s)
        self.fixture_tilt_deg = (float(fixture_tilt_deg[0]), float(fixture_tilt_deg[1]))
        self.local_gravity_mps2 = float(local_gravity_mps2)
        holds = np.array([p.hold_s for p in self.poses], float)
        n = len(self.poses)
        self.hold_start_s = (
            self.start_delay_s + np.concatenate([[0.0], np.cumsum(holds[:-1])]) + self.move_s * np.arange(n)
        )
        self.hold_end_s = self.hold_start_s + holds
        q = np.array([p.q_sensor_to_world for p in self.poses], float)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        self._q_nominal = q
        # Body-frame rotation of each move: q_rel = q_k^-1 q_{k+1} = rot(axis, angle), shortest path.
        q_rel = quat_multiply(quat_conjugate(q[:-1]), q[1:]) if n > 1 else np.zeros((0, 4))
        q_rel = np.where(q_rel[:, :1] < 0, -q_rel, q_rel)
        vec_norm = np.linalg.norm(q_rel[:, 1:], axis=1)
        self._move_angle_rad = 2.0 * np.arctan2(vec_norm, q_rel[:, 0]) if n > 1 else np.zeros(0)
        safe = np.where(vec_norm > 1e-12, vec_norm, 1.0)
        axis = q_rel[:, 1:] / safe[:, None]
        axis[vec_norm <= 1e-12] = (0.0, 0.0, 1.0)
        self._move_axis = axis
        tx, ty = np.deg2rad(self.fixture_tilt_deg)
        self.q_tilt = quat_multiply(
            quat_from_axis_angle([0.0, 1.0, 0.0], ty), quat_from_axis_angle([1.0, 0.0, 0.0], tx)
        )

    @property
    def duration_s(self) -> float:
        """End of the last hold (s)."""
        return float(self.hold_end_s[-1])

    def kinematics(self, t_s: np.ndarray) -> Kinematics:
        """Exact orientation, rate and specific force at times t_s (s); held still outside [0, T]."""
        t = np.asarray(t_s, float).reshape(-1)
        n = len(self.poses)
        k = np.clip(np.searchsorted(self.hold_start_s, t, side="right") - 1, 0, n - 1)
        u = (t - self.hold_end_s[k]) / self.move_s
        moving = (u > 0.0) & (k < n - 1)
        km = np.minimum(k, max(n - 2, 0))
        s, ds = _smootherstep(np.where(moving, u, 0.0))
        q_nom = self._q_nominal[k].copy()
        omega_rad = np.zeros((t.size, 3))
        if n > 1 and np.any(moving):
            idx = np.nonzero(moving)[0]
            ang = s[idx] * self._move_angle_rad[km[idx]]
            q_nom[idx] = quat_multiply(
                self._q_nominal[km[idx]], quat_from_axis_angle(self._move_axis[km[idx]], ang)
            )
            omega_rad[idx] = (ds[idx] / self.move_s * self._move_angle_rad[km[idx]])[
                :, None
            ] * self._move_axis[km[idx]]
        q = quat_multiply(self.q_tilt, q_nom)
        up_world = np.array([0.0, 0.0, self.local_gravity_mps2 / STANDARD_GRAVITY_MPS2])
        f = rotate_inverse(q, np.broadcast_to(up_world, (t.size, 3)))
        zeros = np.zeros((t.size, 3))
        return Kinematics(
            t_s=t,
            specific_force_g=f,
            omega_dps=np.rad2deg(omega_rad),
            position_m=zeros,
            velocity_mps=zeros.copy(),
            q_sensor_to_world=q,
        )

    def labels(self) -> list[PoseLabel]:
        """One label per hold, with the nominal up vector and orientation."""
        return [
            PoseLabel(
                p.name,
                float(self.hold_start_s[i]),
                float(self.hold_end_s[i]),
                vec3(p.up_sensor),
                quat4(self._q_nominal[i]),
                i,
            )
            for i, p in enumerate(self.poses)
        ]
