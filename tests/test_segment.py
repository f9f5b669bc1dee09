"""segment: pose statistics, windowed observations, pose-mean tables, static checks and detection.

`synth_session` (also imported by the other batch-stage tests) builds a seeded labelled session:
reading = S f + b + AR(1) noise, quantised to counts, f = g_scale * up.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from accellog.calibrate.detect import detect_static, with_labels
from accellog.calibrate.segment import check_coverage, obs_from_pose_means, observations, pose_stats
from accellog.core.errors import InputError, ModelError
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


def test_pose_stats_means_and_autocorr_sem():
    s = synth_session(hold_s=20.0, seed=1)
    st = pose_stats(s)
    assert [p.name for p in st] == ["+z", "-z", "+y", "-y", "+x", "-x"]
    for p in st:
        expect = S_TRUE @ p.up_sensor + B_TRUE
        # mean within 5 autocorrelation-aware standard errors
        assert np.all(np.abs(p.mean_g - expect) < 5 * p.sem_g + 1e-5)
        # AR(1) phi=0.5: tau = (1+phi)/(1-phi) = 3
        assert np.all((p.tau_samples > 2.0) & (p.tau_samples < 4.5))
        assert p.start_s >= s.poses[0].start_s
        assert p.temp_degC == pytest.approx(30.0, abs=0.2)
        assert p.dtemp_degC_per_s == pytest.approx(0.001, rel=1e-6)


def test_observations_windows_fill_all_columns():
    s = synth_session(hold_s=10.0, seed=2)
    obs = observations(s, window_s=2.0, trim_s=0.5)
    # 9 s usable per hold -> 4 windows of 2.25 s
    assert obs.n == 6 * 4
    assert obs.pose_names == ["+z", "-z", "+y", "-y", "+x", "-x"]
    assert np.all(obs.t_in_pose_s > 0.5) and np.all(obs.t_in_pose_s < 9.5)
    assert np.all(obs.n_samples > 300)
    assert obs.temp_degC is not None and np.allclose(obs.dtemp_degC_per_s, 0.001, atol=1e-6)
    assert np.all(np.isfinite(obs.q_sensor_to_world))
    expect = obs.up_sensor @ S_TRUE.T + B_TRUE
    z = (obs.meas_g - expect) / obs.sigma_g
    # standard errors are honest: normalised residuals have unit scale (not 1/sqrt(tau))
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.6


def test_obs_from_pose_means_and_duplicates():
    up = np.eye(3)[[2, 2, 1, 1, 0, 0]] * np.array([1, -1, 1, -1, 1, -1])[:, None]
    obs = obs_from_pose_means(up, up * 1.01, np.full((6, 3), 0.004), 5400)
    assert obs.pose_names == ["+z", "-z", "+y", "-y", "+x", "-x"]
    assert np.allclose(obs.sigma_g, 0.004 / np.sqrt(5400))
    with pytest.raises(InputError, match=r"more than once"):
        obs_from_pose_means(up[[0, 0, 2, 3, 4, 5]], up, np.full((6, 3), 0.004), 100)


def test_coverage_names_missing_faces():
    s = synth_session(poses=["+z", "-z", "+y", "-y", "+x"], seed=3)
    obs = observations(s)
    check_coverage(obs)  # five faces still determine S and b (rank [up 1] = 4)
    s2 = synth_session(poses=["+z", "-z", "+y"], seed=3)
    with pytest.raises(ModelError, match=r"missing .*-x"):
        check_coverage(observations(s2))


def test_moving_hold_is_refused_with_pose_and_time():
    s = synth_session(seed=4)
    p = s.poses[2]
    sl = s.slice_time(p.start_s + 4.0, p.start_s + 5.0)
    s.accel_g[sl] += np.random.default_rng(0).normal(0, 0.2, (sl.stop - sl.start, 3))
    with pytest.raises(
        InputError, match=r"pose '\+y' is labelled static but moves at t = 28\.\d+-2[89]\.\d+ s"
    ):
        observations(s)


def test_units_and_nan_and_short_holds():
    s = synth_session(seed=5)
    s.accel_g = s.accel_counts.astype(float)  # counts declared as g
    with pytest.raises(InputError, match=r"counts declared as g"):
        pose_stats(s)
    s = synth_session(seed=5)
    s.accel_g[s.slice_time(30.0, 30.01)] = np.nan
    with pytest.raises(InputError, match=r"NaN"):
        observations(s)
    s = synth_session(seed=5, hold_s=1.0)
    with pytest.raises(InputError, match=r"samples after trimming"):
        observations(s, trim_s=0.45, min_samples=50)


def test_detect_static_finds_holds_and_refuses_too_few():
    s = synth_session(seed=6, hold_s=4.0, move_s=2.0, label=False, phi=0.0, noise_g=0.002)
    labels = detect_static(s, min_poses=6)
    assert len(labels) >= 6
    ups = np.array([lab.up_sensor for lab in labels])
    truth = {tuple(np.round(u)) for u in ups}
    assert len(truth) == 6
    obs = observations(with_labels(s, labels), check_moving=True)
    assert obs.n >= 6
    with pytest.raises(InputError, match=r"found at most 6 distinct static orientations \(need >= 9"):
        detect_static(s, min_poses=9)
