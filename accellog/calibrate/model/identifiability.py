"""Can the data determine a model? Pose and driver coverage of observations, and the rank check.

effect_requirement(name, obs, drivers, model) says why an effect cannot be revealed by this data
(what to record) or None; rank_check(J, ...) refuses (ModelError) a model whose column-normalised
Jacobian J / |J_k| has a singular value below RANK_TOL * s_max, naming the parameters in its null
space (|v_k| > 0.2) and the poses or signals that would determine them. What unlabelled stops
determine by a gravity-norm fit: calibrate.model.stops.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import numpy as np

from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import AXES, all_effects
from accellog.core.errors import InputError, ModelError
from accellog.core.session import ObsTable

GEOMETRY_EFFECTS = {"fixture_tilt", "nonlin2", "nonlin3", "g_cross"}
"""Effects whose identifiability is a property of the pose set; fit_model checks it explicitly.
fixture_tilt in particular is refused without a face held at two rotations about the vertical:
with six poses its estimate would rest entirely on the nominal yaw of each face."""


RANK_TOL = 1e-9
"""Relative singular value of the column-normalised Jacobian below which a direction is unidentifiable."""


def q_or_none(obs: ObsTable) -> np.ndarray | None:
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
    q = q_or_none(obs)
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


# ---------------------------------------------------------------------------------------------
# can the recommended recording identify it?  A synthetic design of the best protocol we advise

NORM_RANK_TOL = 1e-7
"""Relative singular value below which a direction of the gravity-norm Jacobian is unidentifiable."""


def design_obs(rounds: int = 3, windows: int = 1, hold_s: float = 20.0) -> ObsTable:
    """The richest recording the advice recommends, as observations: the 26 cube directions (6
    faces, 12 edges, 8 corners), `rounds` rounds each at another rotation about the vertical (0, 90,
    180 deg), `windows` windows per hold, from power-up (first window at 1 s), the die temperature
    heating 20 -> 40 degC and cooling back to 28 degC (temperature does not follow time)."""
    from accellog.core.rotations import quat_between, quat_from_axis_angle, quat_multiply

    dirs = np.array([v for v in np.ndindex(3, 3, 3) if v != (1, 1, 1)], float) - 1.0
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    up, q, pid, tin = [], [], [], []
    for r in range(rounds):
        qy = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.pi / 2 * r)
        for k, u in enumerate(dirs):
            qk = quat_multiply(qy, quat_between(u, np.array([0.0, 0.0, 1.0])))
            for w in range(windows):
                up.append(u)
                q.append(qk)
                pid.append(r * len(dirs) + k)
                tin.append((w + 0.5) * hold_s / windows)
    n = len(up)
    t = 1.0 + np.arange(n) * (hold_s / windows) + np.repeat(np.arange(n // windows), windows) * 2.0
    x = t / t[-1]
    T = np.where(x < 0.6, 20.0 + 20.0 * x / 0.6, 40.0 - 12.0 * (x - 0.6) / 0.4)
    up_a = np.array(up)
    return ObsTable(
        meas_g=up_a.copy(),
        sigma_g=np.full((n, 3), 1e-4),
        up_sensor=up_a,
        pose_id=np.array(pid),
        pose_names=[f"d{i}" for i in range(rounds * len(dirs))],
        t_s=t,
        t_in_pose_s=np.array(tin),
        n_samples=np.full(n, 100),
        std_g=np.full((n, 3), 1e-3),
        temp_degC=T,
        dtemp_degC_per_s=np.gradient(T, t),
        q_sensor_to_world=np.array(q),
    )


def _null_params(J: np.ndarray, names: list[str], tol: float) -> list[str]:
    """Parameters in the near-null space of the column-normalised J (|v_k| > 0.2), zero columns too."""
    norms = np.linalg.norm(J, axis=0)
    zero = [names[k] for k in np.flatnonzero(~(norms > 0))]
    if zero:
        return zero
    _, s, vt = np.linalg.svd(J / norms, full_matrices=False)
    bad: list[str] = []
    for v in vt[s < tol * s[0]]:
        bad += [names[k] for k in np.flatnonzero(np.abs(v) > 0.2) if names[k] not in bad]
    return bad


def design_null(model: Model, kind: str = "labelled", obs: ObsTable | None = None) -> list[str]:
    """Parameters of `model` that even the design (design_obs, or obs) cannot determine by a
    'labelled' fit (known poses) or a 'norm' fit (orientation-free: |correct(a')| = g), from the
    rank of the column-normalised Jacobian at the documented starting point (Model.initial_theta,
    where every fit starts); [] when all can be."""
    o = design_obs() if obs is None else obs
    optional = {"temp_degC": o.temp_degC, "dtemp_degC_per_s": o.dtemp_degC_per_s}
    drv = {"t_s": o.t_s, "t_in_pose_s": o.t_in_pose_s, **{k: v for k, v in optional.items() if v is not None}}
    th = model.initial_theta()
    steps = np.maximum(1e-4 * model.param_typical, 1e-7 * np.abs(th))
    if kind == "norm":
        meas = model.predict(th, o.up_sensor, drv)

        def fun(x):
            return np.linalg.norm(model.correct(x, meas, drv), axis=1) - 1.0

        tol = NORM_RANK_TOL
    else:

        def fun(x):
            return (model.predict(x, model.truth_g(x, o.up_sensor, o.q_sensor_to_world), drv)).ravel()

        tol = RANK_TOL
    J = np.empty((fun(th).size, th.size))
    for k in range(th.size):
        e = np.zeros_like(th)
        e[k] = steps[k]
        J[:, k] = (fun(th + e) - fun(th - e)) / (2.0 * steps[k])
    return _null_params(J, model.param_names, tol)


NORM_ONLY_LABELLED = "cannot be identified from a gravity-norm fit; record labelled poses"


def norm_blind_params(model: Model) -> list[str]:
    """design_null(model, 'norm'), or [] when the design cannot be evaluated (a user effect that
    needs a driver signal of its own)."""
    try:
        return design_null(model, "norm")
    except (ModelError, InputError):
        return []


def norm_blind_reason(model: Model, effect: str) -> str | None:
    """Why `effect` cannot be identified on top of `model` by a gravity-norm fit with any
    orientations (None if a good recording could identify it): the parameters that enter |f| alike."""
    try:
        m = model.with_terms([effect])
    except ModelError:
        return None
    null = list(_norm_null(tuple(m.term_names))) if m.effects_file is None else norm_blind_params(m)
    if not null:
        return None
    return f"{', '.join(null)} {NORM_ONLY_LABELLED} (they enter |f| alike even with every orientation)"


@functools.lru_cache(maxsize=256)
def _norm_null(terms: tuple[str, ...]) -> tuple[str, ...]:
    """design_null(Model(terms), 'norm') for library models (cached: the same for every session)."""
    return tuple(design_null(Model(list(terms)), "norm"))


@functools.lru_cache(maxsize=256)
def _labelled_null(terms: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(design_null(Model(list(terms)), "labelled"))


def checked_advice(model: Model, effect: str, reason: str) -> str:
    """A recording recommended for `effect` (reason, from effect_requirement), kept only when the
    design of the recommended protocol (design_obs) identifies model + effect by a labelled fit;
    otherwise what no static recording can determine."""
    try:
        m = model.with_terms([effect])
    except ModelError as exc:
        return str(exc)
    try:
        null = _labelled_null(tuple(m.term_names)) if m.effects_file is None else design_null(m)
    except (ModelError, InputError):  # a user effect that needs a driver signal of its own
        return reason
    if null:
        return f"{effect}: {', '.join(null)} cannot be determined by any static recording of known poses"
    return reason
