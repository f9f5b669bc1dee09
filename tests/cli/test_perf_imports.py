"""What the long-running commands import, and the scipy.special forms that keep scipy.stats (~0.8 s of
CPU at start-up) out of `diagnose`: equal to scipy.stats' own survival functions."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats
from support.synthetic import synthetic_obs, synthetic_session, true_theta

from accellog.calibrate.model.compose import build_model
from accellog.core.numeric import f_sf, normal_sf
from accellog.store.writer import write_session

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("x", [-1.0, 0.0, 1e-300, 0.3, 3.2, 50.0, np.inf, np.nan])
@pytest.mark.parametrize("d1,d2", [(1, 5), (2, 100), (4, 20), (0, 3), (3, 1e6)])
def test_f_sf_is_scipy_stats(x, d1, d2):
    np.testing.assert_equal(f_sf(x, d1, d2), float(stats.f.sf(x, d1, d2)))


@pytest.mark.parametrize("z", [-3.0, 0.0, 1.5, 8.0, 40.0, np.inf, np.nan])
def test_normal_sf_is_scipy_stats(z):
    np.testing.assert_equal(normal_sf(z), float(stats.norm.sf(z)))


LAZY_FOR_DIAGNOSE = (
    "scipy.stats",
    "rerun",
    "pyarrow",
    "dask",
    "accellog.flows.stages",  # whole-session readers and importers (~0.12 s CPU): streamed instead
    "accellog.present.tables",  # table module (calibrate.calfile, navigate): --json is core.jsonio
    "accellog.present.discovery_text",  # the terminal views: not with --json
)


def test_diagnose_loads_no_scipy_stats(tmp_path):
    """`accellog diagnose --json` on a labelled MCAP session runs without importing scipy.stats (nor
    rerun, pyarrow, dask, the whole-session stages or the terminal tables): each would add to every
    run's start-up."""
    model = build_model("model3")
    s = synthetic_session(model, true_theta(model), hold_s=4.0, rate_hz=100.0, seed=3)
    path = write_session(tmp_path / "s.mcap", s)
    code = (
        "import sys, io, contextlib\nfrom accellog.cli import main\n"
        f"with contextlib.redirect_stdout(io.StringIO()): rc = main(['diagnose', {str(path)!r}, '--json'])\n"
        f"print(rc, ' '.join(m for m in {LAZY_FOR_DIAGNOSE!r} if m in sys.modules))"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    rc, *loaded = out.stdout.split()
    assert rc == "0" and loaded == []


def test_evaluate_loads_no_diagnosis(tmp_path):
    """`accellog evaluate --json` of a static test imports neither the diagnosis nor its driver
    signals (scipy.linalg; 0.12 s of CPU and 20 MB on every evaluate when the hand-held verdict's
    list of what the norm cannot see was imported from the diagnosis)."""
    model = build_model("model3")
    s = synthetic_session(model, true_theta(model), hold_s=4.0, rate_hz=100.0, seed=3)
    path = write_session(tmp_path / "s.mcap", s)
    cal = tmp_path / "cal.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    subprocess.run([sys.executable, "-m", "accellog", "fit", str(path), "-o", str(cal)], env=env, check=True,
                   capture_output=True)  # fmt: skip
    lazy = (
        "accellog.calibrate.diagnosis.diagnose",
        "accellog.calibrate.diagnosis.driver_signals",
        "scipy.stats",
    )
    code = (
        "import sys, io, contextlib\nfrom accellog.cli import main\n"
        f"with contextlib.redirect_stdout(io.StringIO()): rc = main(['evaluate', {str(path)!r}, '--cal', "
        f"{str(cal)!r}, '--json'])\n"
        f"print(rc, ' '.join(m for m in {lazy!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    rc, *loaded = out.stdout.split()
    assert rc == "0" and loaded == []


def test_yaw_per_face_equals_per_row():
    """driver_signals._yaw_deg forms the face rotation once per face: the same angles, bit for bit,
    as one quat_between per row (24 poses: 6 faces x 4 yaw angles, 6 windows each)."""
    from accellog.calibrate.diagnosis.driver_signals import _yaw_deg
    from accellog.core.rotations import quat_between, quat_conjugate, quat_multiply

    model = build_model("model3")
    obs = synthetic_obs(model, true_theta(model), protocol="24", hold_s=12.0, seed=2)
    z = np.array([0.0, 0.0, 1.0])
    qf = np.stack([quat_between(u, z) for u in np.asarray(obs.up_sensor, float)])
    qy = quat_multiply(np.asarray(obs.q_sensor_to_world, float), quat_conjugate(qf))
    want = np.rad2deg(2.0 * np.arctan2(qy[:, 3], qy[:, 0]))
    got = _yaw_deg(obs)
    assert got is not None and np.array_equal(got, want)
    assert np.unique(np.round(got)).size > 1  # the yaw really varies


def test_host_clock_taken_in_the_observation_pass(tmp_path):
    """observe_riding with a HostClock takes the host clock points in the observation pass (as
    diagnose does): the same line fit as a pass of their own (store.stream.read_host_clock)."""
    from accellog.calibrate.observe.segment import observe_riding
    from accellog.store.source import open_source
    from accellog.store.stream import HostClock, read_host_clock

    model = build_model("model3")
    s = synthetic_session(model, true_theta(model), hold_s=4.0, rate_hz=100.0, eps_clock=20e-6, seed=4)
    path = write_session(tmp_path / "s.mcap", s)
    want = read_host_clock(path)
    got = observe_riding(open_source(path), rider=lambda _s: HostClock())[1].result()
    assert want is not None and got is not None and want.count > 5
    assert (want.slope, want.residual_ss, want.count) == (got.slope, got.residual_ss, got.count)


def test_fit_takes_the_gyro_first_pass_in_the_observation_pass(tmp_path, monkeypatch):
    """`fit` on a labelled MCAP file reads the samples twice (observations + the gyro's bias
    windows, then the gyro's moves), not three times, and its gyro calibration is the one of
    calibrate_blocks' own passes on the file, exactly (many small blocks: windows span them)."""
    from accellog.calibrate.gyro import stream as stream_gyro
    from accellog.calibrate.gyro.calibrate import gyro_full_scale_dps
    from accellog.flows.simulate import Scenario, simulate
    from accellog.flows.stages import run_fit
    from accellog.store import source
    from accellog.store.mcap import fastread
    from accellog.store.stream import read_labels

    path = tmp_path / "six.mcap"
    simulate(Scenario(protocol="six", hold_s=3.0, move_s=1.0, sample_rate_hz=500.0), path)
    monkeypatch.setattr(fastread, "_GROUP_BYTES", 32 << 10)
    meta, poses, _ = read_labels(path)
    want = stream_gyro.calibrate_blocks(
        source.open_source(path), poses, full_scale_dps=gyro_full_scale_dps(meta)
    )
    passes = []
    real = source.iter_imu
    monkeypatch.setattr(source, "iter_imu", lambda p: passes.append(p) or real(p))
    got = run_fit(str(path)).cal.gyro
    assert len(passes) == 2
    assert want is not None and got is not None and got.to_dict() == want.to_dict()
