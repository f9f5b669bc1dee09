"""Strapdown on a 10-minute 1 kHz moving run: each calibration's track error and the integration speed.

Run: python benchmarks/bench_strapdown.py
Errors come from the measurement equation (numpy, seeded): a' = S f + b0 + b_T (T - 25) + noise with
T 25 -> 45 degC; calibrations fitted on simulated six-pose means (model1: bias, model3: full S,
found: model3 + temp_bias). Speed: strapdown() alone, and the prefix-scan attitude versus a
sequential Python loop over the same increments, measured side by side in this run.
"""

from __future__ import annotations

import time

import numpy as np
from rich.console import Console
from rich.table import Table

from accellog.acquire.emulator.robot import long_run
from accellog.core.rotations import prefix_quat_product, quat_from_rotvec, quat_multiply
from accellog.core.session import POSE_UP_VECTORS
from accellog.navigate.strapdown import strapdown
from accellog.navigate.track_eval import run_tracks

HZ = 1000.0


def main() -> None:
    motion = long_run(600.0)
    t = np.arange(0.0, 600.0, 1.0 / HZ)
    k = motion.kinematics(t)
    rng = np.random.default_rng(1)
    S = np.diag([1.02, 0.985, 1.025]) + np.array([[0, 0.012, -0.01], [0.008, 0, 0.011], [-0.009, 0.01, 0]])
    b0, bt = np.array([0.03, -0.02, 0.05]), np.array([0.0015, -0.001, 0.002])
    temp = 25.0 + 20.0 * t / t[-1]
    a = k.specific_force_g @ S.T + b0 + np.multiply.outer(temp - 25.0, bt) + rng.normal(0, 0.004, (t.size, 3))
    w = k.omega_dps + rng.normal(0, 0.1, (t.size, 3))
    up = np.array(list(POSE_UP_VECTORS.values()))

    def fit(up_, y, dT=None):
        cols = [up_, np.ones((len(up_), 1))] + ([dT[:, None]] if dT is not None else [])
        X, *_ = np.linalg.lstsq(np.hstack(cols), y, rcond=None)
        return X[:3].T, X[3], (X[4] if dT is not None else np.zeros(3))

    y25 = up @ S.T + b0
    S3, b3, _ = fit(up, y25)
    y2 = np.vstack([up @ S.T + b0 - 5 * bt, up @ S.T + b0 + 15 * bt])
    S4, b4, bt4 = fit(np.vstack([up, up]), y2, np.r_[np.full(6, -5.0), np.full(6, 15.0)])
    b1 = (y25 - up).mean(axis=0)
    corr = {
        "raw": None,
        "model1": lambda x: x - b1,
        "model3": lambda x: np.linalg.solve(S3, (x - b3).T).T,
        "found": lambda x: np.linalg.solve(S4, (x - b4 - np.multiply.outer(temp - 25, bt4)).T).T,
    }
    kw = dict(
        local_gravity_mps2=9.80665,
        truth_t_s=t,
        truth_position_m=k.position_m,
        truth_q0=k.q_sensor_to_world[0],
    )
    plain = {r.name: r.error for r in run_tracks(t, a, w, corr, use_zupt=False, **kw)}
    zupted = {r.name: r.error for r in run_tracks(t, a, w, corr, use_zupt=True, **kw)}

    n_stops = next(iter(zupted.values())).zupt_stops
    tab = Table(title=f"10-minute 1 kHz robot run ({n_stops} stops used by ZUPT): position error vs truth")
    for c in ("calibration", "final (m)", "RMS (m)", "final, ZUPT (m)", "RMS, ZUPT (m)"):
        tab.add_column(c, justify="right" if c != "calibration" else "left")
    for name in corr:
        p, z = plain[name], zupted[name]
        tab.add_row(
            name,
            f"{p.final_error_m:.4g}",
            f"{p.rms_error_m:.4g}",
            f"{z.final_error_m:.3g}",
            f"{z.rms_error_m:.3g}",
        )
    Console().print(tab)
    Console().print("found = model3 + temp_bias (the hidden effect, fitted from holds at 20 and 40 degC)")

    # speed: strapdown of the whole run (best of 3), and prefix scan vs a sequential loop
    minutes = (t[-1] - t[0]) / 60.0
    best = min(_timed(lambda: strapdown(t, a, w, q0=k.q_sensor_to_world[0])) for _ in range(3))
    n_loop = 60_000
    dq = quat_from_rotvec(np.deg2rad(w[:n_loop]) / HZ)
    scan_s = min(_timed(lambda: prefix_quat_product(dq)) for _ in range(3))
    loop_s = _timed(lambda: _sequential(dq))
    sp = Table(title=f"integration speed ({t.size:,} samples, {minutes:.1f} min of data)")
    sp.add_column("what")
    sp.add_column("value", justify="right")
    sp.add_row("strapdown: s per minute of data", f"{best / minutes:.3f}")
    sp.add_row("strapdown: ratio to real time", f"{minutes * 60.0 / best:.0f}x faster")
    sp.add_row(f"attitude prefix scan vs Python loop ({n_loop:,} steps)", f"{loop_s / scan_s:.0f}x faster")
    Console().print(sp)


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _sequential(dq: np.ndarray) -> np.ndarray:
    out = np.empty_like(dq)
    acc = np.array([1.0, 0.0, 0.0, 0.0])
    for i in range(dq.shape[0]):
        acc = quat_multiply(acc, dq[i])
        out[i] = acc
    return out


if __name__ == "__main__":
    main()
