"""A seeded labelled session for the batch-stage tests: reading = S f + b + AR(1) noise, quantised
to counts, f = g_scale * up; and a JSON comparison within a relative tolerance."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.signal import lfilter

from accellog.core.protocol import PoseSpec, six_position
from accellog.core.session import PoseLabel, Session, SessionMeta

S_TRUE = np.array([[1.01, 0.004, -0.006], [0.003, 0.985, 0.008], [-0.005, 0.002, 1.02]])
B_TRUE = np.array([0.03, -0.02, 0.05])


def synth_session(
    *,
    S: np.ndarray = S_TRUE,
    b: np.ndarray = B_TRUE,
    poses: list[str] | None = None,
    hold_s: float = 10.0,
    move_s: float = 2.0,
    rate_hz: float = 200.0,
    noise_g: float = 0.003,
    phi: float = 0.5,
    g_scale: float = 1.0,
    seed: int = 0,
    lsb_per_g: float = 16384.0,
    jitter: float = 0.2,
    temp_degC: float = 30.0,
    label: bool = True,
    ups: np.ndarray | None = None,
) -> Session:
    """Labelled six-pose (or given poses, or arbitrary unit up vectors `ups`) session; moves between
    holds are smooth turns."""
    rng = np.random.default_rng(seed)
    specs = six_position(hold_s) if poses is None else [s for s in six_position(hold_s) if s.name in poses]
    if ups is not None:
        specs = [
            PoseSpec(f"u{i}", tuple(float(v) for v in u / np.linalg.norm(u)), (1.0, 0.0, 0.0, 0.0), hold_s)
            for i, u in enumerate(ups)
        ]
    n_per = round((hold_s + move_s) * rate_hz)
    n = n_per * len(specs)
    dt = (1.0 + jitter * (rng.random(n) - 0.5)) / rate_hz  # uneven sample times
    t = np.concatenate([[0.0], np.cumsum(dt[:-1])])
    f = np.zeros((n, 3))
    labels = []
    for i, sp in enumerate(specs):
        t0 = t[i * n_per]
        t_hold_end = t0 + hold_s
        up = np.array(sp.up_sensor)
        nxt = np.array(specs[i + 1].up_sensor) if i + 1 < len(specs) else up
        seg = slice(i * n_per, (i + 1) * n_per)
        ts = t[seg]
        w = np.clip((ts - t_hold_end) / max(move_s, 1e-9), 0.0, 1.0)[:, None]
        v = (1 - w) * up + w * nxt + np.sin(np.pi * w) * np.array([0.6, 0.5, 0.4])  # never through 0
        f[seg] = g_scale * v / np.linalg.norm(v, axis=1, keepdims=True)
        labels.append(PoseLabel(sp.name, float(t0), float(t_hold_end), sp.up_sensor, sp.q_sensor_to_world, 0))
    white = rng.normal(0.0, noise_g * np.sqrt(1 - phi**2), (n, 3))
    noise = lfilter([1.0], [1.0, -phi], white, axis=0)
    reading = f @ S.T + b + noise
    counts = np.clip(np.round(reading * lsb_per_g), -32768, 32767).astype(np.int32)
    meta = SessionMeta(source="emulator", accel_lsb_per_g=lsb_per_g, sample_rate_hz=rate_hz, accel_range_g=2)
    return Session(
        meta=meta,
        t_s=t,
        sample_index=np.arange(n),
        accel_g=counts / lsb_per_g,
        accel_counts=counts,
        temp_degC=np.full(n, temp_degC) + 0.001 * t,
        poses=labels if label else [],
        path="synthetic.mcap",
    )


RTOL = 1e-9


def assert_json_close(a, b, path: str = "") -> None:
    """Same keys, same strings, floats within RTOL relative (or 1e-15 absolute near zero)."""
    if isinstance(a, dict):
        assert set(a) == set(b), (path, set(a) ^ set(b))
        for k in a:
            assert_json_close(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_json_close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):  # NaN (the 60 s of a 40 s session) too
        assert b == pytest.approx(a, rel=RTOL, abs=1e-15, nan_ok=True), path
    else:
        assert a == b, (path, a, b)


def random_blocks(n: int, rng: np.random.Generator, cuts: list[int] = ()) -> list[slice]:
    """Irregular slices covering range(n), with edges at `cuts` too."""
    edges = sorted({0, n, *cuts, *rng.integers(1, n, size=max(n // 3000, 3)).tolist()})
    return [slice(a, b) for a, b in itertools.pairwise(edges)]
