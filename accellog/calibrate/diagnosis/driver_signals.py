"""Driver signals against the residual: what the model misses, even when the effect library lacks it.

Each signal (temperature, its rate, t, t_in_pose, gravity components, squares, products, rotation
about the vertical, user signals) is projected onto the whitened residual after removing what the
model can already absorb: dchi2 = (r . c_perp)^2 / |c_perp|^2 per (signal, axis), tested with
F = dchi2 / ((chi2 - dchi2) / dof), p = P(F_{1, dof} > F), significant when p < ALPHA / n_tests
(Bonferroni) and dchi2 > 25.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from scipy import linalg

from accellog.calibrate.model.effects import AXES
from accellog.calibrate.model.fit import FitResult
from accellog.core.numeric import f_sf
from accellog.core.rotations import quat_between, quat_conjugate, quat_multiply
from accellog.core.session import ObsTable

ALPHA = 1e-3
"""Family-wise false-alarm rate of the candidate tests (Bonferroni over candidates)."""
MIN_DRIVER_R2 = 0.25
"""A driver signal is offered as what the residual follows only when it explains at least this
share of it (partial R^2): a signal explaining 8 % of an untouched recording's residual is not."""


def _yaw_deg(obs: ObsTable) -> np.ndarray | None:
    """Rotation about the vertical of each row (deg): q = q_yaw * q_face, q_face = up -> +z."""
    q = obs.q_sensor_to_world
    if q is None or not np.all(np.isfinite(q)):
        return None
    q = np.asarray(q, float)
    up = np.asarray(obs.up_sensor, float)
    faces, row_face = np.unique(up, axis=0, return_inverse=True)  # a few faces, many rows
    qf = np.stack([quat_between(u, np.array([0.0, 0.0, 1.0])) for u in faces])[row_face.reshape(-1)]
    qy = quat_multiply(q, quat_conjugate(qf))
    return np.rad2deg(2.0 * np.arctan2(qy[:, 3], qy[:, 0]))


def driver_signal_table(
    obs: ObsTable, drivers: Mapping[str, np.ndarray], gravity_g: float = 1.0
) -> dict[str, np.ndarray]:
    """Candidate explanatory signals, each (n,) or (n,3) (per-axis), named with units."""
    f = gravity_g * np.asarray(obs.up_sensor, float)
    sig: dict[str, np.ndarray] = {}
    if "temp_degC" in drivers:
        dT = drivers["temp_degC"] - 25.0
        sig["temp_degC"] = dT
        sig["temp_degC^2"] = dT**2
        sig["temp_degC*f_axis (g degC)"] = dT[:, None] * f
    if "dtemp_degC_per_s" in drivers:
        sig["dtemp_degC_per_s"] = drivers["dtemp_degC_per_s"]
    sig["t_s"] = drivers["t_s"]
    sig["t_s^2"] = drivers["t_s"] ** 2
    sig["exp(-t_s/60)"] = np.exp(-drivers["t_s"] / 60.0)
    sig["exp(-t_s/600)"] = np.exp(-drivers["t_s"] / 600.0)
    sig["t_in_pose_s"] = drivers["t_in_pose_s"]
    sig["t_in_pose_s^2"] = drivers["t_in_pose_s"] ** 2
    for i, a in enumerate(AXES):
        sig[f"f_{a} (g)"] = f[:, i]
        sig[f"f_{a}^2 (g^2)"] = f[:, i] ** 2
        sig[f"f_{a}^3 (g^3)"] = f[:, i] ** 3
        sig[f"|f_{a}| (g)"] = np.abs(f[:, i])
    for i, j in ((0, 1), (0, 2), (1, 2)):
        sig[f"f_{AXES[i]}*f_{AXES[j]} (g^2)"] = f[:, i] * f[:, j]
    yaw = _yaw_deg(obs)
    if yaw is not None:
        sig["cos(yaw about vertical)"] = np.cos(np.deg2rad(yaw))
        sig["sin(yaw about vertical)"] = np.sin(np.deg2rad(yaw))
    std = {"t_s", "t_in_pose_s", "temp_degC", "dtemp_degC_per_s"}
    for k, v in drivers.items():
        if k not in std:
            sig[k] = np.asarray(v, float)
            sig[f"{k}^2"] = np.asarray(v, float) ** 2
    return sig


def _orthonormal_basis(J: np.ndarray) -> np.ndarray:
    """Q with orthonormal columns spanning J's (columns with |R_kk| <= 1e-12 max |R_kk| dropped).

    Householder QR of one Fortran copy of J, overwritten by Q (LAPACK geqrf + orgqr in place):
    memory of one Jacobian more, where np.linalg.qr needs four (J is 3 n_obs x n_params)."""
    if not J.shape[1]:
        return np.zeros((J.shape[0], 0))
    Q, R = linalg.qr(np.array(J, order="F"), mode="economic", overwrite_a=True, check_finite=False)
    d = np.abs(np.diag(R))
    keep = d > 1e-12 * max(d.max(), 1e-300)
    return Q if keep.all() else Q[:, keep]


def driver_signals(res: FitResult, obs: ObsTable, drivers: Mapping[str, np.ndarray]) -> list[dict]:
    """Residuals against every driver signal: correlation, partial R^2 and the chi2 drop if the
    signal were added as one more additive term on that axis (after projecting out the model)."""
    sig = np.asarray(obs.sigma_g, float)
    J = res.jacobian
    if J is None:
        raise ValueError("driver signals need the fit's Jacobian, and this fit has none")
    J = J if res.weighted else J / sig.ravel()[:, None]
    rw = res.residual_g / sig
    r = rw.ravel()
    chi2 = float(r @ r)
    Q = _orthonormal_basis(J)
    del J  # a recomputed Jacobian is freed here: Q took its place
    dof = max(res.dof - 1, 1)
    rows: list[dict[str, Any]] = []
    table = driver_signal_table(obs, drivers, res.gravity_g)
    n_tests = 3 * len(table)
    for name, s in table.items():
        s = np.asarray(s, float)
        for i, a in enumerate(AXES):
            col = s[:, i] if s.ndim == 2 else s
            if np.ptp(col) == 0:
                continue
            c = np.zeros_like(rw)
            c[:, i] = col / sig[:, i]
            c = c.ravel()
            cp = c - Q @ (Q.T @ c)
            nc = float(cp @ cp)
            if nc <= 1e-12 * float(c @ c):
                continue  # the model already contains this signal on this axis
            d = float(r @ cp) ** 2 / nc
            F = d / max((chi2 - d) / dof, 1e-300)
            p = f_sf(F, 1, dof)
            corr = float(np.corrcoef(rw[:, i], col)[0, 1]) if np.std(rw[:, i]) > 0 else 0.0
            rows.append(
                {
                    "signal": name,
                    "axis": a,
                    "correlation": corr,
                    "partial_r2": d / chi2 if chi2 > 0 else 0.0,
                    "delta_chi2": d,
                    "p_value": p,
                    "significant": bool(p < ALPHA / n_tests and d > 25.0),
                }
            )
    rows.sort(key=lambda x: -x["delta_chi2"])
    return rows
