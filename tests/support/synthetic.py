"""Synthetic sessions and observation tables with known truth, for tests and benchmarks (not the library)."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import AXES, LIBRARY
from accellog.calibrate.model.fit import obs_drivers
from accellog.core.protocol import PoseSpec, parse_protocol
from accellog.core.rotations import quat_between, quat_from_rotvec, rotate
from accellog.core.session import ObsTable

# ---------------------------------------------------------------------------------------------
# synthetic observations (tests, benchmarks, docs)


def cube_poses(hold_s: float = 30.0) -> list[PoseSpec]:
    """26 poses: 6 faces, 12 edges, 8 corners of a cube (off-axis gravity for nonlin3, g_cross)."""
    out = []
    for v in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).T.reshape(-1, 3):
        if not v.any():
            continue
        up = v / np.linalg.norm(v)
        q = quat_between(up, np.array([0.0, 0.0, 1.0]))
        name = ",".join(f"{'+' if c > 0 else '-'}{a}" for c, a in zip(v, AXES, strict=True) if c)
        out.append(PoseSpec(name, tuple(float(x) for x in up), tuple(float(x) for x in q), hold_s))
    return out


def synthetic_obs(
    model: Model,
    theta: np.ndarray,
    *,
    protocol: str | Sequence[PoseSpec] = "six",
    hold_s: float = 30.0,
    move_s: float = 5.0,
    windows_per_hold: int = 6,
    repeats: int = 1,
    noise_density_g_rthz: float = 300e-6,
    temp_path: Callable[[np.ndarray], np.ndarray] | None = None,
    extra: Callable[[ObsTable], np.ndarray] | None = None,
    extra_drivers: Callable[[ObsTable], dict[str, np.ndarray]] | None = None,
    gravity_g: float = 1.0,
    t0_s: float = 2.0,
    seed: int = 0,
) -> ObsTable:
    """Window means straight from the measurement equation with seeded white noise.

    Holds of hold_s (s) separated by move_s, split into windows; sigma of a window mean of duration
    T is noise_density / sqrt(2 T) (white noise, one-sided density in g/sqrt(Hz)). temp_path(t_s)
    gives the die temperature (degC); extra(obs) adds an (n,3) g term outside the model;
    extra_drivers(obs) gives user driver signals the model needs (e.g. {'humidity_pct': ...}).
    """
    poses = parse_protocol(protocol, hold_s) if isinstance(protocol, str) else list(protocol)
    rng = np.random.default_rng(seed)
    seq = [(f"{p.name}#{r}" if repeats > 1 else p.name, p) for r in range(repeats) for p in poses]
    w = hold_s / windows_per_hold
    k = np.arange(windows_per_hold)
    t_in = (k + 0.5) * w
    starts = t0_s + np.arange(len(seq)) * (hold_s + move_s)
    t = (starts[:, None] + t_in[None, :]).ravel()
    n = t.size
    pid = np.repeat(np.arange(len(seq)), windows_per_hold)
    up = np.array([p.up_sensor for _, p in seq], float)[pid]
    q = np.array([p.q_sensor_to_world for _, p in seq], float)[pid]
    T = temp_path(t) if temp_path is not None else np.full(n, 25.0)
    dTdt = (temp_path(t + 0.5) - temp_path(t - 0.5)) / 1.0 if temp_path is not None else np.zeros(n)
    sigma = np.full((n, 3), noise_density_g_rthz / np.sqrt(2.0 * w))
    obs = ObsTable(
        meas_g=np.zeros((n, 3)),
        sigma_g=sigma,
        up_sensor=up,
        pose_id=pid,
        pose_names=[s for s, _ in seq],
        t_s=t,
        t_in_pose_s=np.tile(t_in, len(seq)),
        n_samples=np.full(n, round(w * 1000)),
        std_g=np.full((n, 3), noise_density_g_rthz * np.sqrt(500.0)),
        temp_degC=np.asarray(T, float),
        dtemp_degC_per_s=np.asarray(dTdt, float),
        q_sensor_to_world=q,
        session=f"synthetic-{seed}",
    )
    drv = obs_drivers(obs, extra_drivers(obs) if extra_drivers is not None else None)
    f = model.truth_g(theta, up, q, gravity_g)
    meas = model.predict(theta, f, drv)
    if extra is not None:
        meas = meas + extra(obs)
    obs.meas_g = meas + rng.standard_normal((n, 3)) * sigma
    return obs


def true_theta(model: Model, values: Mapping[str, float] | None = None, seed: int = 1) -> np.ndarray:
    """Plausible MPU-9250 parameters: bias ~ 50 mg, scale 1 +- 2 %, cross-axis ~ 1 %, other
    effects at their typical size (random signs), overridden by `values`."""
    rng = np.random.default_rng(seed)
    th = model.initial_theta()
    for e in model.effects:
        sl = model.slices[e.name]
        if e.name in LIBRARY and e.name not in ("warmup", "fixture_tilt"):
            th[sl] = th[sl] + np.array([p.typical for p in e.params]) * rng.choice(
                [-1.0, 1.0], len(e.params)
            ) * rng.uniform(0.7, 1.3, len(e.params))
        if e.name == "warmup":
            th[sl] = [4e-3, -3e-3, 5e-3, 90.0]
        if e.name == "fixture_tilt":
            th[sl] = [3e-3, -2e-3]
    for k, v in (values or {}).items():
        th[model.index[k]] = v
    return th


def synthetic_session(
    model: Model,
    theta: np.ndarray,
    *,
    protocol: str | Sequence[PoseSpec] = "six",
    hold_s: float = 10.0,
    move_s: float = 2.0,
    rate_hz: float = 200.0,
    noise_density_g_rthz: float = 300e-6,
    temp_path: Callable[[np.ndarray], np.ndarray] | None = None,
    eps_clock: float = 0.0,
    lsb_per_g: float = 16384.0,
    seed: int = 0,
):
    """A labelled Session of static holds sampled at rate_hz straight from the measurement equation
    (white noise of the given density, counts quantised at lsb_per_g). Host time runs
    (1 + eps_clock) faster than sensor time, plus 1 ms of read jitter."""
    from accellog.core.session import PoseLabel, Session, SessionMeta

    poses = parse_protocol(protocol, hold_s) if isinstance(protocol, str) else list(protocol)
    rng = np.random.default_rng(seed)
    dur = len(poses) * (hold_s + move_s) + move_s
    n = int(dur * rate_hz)
    t = np.arange(n) / rate_hz
    labels, up, q = [], np.zeros((n, 3)), np.zeros((n, 4))
    for k, p in enumerate(poses):
        s0 = move_s + k * (hold_s + move_s)
        labels.append(PoseLabel(p.name, s0, s0 + hold_s, p.up_sensor, p.q_sensor_to_world, k))
        m = t >= s0 - move_s
        up[m] = p.up_sensor
        q[m] = p.q_sensor_to_world
    up[~np.any(up, axis=1)] = poses[0].up_sensor
    q[~np.any(q, axis=1)] = poses[0].q_sensor_to_world
    T = temp_path(t) if temp_path is not None else np.full(n, 25.0)
    drv = {"t_s": t, "temp_degC": T, "t_in_pose_s": np.zeros(n), "dtemp_degC_per_s": np.gradient(T, t)}
    f = model.truth_g(theta, up, q, 1.0)
    a = model.predict(theta, f, drv) + rng.standard_normal((n, 3)) * noise_density_g_rthz * np.sqrt(
        rate_hz / 2
    )
    counts = np.clip(np.round(a * lsb_per_g), -32768, 32767).astype(np.int32)
    host = t * (1.0 + eps_clock) + rng.uniform(0.0, 1e-3, n)
    meta = SessionMeta(
        source="emulator",
        accel_range_g=2.0,
        accel_lsb_per_g=lsb_per_g,
        sample_rate_hz=rate_hz,
        software="synthetic",
    )
    return Session(
        meta=meta,
        t_s=t,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=counts / lsb_per_g,
        accel_counts=counts,
        temp_degC=T,
        host_time_s=host,
        poses=labels,
    )


def hold_disturbance(tilt_rad: float, wander_g: float, seed: int):
    """extra(obs) -> (n,3) g: a per-hold placement tilt error of the truth plus a per-hold bias offset."""

    def extra(obs):
        rng = np.random.default_rng(10_000 + seed)
        pid = np.asarray(obs.pose_id)
        holds = np.unique(pid)
        out = np.zeros((obs.n, 3))
        wander = rng.standard_normal((holds.size, 3)) * wander_g
        for k, h in enumerate(holds):
            m = pid == h
            q = quat_from_rotvec(rng.standard_normal(3) * tilt_rad)
            up = np.asarray(obs.up_sensor, float)[m]
            out[m] = rotate(q, up) - up + wander[k]
        return out

    return extra
