"""Diagnose speed and estimator efficiency.

1. A 24-pose session (30 s holds, 1 kHz, warm-up temperature path, hidden temp_bias) is generated
   sample by sample, cut into 2 s windows by accellog.calibrate.observe.segment.observations (the window step), then
   diagnosed against model3 with every library effect as a candidate (the diagnose step).
   Goal: diagnose < 5 s.
2. Parameter error vs Cramer-Rao bound: over seeds, RMS of (theta_hat - theta) / sigma per parameter
   (1.0 = the fit attains the bound and its reported sigma is right).

3. Scaling with session length (issue 11): diagnose on 24 holds of 2 s windows for 15 min / 1 h /
   4 h sessions (the windows per hold grow with the hold), with the leave-one-hold-out
   cross-validation in the p x p form; the dense per-hold form (the pre-issue-11 cv_scores) is timed
   beside it on the same fit. Goal: diagnose on 1 h < 1.5 s, time linear in the windows.

Run: python benchmarks/bench_diagnose.py [--skip-efficiency]
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from accellog.calibrate.diagnosis.cross_validation import cv_scores
from accellog.calibrate.diagnosis.diagnose import diagnose
from accellog.calibrate.model.compose import build_model
from accellog.calibrate.model.fit import fit_model
from accellog.calibrate.observe.segment import observations

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from support.synthetic import synthetic_obs, synthetic_session, true_theta


def temp(t):
    return 24.0 + 8.0 * (1.0 - np.exp(-t / 400.0)) + 1.5 * np.sin(2 * np.pi * t / 700.0)


def _cv_dense(res, obs):
    """cv_scores before issue 11: a dense 3n x 3n matrix per hold (eigvalsh + solve)."""
    J, sig = res.jacobian, np.asarray(obs.sigma_g, float)
    r = (res.residual_g / sig).ravel()
    A = np.linalg.pinv(J.T @ J)
    for g in np.unique(obs.pose_id):
        rows = (np.flatnonzero(obs.pose_id == g)[:, None] * 3 + np.arange(3)).ravel()
        M = np.eye(rows.size) - J[rows] @ A @ J[rows].T
        np.linalg.eigvalsh(M)
        np.linalg.solve(M, r[rows])


def scaling() -> None:
    truth = build_model("model3+temp_bias")
    th = true_theta(truth, seed=1)
    print(f"diagnose vs session length (24 holds, 2 s windows); load average {os.getloadavg()}")
    print(
        f"{'session':>8}{'windows':>9}{'diag. BLAS thr. s':>18}{'diag. 1 thr. s':>15}{'cv (p x p) s':>14}{'cv dense s':>12}{'dense/pxp':>10}"
    )
    for minutes in (15, 60, 240):
        hold = minutes * 60.0 / 24 - 3.0
        obs = synthetic_obs(truth, th, protocol="24", hold_s=hold, move_s=3.0,
                            windows_per_hold=int(hold // 2), temp_path=temp, seed=3)  # fmt: skip
        t_all = time.perf_counter()
        diagnose(obs, build_model("model3"))  # numpy's default BLAS threads
        t0 = time.perf_counter()
        with threadpool_limits(limits=1, user_api="blas"):  # as the CLI runs it
            diagnose(obs, build_model("model3"))
        t1 = time.perf_counter()
        res = fit_model(obs, build_model("model3"))
        t2 = time.perf_counter()
        cv_scores(res, obs)
        t3 = time.perf_counter()
        dense = ""
        if minutes <= 60:  # the dense form at 4 h takes minutes
            _cv_dense(res, obs)
            dense = f"{time.perf_counter() - t3:>12.3f}{(time.perf_counter() - t3) / (t3 - t2):>10.1f}"
        print(f"{minutes:>6} m{obs.n:>9}{t0 - t_all:>18.3f}{t1 - t0:>15.3f}{t3 - t2:>14.3f}{dense}")
    print("goal: diagnose on 1 h < 1.5 s")
    print()


def main() -> None:
    scaling()
    if "--skip-efficiency" in sys.argv:
        return
    truth = build_model("model3+temp_bias")
    th = true_theta(truth, seed=1)
    t0 = time.perf_counter()
    sess = synthetic_session(
        truth, th, protocol="24", hold_s=30.0, move_s=3.0, rate_hz=1000.0, temp_path=temp
    )
    t1 = time.perf_counter()
    obs = observations(sess, window_s=2.0)
    t2 = time.perf_counter()
    d = diagnose(obs, build_model("model3"))
    t3 = time.perf_counter()
    print(f"session: {sess.n} samples, {len(sess.poses)} holds -> {obs.n} windows")
    print(f"{'step':<34}{'time s':>10}")
    print(f"{'generate samples (not timed goal)':<34}{t1 - t0:>10.3f}")
    print(f"{'windows (segment.observations)':<34}{t2 - t1:>10.3f}")
    print(
        f"{'diagnose, ' + str(len(d.candidates)) + ' candidates':<34}{t3 - t2:>10.3f}   goal < 5 s: {'OK' if t3 - t2 < 5 else 'MISSED'}"
    )
    print(f"{'windows + diagnose':<34}{t3 - t1:>10.3f}")
    print(f"verdict: {d.verdict}")
    print()
    print("parameter error / Cramer-Rao bound (RMS over seeds of (theta_hat - theta)/sigma; 1.0 = efficient)")
    print(
        f"{'model (24 poses, 6 windows/hold)':<36}{'seeds':>6}{'min':>8}{'median':>8}{'max':>8}{'sd/CRB':>8}"
    )
    for name, n in (
        ("model3", 200),
        ("model3+temp_bias+temp_scale", 100),
        ("model3+fixture_tilt+warmup", 60),
    ):
        m = build_model(name)
        tht = true_theta(m, seed=2)
        z, est, sig = [], [], []
        for s in range(n):
            o = synthetic_obs(m, tht, protocol="24", temp_path=temp, seed=500 + s)
            r = fit_model(o, m)
            z.append((r.theta - tht) / r.sigma)
            est.append(r.theta)
            sig.append(r.sigma)
        rms = np.sqrt(np.mean(np.square(z), axis=0))
        sd_ratio = np.median(np.std(est, axis=0, ddof=1) / np.mean(sig, axis=0))
        print(f"{name:<36}{n:>6}{rms.min():>8.2f}{np.median(rms):>8.2f}{rms.max():>8.2f}{sd_ratio:>8.2f}")


if __name__ == "__main__":
    main()
