"""Analytic Jacobians of the measurement equation for the library effects (accellog.calibrate.model.compose).

Per row, a = M u + b, M = diag(s) + C, u = f + k2 f^2 + k3 f^3 + G p(f), p = (f_x f_y, f_x f_z, f_y f_z),
s_i = S_ii + sT_i dT + sT2_i dT^2, b_i = b_i + bT_i dT + bT2_i dT^2 + dt_i t + w_i (1 - e^(-t/tau)):

    da_i/db_i = 1, /dbT_i = dT, /dbT2_i = dT^2, /ddt_i = t, /dw_i = 1 - e^(-t/tau),
    da_i/dtau = -sum... = -w_i (t / tau^2) e^(-t/tau)
    da_i/dS_ii = u_i, /dsT_i = dT u_i, /dsT2_i = dT^2 u_i, da_i/dS_ij = u_j (i != j)
    da/dk2_j = M[:, j] f_j^2, da/dk3_j = M[:, j] f_j^3, da/dG_j,p = M[:, j] p_p

(at fixed true specific force f). Columns of fixture_tilt (it moves f) and of user effects are left
to central differences (`numeric`). The gravity-norm residual e = |f| - g with f = correct(theta, a')
follows by the implicit function theorem: de/dtheta = -(A^-T f/|f|) . da/dtheta, A = da/df =
M (I diag(1 + 2 k2 f + 3 k3 f^2) + G dp/df).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from accellog.calibrate.model.compose import S_INDEX, Model
from accellog.calibrate.model.effects import CROSS_NAMES, TRI_NAMES
from accellog.core.numeric import jacobian_array

NUMERIC_TERMS = {"fixture_tilt"}
"""Library effects whose columns are left to central differences (they move the truth f)."""


def numeric_columns(model: Model) -> list[int]:
    """Parameter indices without an analytic column: fixture_tilt and user effects."""
    out: list[int] = []
    for e in model.effects:
        if e.name in NUMERIC_TERMS or e.contribution is not None:
            out += list(range(model.n_params))[model.slices[e.name]]
    return out


def _driver(x: np.ndarray | None, name: str, term: str) -> np.ndarray:
    """The driver series x a term needs (ValueError naming both when the drivers lack it)."""
    if x is None:
        raise ValueError(f"term {term!r} needs the driver {name!r}")
    return x


def _matrix(sdiag: np.ndarray, C: np.ndarray, n: int) -> np.ndarray:
    """M per row (n,3,3): diag(s) + C."""
    M = np.broadcast_to(C, (n, 3, 3)).copy()
    s = np.broadcast_to(sdiag, (n, 3))
    M[:, [0, 1, 2], [0, 1, 2]] += s
    return M


def predict_jacobian(
    model: Model, theta: np.ndarray, f_g: np.ndarray, drivers: Mapping[str, np.ndarray]
) -> np.ndarray:
    """da/dtheta (n, 3, k) of Model.predict at fixed truth f_g (n,3) g; the numeric_columns are zero."""
    theta = np.asarray(theta, float)
    f = np.atleast_2d(np.asarray(f_g, float))
    n = f.shape[0]
    k2, k3, G, sdiag, C, _ = model._components(theta, drivers)
    u = model._input(f, k2, k3, G)
    M = _matrix(sdiag, C, n)
    J = jacobian_array(3 * n, model.n_params).reshape(n, 3, model.n_params)  # handed to the solver uncopied
    ax = np.arange(3)
    dT = None
    if "temp_degC" in drivers and drivers["temp_degC"] is not None:
        dT = np.asarray(drivers["temp_degC"], float) - model.t_ref_degC
    t = np.asarray(drivers["t_s"], float) if "t_s" in drivers else None

    def cols(term: str) -> np.ndarray:
        return np.arange(model.n_params)[model.slices[term]]

    for term in model.term_names:
        if term not in model.slices or term in NUMERIC_TERMS:
            continue
        c = cols(term)
        if term == "bias":
            J[:, ax, c] = 1.0
        elif term in ("temp_bias", "temp_bias2"):
            J[:, ax, c] = (_driver(dT, "temp_degC", term) ** (1 if term == "temp_bias" else 2))[:, None]
        elif term == "time_drift":
            J[:, ax, c] = _driver(t, "t_s", term)[:, None]
        elif term == "warmup":
            t = _driver(t, "t_s", term)
            w, tau = theta[c[:3]], max(float(theta[c[3]]), 1e-6)
            e = np.exp(-t / tau)
            J[:, ax, c[:3]] = (-np.expm1(-t / tau))[:, None]
            if float(theta[c[3]]) > 1e-6:  # the model clips tau at 1e-6 s: flat below
                J[:, :, c[3]] = -w[None, :] * (t * e / tau**2)[:, None]
        elif term == "scale":
            J[:, ax, c] = u
        elif term in ("temp_scale", "temp_scale2"):
            J[:, ax, c] = u * (_driver(dT, "temp_degC", term) ** (1 if term == "temp_scale" else 2))[:, None]
        elif term in ("cross_axis", "misalignment_tri"):
            for k, nm in zip(c, CROSS_NAMES if term == "cross_axis" else TRI_NAMES, strict=True):
                i, j = S_INDEX[nm]
                J[:, i, k] = u[:, j]
        elif term in ("nonlin2", "nonlin3"):
            power = 2 if term == "nonlin2" else 3
            for j, k in enumerate(c):
                J[:, :, k] = M[:, :, j] * (f[:, j] ** power)[:, None]
        elif term == "g_cross":
            prods = np.stack([f[:, 0] * f[:, 1], f[:, 0] * f[:, 2], f[:, 1] * f[:, 2]], axis=1)
            for j in range(3):
                for p in range(3):
                    J[:, :, c[3 * j + p]] = M[:, :, j] * prods[:, p][:, None]
    return J


def force_jacobian(
    model: Model, theta: np.ndarray, f_g: np.ndarray, drivers: Mapping[str, np.ndarray]
) -> np.ndarray:
    """A = da/df (n,3,3) of the library part of Model.predict (user effects not included)."""
    f = np.atleast_2d(np.asarray(f_g, float))
    n = f.shape[0]
    k2, k3, G, sdiag, C, _ = model._components(np.asarray(theta, float), drivers)
    d = np.ones_like(f)
    if k2 is not None:
        d = d + 2.0 * k2 * f
    if k3 is not None:
        d = d + 3.0 * k3 * f * f
    du = np.zeros((n, 3, 3))
    du[:, [0, 1, 2], [0, 1, 2]] = d
    if G is not None:
        dp = np.zeros((n, 3, 3))  # rows: products xy, xz, yz; columns: f_x, f_y, f_z
        dp[:, 0, 0], dp[:, 0, 1] = f[:, 1], f[:, 0]
        dp[:, 1, 0], dp[:, 1, 2] = f[:, 2], f[:, 0]
        dp[:, 2, 1], dp[:, 2, 2] = f[:, 2], f[:, 1]
        du = du + G[None, :, :] @ dp
    return _matrix(sdiag, C, n) @ du


def norm_jacobian(
    model: Model, theta: np.ndarray, meas_g: np.ndarray, drivers: Mapping[str, np.ndarray]
) -> np.ndarray | None:
    """d|correct(theta, a')|/dtheta (n, k) by the implicit function theorem (module doc); None when
    the model has user effects (their da/df is not known). numeric_columns are zero."""
    if any(e.contribution is not None for e in model.effects):
        return None
    f = model.correct(theta, meas_g, drivers)
    fhat = f / np.linalg.norm(f, axis=1, keepdims=True)
    A = force_jacobian(model, theta, f, drivers)
    v = np.linalg.solve(np.transpose(A, (0, 2, 1)), fhat[:, :, None])[:, :, 0]
    return -np.einsum("ni,nik->nk", v, predict_jacobian(model, theta, f, drivers))
