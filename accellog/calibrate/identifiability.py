"""Can the data determine a model? Pose and driver coverage of observations, and the rank check.

effect_requirement(name, obs, drivers, model) says why an effect cannot be revealed by this data
(what to record) or None; rank_check(J, ...) refuses (ModelError) a model whose column-normalised
Jacobian J / |J_k| has a singular value below RANK_TOL * s_max, naming the parameters in its null
space (|v_k| > 0.2) and the poses or signals that would determine them.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from accellog.calibrate.effects import AXES, all_effects
from accellog.calibrate.model import Model
from accellog.core.errors import ModelError
from accellog.core.session import ObsTable

GEOMETRY_EFFECTS = {"fixture_tilt", "nonlin2", "nonlin3", "g_cross"}
"""Effects whose identifiability is a property of the pose set; fit_model checks it explicitly.
fixture_tilt in particular is refused without a face held at two rotations about the vertical:
with six poses its estimate would rest entirely on the nominal yaw of each face."""


RANK_TOL = 1e-9
"""Relative singular value of the column-normalised Jacobian below which a direction is unidentifiable."""


def _q_or_none(obs: ObsTable) -> np.ndarray | None:
    q = obs.q_sensor_to_world
    return None if q is None else np.asarray(q, float)


def pose_faces(obs: ObsTable) -> list[str]:
    """Distinct faces present ('+x' ... '-z' for on-axis poses, 'off-axis' otherwise)."""
    out = []
    for u in np.unique(np.round(np.asarray(obs.up_sensor, float), 3), axis=0):
        k = int(np.argmax(np.abs(u)))
        if abs(abs(u[k]) - 1.0) < 1e-3:
            out.append(("+" if u[k] > 0 else "-") + AXES[k])
        else:
            out.append("off-axis")
    return sorted(set(out))


def _levels(x: np.ndarray, step: float = 0.05) -> int:
    return int(np.unique(np.round(np.asarray(x, float) / step)).size)


def yaw_groups(obs: ObsTable) -> int:
    """Largest number of distinct orientations (rotations about the vertical) of any one face."""
    q = _q_or_none(obs)
    if q is None or not np.all(np.isfinite(q)):
        return 0
    up = np.round(np.asarray(obs.up_sensor, float), 3)
    qs = np.round(q * np.sign(q[:, :1] + 1e-12), 3)
    best = 0
    for u in np.unique(up, axis=0):
        m = np.all(up == u, axis=1)
        best = max(best, np.unique(qs[m], axis=0).shape[0])
    return best


def effect_requirement(
    name: str, obs: ObsTable, drivers: Mapping[str, np.ndarray], model: Model
) -> str | None:
    """Why the data cannot reveal effect `name` (what to record), or None if it may."""
    lib = all_effects(model.effects_file)
    e = lib.get(name)
    if e is None:
        return f"unknown effect {name!r}"
    if not e.static:
        return (
            "not identifiable from static pose means: a sample-clock error scales time, which shows "
            "as sensor time drifting against host time (supply host timestamps) and in integration"
        )
    for d in e.drivers:
        if d not in drivers:
            return f"needs driver {d!r} ({DRIVER_HINT.get(d, 'not in this data')})"
    up = np.asarray(obs.up_sensor, float)
    if name in ("temp_bias", "temp_scale", "temp_bias2", "temp_scale2"):
        T = drivers["temp_degC"]
        span = float(np.ptp(T))
        need = 1.0 if name in ("temp_bias", "temp_scale") else 3.0
        if span < need:
            return (
                f"{name} not identifiable: temperature spans only {span:.1f} degC (need >= {need:g}); "
                "record a warm-up from power-up or a temperature sweep, with several windows per hold"
            )
    if name in ("temp_bias2", "temp_scale", "temp_scale2"):
        # a curve through k temperature levels needs k >= terms: at two levels dT and dT^2 are the same
        # signal (plateaus); scale terms need the levels while each axis is vertical (|f_i| > 0.5 g)
        T = drivers["temp_degC"]
        need = 2 if name == "temp_scale" else 3
        rows = (
            {"any pose": np.ones(T.shape, bool)}
            if name == "temp_bias2"
            else {f"axis {a} up/down": np.abs(up[:, i]) > 0.5 for i, a in enumerate(AXES)}
        )
        bad = [k for k, m in rows.items() if _levels(T[m], 0.5) < need]
        if bad:
            return (
                f"{name} not identifiable: fewer than {need} temperature levels (0.5 degC apart) for "
                f"{', '.join(bad)}; hold the poses at {need} or more temperatures (a sweep or warm-up)"
            )
    if name in ("time_drift", "warmup"):
        span = float(np.ptp(drivers["t_s"]))
        if span < 60.0:
            return f"{name} needs observations spread over >= 60 s (have {span:.0f} s)"
        if name == "warmup" and float(np.min(drivers["t_s"])) > 600.0:
            return "warmup needs data from the first minutes after power-up (first window starts late)"
    if name == "fixture_tilt" and yaw_groups(obs) < 2:
        return (
            "fixture_tilt not identifiable: no face is held at two rotations about the vertical; "
            "record the 24-pose protocol (each face at 0/90/180/270 deg, --protocol 24)"
        )
    if name == "nonlin2":
        bad = [a for i, a in enumerate(AXES) if _levels(up[:, i]) < 3]
        if bad:
            return f"nonlin2 needs each axis at three levels (+1, 0, -1 g); missing for {', '.join(bad)}"
    if name == "nonlin3":
        bad = [a for i, a in enumerate(AXES) if _levels(up[:, i]) < 4]
        if bad:
            return (
                f"nonlin3 needs poses off the axes (f at four levels, e.g. 45 deg tilts or cube "
                f"edges/corners): missing for {', '.join(bad)}; at +-1 g it is indistinguishable from scale"
            )
    if name == "g_cross":
        prods = np.stack([up[:, 0] * up[:, 1], up[:, 0] * up[:, 2], up[:, 1] * up[:, 2]], axis=1)
        bad = [p for k, p in enumerate(("xy", "xz", "yz")) if _levels(prods[:, k], 0.05) < 3]
        if bad:
            return (
                "g_cross needs poses off the axes so that f_j f_k takes several values (cube edges, "
                f"45 deg tilts in both directions): missing for products {', '.join(bad)}"
            )
    return None


DRIVER_HINT = {
    "temp_degC": "record the die temperature (TEMP_OUT) with the session, during a warm-up or a "
    "temperature sweep of a few degC",
    "dtemp_degC_per_s": "record the die temperature (TEMP_OUT) with the session, during a warm-up or a "
    "temperature sweep of a few degC",
    "t_s": "observation times are missing",
    "t_in_pose_s": "label the static holds",
}


def _param_hint(pname: str, model: Model, obs: ObsTable, drivers: Mapping[str, np.ndarray]) -> str:
    faces = pose_faces(obs)
    for e in model.effects:
        if pname in e.param_names:
            break
    else:  # pragma: no cover
        return ""
    ax = pname[-1] if pname[-1] in AXES else ""
    if pname.startswith("S_") and len(pname) == 4 and pname[2] == pname[3]:
        have = [f for f in faces if f.endswith(ax)]
        return (
            f"scale of {ax} needs {ax} at two levels: both +{ax} and -{ax} poses "
            f"(have {', '.join(have) or f'no {ax} pose'})"
        )
    if pname.startswith("S_") and len(pname) == 4:
        j = pname[3]
        return f"{pname} (axis {pname[2]} sensing {j}) needs a pose with {j} up or down"
    if pname.startswith("b_"):
        return f"bias of {ax} needs {ax} readings at known orientations"
    reason = effect_requirement(e.name, obs, drivers, model)
    return reason or f"{e.name}: {e.reveal}"


def rank_check(
    J: np.ndarray, model: Model, obs: ObsTable, drivers: Mapping[str, np.ndarray], *, overwrite: bool = False
) -> float:
    """Raise ModelError if the column-normalised Jacobian is rank deficient, naming the
    parameters in its null space and what data would determine them; return its condition number.
    overwrite: normalise J in place (the caller's temporary: one Jacobian less in memory)."""
    norms = np.linalg.norm(J, axis=0)
    names = model.param_names
    zero = [names[k] for k in range(len(names)) if norms[k] == 0 or not np.isfinite(norms[k])]
    bad: list[str] = list(zero)
    cond = np.inf
    if not zero and J.shape[1]:
        Jn = np.divide(J, norms, out=J if overwrite else None)
        s = np.linalg.svd(Jn, compute_uv=False)  # no U (3 n_obs x n_params): one Jacobian less
        cond = float(s[0] / s[-1]) if s[-1] > 0 else np.inf
        null = []
        if s[-1] < RANK_TOL * s[0]:  # rank deficient: the null vectors name the parameters
            _, s, vt = np.linalg.svd(Jn, full_matrices=False)
            null = vt[s < RANK_TOL * s[0]]
        for v in null:
            bad += [names[k] for k in np.flatnonzero(np.abs(v) > 0.2) if names[k] not in bad]
    if J.shape[0] < J.shape[1]:
        raise ModelError(
            f"model {model.name} has {J.shape[1]} parameters but the data give only {J.shape[0]} "
            f"equations ({obs.n} observations x 3 axes): record more poses (faces present: "
            f"{', '.join(pose_faces(obs))})"
        )
    if bad:
        hints = list(dict.fromkeys(_param_hint(p, model, obs, drivers) for p in bad))
        raise ModelError(
            f"model {model.name} cannot be determined from this data: {', '.join(bad)} not "
            f"identifiable ({'; '.join(hints)}); faces present: {', '.join(pose_faces(obs))}"
        )
    return cond
