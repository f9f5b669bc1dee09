"""Truth motion of a sensor on a driving robot: straight runs, turns, stops, ramps, a banked section.

The robot is described by four smooth channels of time: forward speed v (m/s, along the sensor x
axis) and the Euler angles yaw psi, pitch theta, roll phi (rad, q = q_z(psi) q_y(theta) q_x(phi),
sensor frame = robot body: x forward, y left, z up). Each segment blends every channel it changes
from its start value to its end value with the quintic smootherstep s(u) = 10u^3 - 15u^4 + 6u^5
(s', s'' vanish at both ends, so all channels are C2). While moving, a small vertical vibration
(road and motor; it is what lets a zero-velocity detector tell cruising from standing still) is
added: p_vib = A0 tanh(v / v_s) sin(2 pi f_vib t) z_world.

Exact, self-consistent kinematics (vectorised):

    v_world = R(q) (v, 0, 0) + d p_vib/dt
    a_world = R(q) (omega x (v, 0, 0) + (v', 0, 0)) + d^2 p_vib/dt^2
    omega   = (phi' - psi' sin th,  th' cos phi + psi' cos th sin phi,  -th' sin phi + psi' cos th cos phi)
    f       = R^T (a_world - g_world) / g0,  g_world = (0, 0, -g_local)
    p(t)    = p(t_k) + int_{t_k}^t v_world dt   (5-point Gauss-Legendre on a grid of <= 10 ms steps
                                                 aligned with the segment boundaries; error ~ h^10)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from accellog.core.errors import InputError
from accellog.core.kinematics import Kinematics
from accellog.core.rotations import quat_from_axis_angle, quat_multiply, rotate_inverse
from accellog.core.session import PoseLabel, quat4, vec3
from accellog.core.units import STANDARD_GRAVITY_MPS2

CHANNELS = ("speed_mps", "yaw_rad", "pitch_rad", "roll_rad")


@dataclass(frozen=True)
class Segment:
    """One piece of the path: over duration_s, blend the channels given to their target values.

    speed_mps: forward speed at the end (m/s); yaw_deg / grade_deg / roll_deg: heading (deg,
    counter-clockwise from world x), road grade (deg, positive = driving uphill, i.e. pitch =
    -grade) and roll (deg, right-hand about the forward axis) at the end. None keeps the value.
    kind: 'stop' segments (speed 0 throughout) become static holds in labels().
    """

    duration_s: float
    speed_mps: float | None = None
    yaw_deg: float | None = None
    grade_deg: float | None = None
    roll_deg: float | None = None
    kind: str = "move"


def stop(duration_s: float) -> Segment:
    """Stand still for duration_s (s): a zero-velocity opportunity and a labelled hold."""
    return Segment(duration_s, speed_mps=0.0, kind="stop")


def drive(distance_m: float, speed_mps: float = 1.0, accel_s: float = 2.0) -> list[Segment]:
    """Straight run from rest to rest: smooth accel over accel_s, cruise, smooth decel.

    A smootherstep speed change from 0 to v over T covers v T / 2, so the run covers exactly
    distance_m = v accel_s + v cruise_s (horizontal when level).
    """
    cruise_s = distance_m / speed_mps - accel_s
    if cruise_s < 0:
        raise InputError(f"drive of {distance_m} m at {speed_mps} m/s is shorter than its accel/decel")
    return [
        Segment(accel_s, speed_mps=speed_mps),
        Segment(cruise_s),
        Segment(accel_s, speed_mps=0.0),
    ]


def turn(to_yaw_deg: float, duration_s: float = 2.5) -> Segment:
    """Turn to heading to_yaw_deg (deg, absolute) over duration_s; in place when standing."""
    return Segment(duration_s, yaw_deg=to_yaw_deg)


def _tilt(duration_s: float, channel: str, angle_deg: float) -> Segment:
    """A segment that tilts channel ('grade_deg' | 'roll_deg') to angle_deg."""
    if channel == "grade_deg":
        return Segment(duration_s, grade_deg=angle_deg)
    if channel == "roll_deg":
        return Segment(duration_s, roll_deg=angle_deg)
    raise ValueError(f"no tilt channel {channel!r}")


def _tilted_run(
    what: str,
    distance_m: float,
    channel: str,
    angle_deg: float,
    speed_mps: float,
    accel_s: float,
    tilt_s: float,
) -> list[Segment]:
    """Rest -> accelerate -> tilt channel ('grade_deg' | 'roll_deg') to angle_deg over tilt_s -> cruise
    -> tilt back to 0 -> decelerate -> rest; the cruise makes the run cover distance_m (m)."""
    cruise_s = distance_m / speed_mps - accel_s - 2 * tilt_s
    if cruise_s < 0:
        raise InputError(f"{what} run of {distance_m} m is too short for its transitions")
    return [
        Segment(accel_s, speed_mps=speed_mps),
        _tilt(tilt_s, channel, angle_deg),
        Segment(cruise_s),
        _tilt(tilt_s, channel, 0.0),
        Segment(accel_s, speed_mps=0.0),
    ]


def ramp_run(
    distance_m: float, grade_deg: float, speed_mps: float = 1.0, accel_s: float = 2.0, pitch_s: float = 1.5
) -> list[Segment]:
    """Rest -> accelerate -> drive onto a ramp of grade_deg -> leave it -> decelerate -> rest."""
    return _tilted_run("ramp", distance_m, "grade_deg", grade_deg, speed_mps, accel_s, pitch_s)


def banked_run(
    distance_m: float, roll_deg: float, speed_mps: float = 1.0, accel_s: float = 2.0, roll_s: float = 1.5
) -> list[Segment]:
    """Rest -> accelerate -> roll onto a banked section -> roll back -> decelerate -> rest."""
    return _tilted_run("banked", distance_m, "roll_deg", roll_deg, speed_mps, accel_s, roll_s)


def _smootherstep(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """s(u) = 10u^3 - 15u^4 + 6u^5 and its first two derivatives d/du."""
    u2 = u * u
    s = u2 * u * (10.0 - 15.0 * u + 6.0 * u2)
    ds = 30.0 * u2 * (1.0 - 2.0 * u + u2)
    dds = 60.0 * u * (1.0 - 3.0 * u + 2.0 * u2)
    return s, ds, dds


_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)


class RobotPathMotion:
    """A robot driving a path of Segments (implements accellog.core.kinematics.Motion).

    local_gravity_mps2: g_local (m/s^2) used for the specific force; vibration_m (m),
    vibration_speed_mps (m/s), vibration_hz (Hz): the vertical vibration A0 tanh(v / v_s)
    sin(2 pi f t) while moving (A0 = 0 turns it off; 5e-5 m at 23 Hz is about 0.1 g peak);
    p0_m: start position (m, world); grid_s: step (s) of the precomputed position nodes.
    """

    def __init__(
        self,
        segments: Sequence[Segment],
        *,
        local_gravity_mps2: float = STANDARD_GRAVITY_MPS2,
        vibration_m: float = 5.0e-5,
        vibration_speed_mps: float = 0.05,
        vibration_hz: float = 23.0,
        p0_m: Sequence[float] = (0.0, 0.0, 0.0),
        yaw0_deg: float = 0.0,
        grid_s: float = 0.01,
    ) -> None:
        segs = list(segments)
        if not segs:
            raise InputError("a robot path needs at least one segment")
        dur = np.array([s.duration_s for s in segs], float)
        if np.any(~np.isfinite(dur)) or np.any(dur <= 0):
            raise InputError("every path segment needs a positive duration_s")
        self.segments = segs
        self.local_gravity_mps2 = float(local_gravity_mps2)
        self.vibration_m = float(vibration_m)
        self.vibration_speed_mps = float(vibration_speed_mps)
        self.vibration_hz = float(vibration_hz)
        self.p0_m = np.asarray(p0_m, float)
        self._t_start = np.concatenate([[0.0], np.cumsum(dur)[:-1]])
        self._dur = dur
        # channel values at each segment start and end (speed m/s, angles rad)
        cur = np.array([0.0, np.deg2rad(yaw0_deg), 0.0, 0.0])
        start: list[np.ndarray] = []
        end: list[np.ndarray] = []
        for s in segs:
            nxt = cur.copy()
            for k, val in enumerate((s.speed_mps, s.yaw_deg, s.grade_deg, s.roll_deg)):
                if val is not None:
                    nxt[k] = val if k == 0 else np.deg2rad(-val if k == 2 else val)
            if s.kind == "stop" and (cur[0] != 0.0 or nxt[0] != 0.0):
                raise InputError(f"stop at t={self._t_start[len(start)]:.3f} s while the robot is moving")
            start.append(cur)
            end.append(nxt)
            cur = nxt
        self._start = np.array(start)
        self._end = np.array(end)
        # position nodes: a grid aligned with the segment boundaries, <= grid_s apart
        nodes = [np.array([0.0])]
        for t0, d in zip(self._t_start, dur, strict=True):
            m = max(1, int(np.ceil(d / grid_s)))
            nodes.append(t0 + d * np.arange(1, m + 1) / m)
        self._nodes = np.concatenate(nodes)
        self._nodes[-1] = self.duration_s
        h = np.diff(self._nodes)
        tq = self._nodes[:-1, None] + 0.5 * h[:, None] * (_GL_X[None, :] + 1.0)
        v = self._velocity(tq.ravel()).reshape((*tq.shape, 3))
        inc = 0.5 * h[:, None] * np.einsum("j,kjc->kc", _GL_W, v)
        self._p_nodes = self.p0_m + np.concatenate([np.zeros((1, 3)), np.cumsum(inc, axis=0)])

    @property
    def duration_s(self) -> float:
        return float(self._t_start[-1] + self._dur[-1])

    def _channels(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Channel values, first and second time derivatives at t (s): three (n,4) arrays."""
        k = np.clip(np.searchsorted(self._t_start, t, side="right") - 1, 0, len(self._dur) - 1)
        u = np.clip((t - self._t_start[k]) / self._dur[k], 0.0, 1.0)
        s, ds, dds = _smootherstep(u)
        delta = self._end[k] - self._start[k]
        val = self._start[k] + delta * s[:, None]
        d1 = delta * (ds / self._dur[k])[:, None]
        d2 = delta * (dds / self._dur[k] ** 2)[:, None]
        return val, d1, d2

    @staticmethod
    def _quat(val: np.ndarray) -> np.ndarray:
        """q = q_z(yaw) q_y(pitch) q_x(roll) (w,x,y,z)."""
        qz = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), val[:, 1])
        qy = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), val[:, 2])
        qx = quat_from_axis_angle(np.array([1.0, 0.0, 0.0]), val[:, 3])
        return quat_multiply(qz, quat_multiply(qy, qx))

    @staticmethod
    def _forward(val: np.ndarray) -> np.ndarray:
        """World direction of the sensor x axis: R(q) (1,0,0)."""
        yaw, pitch = val[:, 1], val[:, 2]
        return np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), -np.sin(pitch)], -1)

    def _vib(self, t: np.ndarray, val: np.ndarray, d1: np.ndarray, d2: np.ndarray):
        """Vertical vibration p = A(v) sin(W t), A(v) = A0 tanh(v / v_s): p, dp/dt, d2p/dt2 (m, m/s, m/s^2).

        dp/dt = A' v' sin + A W cos;  d2p/dt2 = (A'' v'^2 + A' v'') sin + 2 A' v' W cos - A W^2 sin.
        """
        a0, vs, w = self.vibration_m, self.vibration_speed_mps, 2.0 * np.pi * self.vibration_hz
        sn, cs = np.sin(w * t), np.cos(w * t)
        th = np.tanh(val[:, 0] / vs)
        amp = a0 * th
        d_amp = a0 * (1.0 - th * th) / vs
        dd_amp = -2.0 * th * d_amp / vs
        dv, ddv = d1[:, 0], d2[:, 0]
        vel = d_amp * dv * sn + amp * w * cs
        acc = (dd_amp * dv * dv + d_amp * ddv) * sn + 2.0 * d_amp * dv * w * cs - amp * w * w * sn
        return amp * sn, vel, acc

    def _velocity(self, t: np.ndarray) -> np.ndarray:
        val, d1, d2 = self._channels(t)
        vel = val[:, :1] * self._forward(val)
        vel[:, 2] += self._vib(t, val, d1, d2)[1]
        return vel

    def kinematics(self, t_s: np.ndarray) -> Kinematics:
        """Exact kinematics at t_s (s, any order, within [0, duration_s])."""
        t = np.atleast_1d(np.asarray(t_s, float))
        if t.size and (np.nanmin(t) < -1e-9 or np.nanmax(t) > self.duration_s + 1e-9 or np.isnan(t).any()):
            raise InputError(f"times outside the robot path [0, {self.duration_s:.3f}] s")
        val, d1, d2 = self._channels(t)
        q = self._quat(val)
        roll, pitch = val[:, 3], val[:, 2]
        dyaw, dpitch, droll = d1[:, 1], d1[:, 2], d1[:, 3]
        sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
        omega = np.stack(
            [droll - dyaw * sp, dpitch * cr + dyaw * cp * sr, -dpitch * sr + dyaw * cp * cr], -1
        )  # rad/s, sensor frame
        v = val[:, 0]
        # body-frame acceleration of the carried frame: omega x (v,0,0) + (v',0,0)
        acc_body = np.stack([d1[:, 0], omega[:, 2] * v, -omega[:, 1] * v], -1)
        fwd = self._forward(val)
        _, vib_v, vib_a = self._vib(t, val, d1, d2)
        vel = v[:, None] * fwd
        vel[:, 2] += vib_v
        # position: node value + Gauss-Legendre integral of the velocity from the node to t
        k = np.clip(np.searchsorted(self._nodes, t, side="right") - 1, 0, len(self._nodes) - 2)
        dt = t - self._nodes[k]
        tq = self._nodes[k][:, None] + 0.5 * dt[:, None] * (_GL_X[None, :] + 1.0)
        vq = self._velocity(tq.ravel()).reshape((*tq.shape, 3))
        pos = self._p_nodes[k] + 0.5 * dt[:, None] * np.einsum("j,kjc->kc", _GL_W, vq)
        # specific force: f = R^T (a_world + (0,0,g)) / g0, with a_world = R acc_body + vib
        extra_world = np.zeros_like(acc_body)
        extra_world[:, 2] = vib_a + self.local_gravity_mps2
        f = (acc_body + rotate_inverse(q, extra_world)) / STANDARD_GRAVITY_MPS2
        return Kinematics(
            t_s=t,
            specific_force_g=f,
            omega_dps=np.rad2deg(omega),
            position_m=pos,
            velocity_mps=vel,
            q_sensor_to_world=q,
        )

    def labels(self) -> list[PoseLabel]:
        """Each 'stop' segment as a static hold: up vector = R^T (0,0,1), nominal q at the stop."""
        out: list[PoseLabel] = []
        for i, (seg, t0, d) in enumerate(zip(self.segments, self._t_start, self._dur, strict=True)):
            if seg.kind != "stop":
                continue
            q = self._quat(self._start[i][None, :])[0]
            up = rotate_inverse(q, np.array([0.0, 0.0, 1.0]))
            out.append(
                PoseLabel(
                    name=f"stop{len(out)}",
                    start_s=float(t0),
                    end_s=float(t0 + d),
                    up_sensor=vec3(up),
                    q_sensor_to_world=quat4(q),
                    hold_index=len(out),
                )
            )
        return out


def demo_loop_segments(
    side_m: float = 8.0, speed_mps: float = 1.0, first_stop_s: float = 4.0
) -> list[Segment]:
    """A closed square loop (about 60 s) that returns exactly to its start and heading.

    Start: stand still first_stop_s (initial alignment, gyro bias). Side 1 climbs a 5 deg ramp,
    side 2 has a 6 deg banked section, side 3 goes down a 5 deg ramp (mirror of side 1, so height
    and horizontal length cancel), side 4 is level. Between sides: stop 1.5 s, turn 90 deg in
    place over 2.5 s, stop 1 s.
    """
    segs: list[Segment] = [stop(first_stop_s)]
    runs = [
        ramp_run(side_m, 5.0, speed_mps),
        banked_run(side_m, 6.0, speed_mps),
        ramp_run(side_m, -5.0, speed_mps),
        drive(side_m, speed_mps),
    ]
    for i, run in enumerate(runs):
        segs += run
        segs += [stop(1.5), turn(90.0 * (i + 1), 2.5), stop(1.0)]
    return segs


def demo_loop(**kw) -> RobotPathMotion:
    """The default demo path: demo_loop_segments() as a RobotPathMotion (kw go to the motion)."""
    return RobotPathMotion(demo_loop_segments(), **kw)


def long_run(duration_s: float = 600.0, **kw) -> RobotPathMotion:
    """Repeated demo loops (one long stop between loops) lasting at least duration_s (s)."""
    one = demo_loop_segments()
    loop_s = sum(s.duration_s for s in one)
    n = max(1, int(np.ceil(duration_s / loop_s)))
    segs = list(one)
    for i in range(1, n):
        for s in demo_loop_segments(first_stop_s=2.0):
            # headings keep increasing: each loop adds 360 deg
            yaw = None if s.yaw_deg is None else s.yaw_deg + 360.0 * i
            segs.append(Segment(s.duration_s, s.speed_mps, yaw, s.grade_deg, s.roll_deg, s.kind))
    return RobotPathMotion(segs, **kw)


def parked_run_segments(
    n_stops: int = 30, max_tilt_deg: float = 15.0, hold_s: float = 8.0, seed: int = 0
) -> list[Segment]:
    """A ground robot's run that parks on slopes: after 4 s standing level, n_stops times drive onto a slope (grade
    g = t cos a, roll r = t sin a, tilt t uniform in [2, max_tilt_deg] deg, azimuth a uniform;
    the tilt changes while moving, as on a ramp), stand hold_s, drive back onto level ground and
    turn in place to a new heading. The stops' gravity directions are all z-up within max_tilt_deg
    (where a ground robot lives)."""
    rng = np.random.default_rng([int(seed), 0x9A4C])
    tilt = rng.uniform(2.0, max_tilt_deg, n_stops)
    az = rng.uniform(0.0, 2 * np.pi, n_stops)
    yaw = np.cumsum(rng.uniform(30.0, 150.0, n_stops) * rng.choice([-1.0, 1.0], n_stops))
    segs: list[Segment] = [stop(4.0)]
    for t, a, y in zip(tilt, az, yaw, strict=True):
        onto = Segment(2.0, grade_deg=t * np.cos(a), roll_deg=t * np.sin(a))
        segs += [Segment(1.5, speed_mps=1.0), onto, Segment(1.5, speed_mps=0.0), stop(hold_s)]
        segs += [Segment(1.5, speed_mps=1.0), Segment(2.0, grade_deg=0.0, roll_deg=0.0)]
        segs += [Segment(1.5, speed_mps=0.0), turn(float(y), 2.5)]
    return segs


def parked_run(seed: int = 0, hold_s: float = 8.0, **kw) -> RobotPathMotion:
    """parked_run_segments(seed=seed, hold_s=hold_s) as a RobotPathMotion (kw go to the motion):
    about 10 min with 8 s stops."""
    return RobotPathMotion(parked_run_segments(seed=seed, hold_s=hold_s), **kw)
