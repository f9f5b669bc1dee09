"""The calibration file's schema: one validator, run by the reader (``calibration_from_dict``) on
every file read and on what ``Calibration.save`` would write.

``check_document`` checks the JSON document before anything is built from it: every number a real
JSON number (``true`` is not 1) within float range and finite; ``params`` a list of {name, unit:
string, value: number}; ``model`` an object whose ``terms`` is a non-empty list of unique effect
names (strings), each a library effect or a user effect with a recorded SHA-256 of its file;
``covariance`` a k x k matrix, symmetric and positive semi-definite within COV_RTOL of its largest
eigenvalue; ``S`` / ``b_g`` 3 x 3 / 3 numbers; the sections always written as objects or strings
not ``null``. ``check_values`` bounds the parameters to what a MEMS accelerometer can be, and
``check_S`` the conditioning of the S that will be applied: cond(S) <= MAX_COND_S.
"""

from __future__ import annotations

import math
from typing import Any, TypeGuard

import numpy as np

from accellog.calibrate.model.compose import check_effects_hash
from accellog.calibrate.model.effects import LIBRARY
from accellog.core.errors import InputError, ModelError

MAX_COND_S = 1e6
"""Largest condition number of S (2-norm): a near-singular S amplifies readings without bound."""
MAX_VARIANCE = 1e6
"""Largest variance of a parameter (its 1-sigma 1000 in the parameter's unit): beyond, absurd."""
COV_RTOL = 1e-8
"""Asymmetry and negative eigenvalues of the covariance allowed, relative to its largest |value|."""

_OBJECTS = ("gravity", "temperature", "fit", "sensor", "device")  # written as objects, never null
_STRINGS = ("software", "created_utc")

# Physical plausibility of a stored calibration of a MEMS accelerometer (datasheet: bias within
# +-80 mg, scale within +-3 %, cross-axis within +-2 %): limits ~10x wider, so only absurd files fail.
SANITY_LIMITS: dict[str, float] = {"bias_g": 1.0, "scale_dev": 0.5, "cross": 0.3}
SANITY_RANGES: dict[str, tuple[float, float]] = {"gravity_mps2": (9.7, 9.9), "truth_g": (0.98, 1.02)}


def _is_number(v: Any) -> TypeGuard[int | float]:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _numbers_in_range(x: Any, path: str, where: str | None) -> None:
    """Every JSON integer of the document fits a float (no 10**400: float() would overflow)."""
    stack = [(x, path)]
    while stack:
        v, p = stack.pop()
        if isinstance(v, dict):
            stack.extend((w, f"{p}.{k}") for k, w in v.items())
        elif isinstance(v, list):
            stack.extend((w, f"{p}[{i}]") for i, w in enumerate(v))
        elif isinstance(v, int) and not isinstance(v, bool) and abs(v) > 1.7e308:
            raise InputError(f"'{p.lstrip('.')}' is an integer beyond float range", where=where)


def _matrix(v: Any, key: str, shape: tuple[int, ...], where: str | None) -> np.ndarray:
    """A numeric array of `shape` from JSON lists of numbers (no booleans, no null), finite."""
    flat = np.asarray(v, dtype=object).ravel() if isinstance(v, list) else None
    ok = flat is not None and all(_is_number(e) for e in flat)
    a = np.asarray(v, dtype=float) if ok else None
    if a is None or a.shape != shape:
        want = " x ".join(map(str, shape))
        raise InputError(f"calibration '{key}' must be {want} numbers", where=where)
    if not np.isfinite(a).all():
        raise InputError(f"calibration '{key}' has a value that is not finite", where=where)
    return a


def _check_params(params: Any, where: str | None) -> int:
    if not isinstance(params, list) or not params:
        raise InputError("calibration 'params' must be a non-empty list", where=where)
    for i, p in enumerate(params):
        if not isinstance(p, dict):
            raise InputError(f"calibration params[{i}] is not an object", where=where)
        name = p.get("name", f"params[{i}]")
        for key in ("name", "unit"):
            if not isinstance(p.get(key), str):
                raise InputError(f"calibration parameter {name!r}: '{key}' must be a string", where=where)
        for key in ("value", "sigma"):
            v = p.get(key)
            if (key == "value" or v is not None) and not (_is_number(v) and math.isfinite(v)):
                raise InputError(
                    f"calibration parameter {name!r}: '{key}' = {v!r} must be a finite number", where=where
                )
    return len(params)


def _check_model(model: Any, where: str | None) -> None:
    if not isinstance(model, dict):
        raise InputError("calibration 'model' must be an object (name, terms, ...)", where=where)
    terms = model.get("terms")
    if not isinstance(terms, list) or not terms or not all(isinstance(t, str) and t for t in terms):
        raise InputError(
            f"calibration model 'terms' must be a list of effect names, got {terms!r}", where=where
        )
    dup = sorted({t for t in terms if terms.count(t) > 1})
    if dup:
        raise InputError(f"calibration model names effect(s) twice: {', '.join(dup)}", where=where)
    for key in ("name", "effects_file", "effects_file_sha256"):
        if model.get(key) is not None and not isinstance(model[key], str):
            raise InputError(f"calibration model '{key}' must be a string, got {model[key]!r}", where=where)
    t_ref = model.get("t_ref_degC", 25.0)
    if not (_is_number(t_ref) and math.isfinite(t_ref)):
        raise InputError(f"calibration model 't_ref_degC' = {t_ref!r} must be a finite number", where=where)
    user = [t for t in terms if t not in LIBRARY]
    if user:
        if not model.get("effects_file"):
            raise InputError(f"model names unknown effect(s) {', '.join(map(repr, user))}", where=where)
        try:
            check_effects_hash(user, model.get("effects_file_sha256"))
        except ModelError as exc:
            raise InputError(str(exc), where=where) from None


def _check_covariance(cov: np.ndarray, names: list[str], where: str | None) -> None:
    neg = np.flatnonzero(np.diag(cov) < 0)
    if neg.size:
        raise InputError(f"covariance has a negative variance (at {names[neg[0]]})", where=where)
    scale = float(np.max(np.abs(cov))) if cov.size else 0.0
    if scale == 0.0:
        return
    if float(np.max(np.abs(cov - cov.T))) > COV_RTOL * scale:
        raise InputError("calibration 'covariance' is not symmetric", where=where)
    low = float(np.linalg.eigvalsh((cov + cov.T) / 2).min())
    if low < -COV_RTOL * scale:
        raise InputError(
            f"calibration 'covariance' is not positive semi-definite (eigenvalue {low:.3g})", where=where
        )


def check_document(d: dict, where: str | None = None) -> None:
    """InputError (one line naming the field) for a calibration document that breaks the schema."""
    _numbers_in_range(d, "", where)
    for key in _OBJECTS:
        if key in d and not isinstance(d[key], dict):
            raise InputError(f"calibration section '{key}' must be an object, got {d[key]!r}", where=where)
    for key in _STRINGS:
        if key in d and not isinstance(d[key], str):
            raise InputError(f"calibration '{key}' must be a string, got {d[key]!r}", where=where)
    if "sources" in d and not isinstance(d["sources"], list):
        raise InputError(f"calibration 'sources' must be a list, got {d['sources']!r}", where=where)
    k = _check_params(d.get("params"), where)
    _check_model(d.get("model"), where)
    if "covariance" not in d:
        raise InputError("calibration file has no 'covariance'", where=where)
    names = [p["name"] for p in d["params"]]
    _check_covariance(_matrix(d["covariance"], "covariance", (k, k), where), names, where)
    grav = d.get("gravity")
    for key in ("truth_g", "local_gravity_mps2"):
        v = grav.get(key) if isinstance(grav, dict) else None
        if not (_is_number(v) and math.isfinite(v)):
            raise InputError(f"calibration 'gravity.{key}' = {v!r} must be a finite number", where=where)
    if "S" in d:
        check_S(_matrix(d["S"], "S", (3, 3), where), where)
    if "b_g" in d:
        _matrix(d["b_g"], "b_g", (3,), where)


def check_S(S: np.ndarray, where: str | None = None) -> None:
    """InputError when S is singular or its condition number exceeds MAX_COND_S."""
    cond = float(np.linalg.cond(S))
    if not (math.isfinite(cond) and cond <= MAX_COND_S):
        raise InputError(
            f"calibration S is near-singular (condition number {cond:.3g} > {MAX_COND_S:g}): "
            "it would amplify readings without bound; refit this calibration",
            where=where,
        )


def check_values(
    names: list[str],
    theta: np.ndarray,
    cov: np.ndarray,
    *,
    truth_g: float,
    local_gravity_mps2: float,
    where: str | None = None,
) -> None:
    """InputError naming the first absurd value: |b_i| > 1 g, |S_ii - 1| > 0.5, |S_ij| > 0.3, any
    |value| > 1e6, a non-finite or negative variance or one above MAX_VARIANCE, gravity outside
    9.7-9.9 m/s^2 or truth_g outside 0.98-1.02."""
    lim = SANITY_LIMITS
    for n, v in zip(names, theta, strict=True):
        bad = None
        if n in ("b_x", "b_y", "b_z") and abs(v) > lim["bias_g"]:
            bad = f"|{n}| > {lim['bias_g']:g} g"
        elif n in ("S_xx", "S_yy", "S_zz") and abs(v - 1.0) > lim["scale_dev"]:
            bad = f"{n} outside 1 +- {lim['scale_dev']:g}"
        elif n.startswith("S_") and len(n) == 4 and n[2] != n[3] and abs(v) > lim["cross"]:
            bad = f"|{n}| > {lim['cross']:g}"
        elif abs(v) > 1e6:
            bad = f"|{n}| > 1e6"
        if bad:
            raise InputError(
                f"absurd calibration value {n} = {v:.6g} ({bad}); refit this calibration", where=where
            )
    d = np.diag(cov) if cov.ndim == 2 else np.array([])
    if not np.isfinite(cov).all() or (d < 0).any():
        k = int(np.argmax(~np.isfinite(d) | (d < 0))) if d.size else 0
        name = names[k] if k < len(names) else "?"
        raise InputError(f"covariance is not finite or has a negative variance (at {name})", where=where)
    if d.size and d.max() > MAX_VARIANCE:
        k = int(np.argmax(d))
        raise InputError(
            f"absurd variance of {names[k]}: {d[k]:.3g} > {MAX_VARIANCE:g}; refit this calibration",
            where=where,
        )
    lo, hi = SANITY_RANGES["gravity_mps2"]
    if not lo <= local_gravity_mps2 <= hi:
        raise InputError(
            f"local_gravity_mps2 = {local_gravity_mps2:g} is not a gravity on Earth ({lo}-{hi} m/s^2)",
            where=where,
        )
    lo, hi = SANITY_RANGES["truth_g"]
    if not lo <= truth_g <= hi:
        raise InputError(f"gravity truth_g = {truth_g:g} outside {lo}-{hi}", where=where)
