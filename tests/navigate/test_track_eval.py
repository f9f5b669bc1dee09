"""Track evaluation and the `accellog track` pipeline: the ordering physics predicts, on simulated runs.

Two levels: (1) errors made directly from the measurement equation with numpy (self-contained);
(2) the emulator's SensorModel -> MCAP -> calibrations fitted by accellog.calibrate.model.fit -> `accellog track`.
"""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest

from accellog.acquire.emulator.robot import RobotPathMotion, Segment, demo_loop
from accellog.core.errors import InputError
from accellog.core.session import POSE_UP_VECTORS, ObsTable, Session, SessionMeta
from accellog.navigate.strapdown import Track
from accellog.navigate.track_eval import evaluate_track, loop_closure, run_session_tracks, run_tracks

UP6 = np.array(list(POSE_UP_VECTORS.values()))
C_ERR = np.array([[0.0, 0.012, -0.010], [0.008, 0.0, 0.011], [-0.009, 0.010, 0.0]])
"""Cross-axis error (dimensionless) used in the ordering tests."""
S_ERR = np.diag(1.0 + np.array([0.02, -0.015, 0.025])) + C_ERR
B0 = np.array([0.03, -0.02, 0.05])  # g
BT = np.array([0.0015, -0.001, 0.002])  # g/degC: the hidden effect


def test_evaluate_track_against_truth():
    t = np.linspace(0.0, 10.0, 101)
    truth = np.stack([t, 0 * t, 0 * t], axis=1)
    err = np.stack([0 * t, 0.1 * t, 0 * t], axis=1)
    tr = Track(t, np.tile([1.0, 0, 0, 0], (t.size, 1)), np.zeros((t.size, 3)), truth + err, name="x")
    e = evaluate_track(tr, t[::2], truth[::2])  # truth on a coarser grid: interpolated
    assert e.reference == "truth" and e.name == "x"
    assert e.final_error_m == pytest.approx(1.0)
    assert e.rms_error_m == pytest.approx(np.sqrt(np.mean((0.1 * t) ** 2)))
    assert e.path_length_m == pytest.approx(10.0)
    assert e.growth_error_m[-1] == pytest.approx(1.0) and e.growth_error_m[0] == pytest.approx(0.1)
    lc = loop_closure(tr)
    assert lc.reference == "loop_closure" and lc.final_error_m == pytest.approx(np.hypot(10.0, 1.0))
    assert np.isnan(lc.rms_error_m)


def _fit_numpy(obs_up: np.ndarray, obs_meas: np.ndarray, dT: np.ndarray | None = None):
    """Least-squares meas = S up + b (+ b_T dT) on static pose means; returns (S, b, b_T)."""
    cols = [obs_up, np.ones((len(obs_up), 1))] + ([dT[:, None]] if dT is not None else [])
    X, *_ = np.linalg.lstsq(np.hstack(cols), obs_meas, rcond=None)
    return X[:3].T, X[3], (X[4] if dT is not None else np.zeros(3))


@pytest.fixture(scope="module")
def numpy_run():
    """Demo loop at 100 Hz; accel a' = S f + b0 + b_T (T - 25) + noise, T 25 -> 45 degC; gyro noise."""
    m = demo_loop()
    t = np.arange(0.0, m.duration_s, 0.01)
    k = m.kinematics(t)
    rng = np.random.default_rng(7)
    temp = 25.0 + 20.0 * t / t[-1]

    def meas(f, temp_c):
        return f @ S_ERR.T + B0 + np.multiply.outer(temp_c - 25.0, BT)

    a = meas(k.specific_force_g, temp) + rng.normal(0, 0.003, (t.size, 3))
    w = k.omega_dps + rng.normal(0, 0.05, (t.size, 3))
    # calibration holds: six poses at 25 degC (models 1, 3) and at 20 + 40 degC (found effects)
    y25 = meas(UP6, np.full(6, 25.0)) + rng.normal(0, 2e-4, (6, 3))
    b1 = (y25 - UP6).mean(axis=0)
    S3, b3, _ = _fit_numpy(UP6, y25)
    y2 = np.vstack([meas(UP6, np.full(6, 20.0)), meas(UP6, np.full(6, 40.0))]) + rng.normal(0, 2e-4, (12, 3))
    S4, b4, bt4 = _fit_numpy(np.vstack([UP6, UP6]), y2, np.r_[np.full(6, -5.0), np.full(6, 15.0)])
    corr = {
        "raw": None,
        "model1": lambda x: x - b1,
        "model3": lambda x: np.linalg.solve(S3, (x - b3).T).T,
        "model3+temp_bias": lambda x: np.linalg.solve(S4, (x - b4 - np.multiply.outer(temp - 25.0, bt4)).T).T,
    }
    kw = dict(
        local_gravity_mps2=9.80665,
        truth_t_s=t,
        truth_position_m=k.position_m,
        truth_q0=k.q_sensor_to_world[0],
    )
    plain = {r.name: r.error for r in run_tracks(t, a, w, corr, use_zupt=False, **kw)}
    zupted = {r.name: r for r in run_tracks(t, a, w, corr, use_zupt=True, **kw)}
    return plain, zupted


def test_ordering_physics_predicts(numpy_run):
    """raw > model1 (bias) > model3 (cross-axis) > model3+temp_bias (the hidden effect), final and RMS.

    Measured: final 1810 / 789 / 269 / 12 m, RMS 788 / 332 / 105 / 5 m over the 64 s loop.
    """
    plain, _ = numpy_run
    order = ["raw", "model1", "model3", "model3+temp_bias"]
    for worse, better in itertools.pairwise(order):
        assert plain[better].final_error_m < 0.6 * plain[worse].final_error_m, (worse, better)
        assert plain[better].rms_error_m < 0.6 * plain[worse].rms_error_m, (worse, better)


def test_zupt_helps_every_calibration(numpy_run):
    _, zupted = numpy_run
    for name, r in zupted.items():
        assert r.error.zupt_stops == 9
        assert r.error.final_error_m < 0.05 * r.error_without_zupt.final_error_m, name
        assert r.error.rms_error_m < 0.05 * r.error_without_zupt.rms_error_m, name
    # the hidden effect still shows through ZUPT: found effects beat model3
    assert zupted["model3+temp_bias"].error.final_error_m < 0.3 * zupted["model3"].error.final_error_m


# ------------------------------------------------------------ emulator -> MCAP -> accellog track

HZ = 200.0


def _emulated_session(motion, *, gyro: bool = True, seed: int = 3) -> Session:
    from accellog.acquire.emulator.sensor_model import AccelErrors, GyroErrors, SensorModel
    from accellog.acquire.emulator.temperature import TemperaturePath

    accel = AccelErrors(
        bias_g=B0,
        scale=np.diag(S_ERR) - 1.0,
        cross_axis=C_ERR,
        temp_bias_g_per_degC=BT,
        noise_density_g_per_rtHz=np.full(3, 300e-6),
    )
    gyr = GyroErrors(bias_dps=np.array([0.8, -0.5, 0.3]), noise_density_dps_per_rtHz=np.full(3, 0.01))
    rate = 20.0 / motion.duration_s
    sm = SensorModel(motion, accel=accel, gyro=gyr, temperature=TemperaturePath.ramp(25.0, rate), seed=seed)
    t = np.arange(0.0, motion.duration_s, 1.0 / HZ)
    blk = sm.sample(
        t,
        accel_lsb_per_g=16384.0,
        gyro_lsb_per_dps=131.0,
        odr_hz=HZ,
        accel_bandwidth_hz=92.0,
        gyro_bandwidth_hz=92.0,
    )
    meta = SessionMeta(source="emulator", accel_lsb_per_g=16384.0, gyro_lsb_per_dps=131.0, sample_rate_hz=HZ)
    ac = blk.accel_counts.astype(np.int32)
    gc = blk.gyro_counts.astype(np.int32)
    from accellog.core.units import temp_counts_to_degC

    return Session(
        meta=meta,
        t_s=t,
        sample_index=np.arange(t.size, dtype=np.int64),
        accel_g=ac / 16384.0,
        accel_counts=ac,
        gyro_dps=gc / 131.0 if gyro else None,
        gyro_counts=gc if gyro else None,
        temp_degC=temp_counts_to_degC(blk.temp_counts.astype(float)),
        temp_counts=blk.temp_counts.astype(np.int32),
        poses=motion.labels(),
        truth=sm.truth(t),
    )


def _calibration_file(path, model: str, temps_degC: list[float]):
    """Fit accellog's model to simulated six-pose means (measurement equation of AccelErrors)."""
    from accellog.acquire.emulator.sensor_model import AccelErrors
    from accellog.calibrate.calfile.calibration import Calibration
    from accellog.calibrate.model.compose import build_model
    from accellog.calibrate.model.fit import fit_model

    acc = AccelErrors(bias_g=B0, scale=np.diag(S_ERR) - 1.0, cross_axis=C_ERR, temp_bias_g_per_degC=BT)
    rng = np.random.default_rng(len(temps_degC))
    rows = []
    for tc in temps_degC:
        rows.append(acc.apply(UP6, np.full(6, tc), np.zeros(6)) + rng.normal(0, 1e-4, (6, 3)))
    n = 6 * len(temps_degC)
    obs = ObsTable(
        meas_g=np.vstack(rows),
        sigma_g=np.full((n, 3), 1e-4),
        up_sensor=np.vstack([UP6] * len(temps_degC)),
        pose_id=np.tile(np.arange(6), len(temps_degC)),
        pose_names=list(POSE_UP_VECTORS),
        t_s=np.arange(n, dtype=float) * 30.0,
        t_in_pose_s=np.full(n, 15.0),
        n_samples=np.full(n, 3000),
        std_g=np.full((n, 3), 0.003),
        temp_degC=np.repeat(np.array(temps_degC, float), 6),
    )
    fit = fit_model(obs, build_model(model))
    Calibration.from_fit(fit, obs=obs).save(path)
    return path


@pytest.fixture(scope="module")
def emulated_files(tmp_path_factory):
    from accellog.store.writer import write_session

    d = tmp_path_factory.mktemp("track")
    sess = write_session(d / "loop.mcap", _emulated_session(demo_loop()))
    cals = [
        _calibration_file(d / "model1.json", "model1", [25.0]),
        _calibration_file(d / "model3.json", "model3", [25.0]),
        _calibration_file(d / "found.json", "model3+temp_bias", [20.0, 40.0]),
    ]
    return d, sess, cals


def test_emulated_run_through_cli(emulated_files, capsys):
    from accellog.cli import main

    _d, sess, cals = emulated_files
    args = ["track", str(sess)] + [a for c in cals for a in ("--cal", str(c))]
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["reference"] == "truth" and out["zupt"] is True
    res = {r["name"]: r for r in out["tracks"]}
    assert list(res) == ["raw", "model1", "model3", "found"]
    order = ["raw", "model1", "model3", "found"]
    for worse, better in itertools.pairwise(order):
        assert (
            res[better]["without_zupt"]["final_error_m"] < 0.6 * res[worse]["without_zupt"]["final_error_m"]
        )
    for r in res.values():
        assert r["zupt_stops"] >= 8
        assert r["final_error_m"] < 0.1 * r["without_zupt"]["final_error_m"]
    assert res["found"]["final_error_m"] < res["model3"]["final_error_m"]
    # human table
    assert main(args) == 0
    txt = capsys.readouterr().out
    assert "found" in txt and "vs truth" in txt


def test_loop_closure_without_truth(emulated_files):
    from accellog.store.reader import read_session

    _, sess, _ = emulated_files
    s = read_session(sess)
    s.truth = None
    runs = run_session_tracks(s, {}, use_zupt=True)
    assert runs[0].error.reference == "loop_closure"
    assert runs[0].error.final_error_m < 0.1 * runs[0].error_without_zupt.final_error_m


def test_cli_bad_input(tmp_path, capsys):
    from accellog.cli import main
    from accellog.store.writer import write_session

    no_gyro = write_session(tmp_path / "nogyro.mcap", _emulated_session(demo_loop(), gyro=False))
    assert main(["track", str(no_gyro)]) != 0
    err = capsys.readouterr().err
    assert err.startswith("accellog: error:") and "no gyro data" in err and err.count("\n") == 1
    moving = RobotPathMotion([Segment(0.5, speed_mps=1.0), Segment(8.0)])  # never stands still
    no_stops = write_session(tmp_path / "nostops.mcap", _emulated_session(moving))
    assert main(["track", str(no_stops)]) != 0
    err = capsys.readouterr().err
    assert "no stops" in err and "--no-zupt" in err and err.count("\n") == 1
    assert main(["track", str(tmp_path / "missing.mcap")]) != 0
    assert "accellog: error:" in capsys.readouterr().err


def test_run_tracks_bad_input():
    t = np.linspace(0, 10, 1001)
    s = Session(
        meta=SessionMeta(source="test"), t_s=t, sample_index=np.arange(t.size), accel_g=np.zeros((t.size, 3))
    )
    with pytest.raises(InputError, match="no gyro data"):
        run_session_tracks(s)
