"""segment: pose statistics, windowed observations, pose-mean tables, static checks and detection.

The seeded labelled session is `support.sessions.synth_session`.
"""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from support.sessions import B_TRUE, S_TRUE, synth_session

from accellog.calibrate.observe.detect import detect_static, with_labels
from accellog.calibrate.observe.segment import check_coverage, obs_from_pose_means, observations, pose_stats
from accellog.calibrate.observe.stream_segment import segment_blocks
from accellog.core.errors import InputError, ModelError


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


@pytest.mark.parametrize("seed", range(3))
def test_detect_static_keeps_a_still_minute_whole(seed):
    """A still minute at 1 kHz is one interval: the moving variance's own noise crosses the tightest
    threshold (2x its 5th percentile) here and there, which cut it into 14-16 pieces."""
    # AR(1) noise, phi 0.8 (a low-pass filtered chip): the variance over 101 samples scatters more
    s = synth_session(poses=["+z"], hold_s=60.0, move_s=0.0, rate_hz=1000.0, phi=0.8, jitter=0.0, seed=seed)
    (hold,) = detect_static(s, min_poses=1)
    assert hold.start_s < s.t_s[0] + 0.1 and hold.end_s > s.t_s[-1] - 0.1


def _blocks(s, size: int) -> list:
    """The session's samples as blocks of `size` samples (what a file's chunks give)."""
    return [
        SimpleNamespace(
            t_s=s.t_s[i : i + size], accel_g=s.accel_g[i : i + size], temp_degC=s.temp_degC[i : i + size]
        )
        for i in range(0, s.n, size)
    ]


@pytest.mark.parametrize("size", [97, 1000, 10**6])
def test_holds_cut_across_blocks_give_the_table_of_one_block(size):
    """segment_blocks gathers each hold from the blocks that hold it: the table (and the statistics)
    does not depend on where the blocks cut the holds."""
    s = synth_session(seed=8, hold_s=6.0)
    s.temp_degC = 25.0 + 0.01 * s.t_s  # a warming sensor: the temperature columns too
    one, stats = observations(s, window_s=1.0, trim_s=0.3), pose_stats(s, trim_s=0.3)
    got: list = []
    cut = segment_blocks(s.meta, s.poses, _blocks(s, size), 1.0, 0.3, where="w", stats_out=got)
    for f in dataclasses.fields(one):
        x, y = getattr(one, f.name), getattr(cut, f.name)
        assert np.array_equal(x, y) if isinstance(x, np.ndarray) else (f.name == "session" or x == y), f.name
    assert one.temp_degC is not None and one.n > 6 * 4
    assert [a.to_dict() for a in got] == [b.to_dict() for b in stats]


def test_session_wide_refusals_come_after_every_holds_own():
    """A hold's own defect (too short) is named before a wrong reading of an earlier hold (units,
    label), and units before labels, labels before motion, whatever the hold order."""
    s = synth_session(seed=9)
    poses = sorted(s.poses, key=lambda p: p.start_s)
    sl = s.slice_time(poses[0].start_s, poses[0].end_s)
    s.accel_g[sl] *= 3.0  # hold 1: |a| = 3 g
    s.poses = [*poses[:1], dataclasses.replace(poses[1], up_sensor=(0.0, 0.0, -1.0) if poses[1].name != "-z"
               else (0.0, 0.0, 1.0)), *poses[2:-1], dataclasses.replace(poses[-1], end_s=poses[-1].start_s + 1.04)]  # fmt: skip
    with pytest.raises(InputError, match=rf"pose {poses[-1].name!r} .* has \d+ samples after trimming"):
        observations(s)
    s.poses = s.poses[:-1]
    with pytest.raises(InputError, match=r"\|accel\| at rest is 3"):
        observations(s)
    s.accel_g[sl] /= 3.0
    with pytest.raises(InputError, match=rf"pose {poses[1].name!r} .*measured gravity is .* from the label"):
        observations(s)
