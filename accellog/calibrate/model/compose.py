"""Model composition: a Model is a list of effects (terms) with one parameter vector theta.

Forward (measurement equation, all in g; dT = T - t_ref_degC; t = time since session start, s):

    u   = f + k2 f^2 + k3 f^3 + G (f_x f_y, f_x f_z, f_y f_z)          (per axis)
    a'  = diag(S_ii + sT dT + sT2 dT^2) u + C u + b(dT, t) + sum_user h(p, f, drivers)
    b   = b0 + bT dT + bT2 dT^2 + dt t + w (1 - exp(-t / tau))

Terms absent from the model contribute nothing (S_ii = 1 without 'scale'). fixture_tilt acts on
the truth (model.truth_g), not on the sensor, so predict/correct map true specific force in the
sensor frame <-> reading. correct() inverts predict() exactly: linear part by a 3x3 inverse (per
row, by adjugate, when S depends on temperature), input nonlinearity by vectorised Newton,
user terms by fixed-point iteration.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from accellog.calibrate.model.effects import (
    AXES,
    CROSS_NAMES,
    DRIVER_HELP,
    LIBRARY,
    PRESETS,
    TRI_NAMES,
    Effect,
    EffectsFile,
    all_effects,
    load_effects_file,
)
from accellog.core.errors import ModelError
from accellog.core.notices import note
from accellog.core.rotations import quat_from_rotvec, rotate_inverse

_ORDER = list(LIBRARY)
S_INDEX = {f"S_{a}{b}": (i, j) for i, a in enumerate(AXES) for j, b in enumerate(AXES)}


def valid_names(effects_file: EffectsFile | None = None) -> list[str]:
    """Presets, library effects and the user file's effects."""
    names = list(PRESETS) + _ORDER
    if effects_file is not None:
        names += list(effects_file.effects)
    return names


class Model:
    """A composed error model. theta is one float vector; param_names/param_units describe it."""

    def __init__(
        self,
        terms: Sequence[str],
        *,
        effects_file: EffectsFile | None = None,
        t_ref_degC: float = 25.0,
        name: str | None = None,
    ) -> None:
        lib = all_effects(effects_file)
        unknown = [t for t in terms if t not in lib]
        if unknown:
            raise ModelError(
                f"unknown effect {', '.join(map(repr, unknown))}; valid names: "
                + ", ".join(valid_names(effects_file))
                + ("" if effects_file else " (user effects need --effects-file)")
            )
        uniq = list(dict.fromkeys(terms))
        builtin = sorted((t for t in uniq if t in LIBRARY), key=_ORDER.index)
        user = [t for t in uniq if t not in LIBRARY]
        self.term_names: list[str] = builtin + user
        self.effects: list[Effect] = [lib[t] for t in self.term_names]
        for e in self.effects:
            clash = [c for c in e.conflicts if c in self.term_names]
            if clash:
                raise ModelError(
                    f"effects {e.name!r} and {clash[0]!r} parametrise the same terms of S: use one"
                )
        self.effects_file = effects_file
        self.t_ref_degC = float(t_ref_degC)
        self.name = name or "+".join(self.term_names)
        self.params = [p for e in self.effects for p in e.params]
        self.param_names: list[str] = [p.name for p in self.params]
        dup = {n for n in self.param_names if self.param_names.count(n) > 1}
        if dup:
            raise ModelError(f"parameter names used twice in model {self.name}: {sorted(dup)}")
        self.param_units: list[str] = [p.unit for p in self.params]
        self.param_typical = np.array([p.typical for p in self.params], float)
        self.index = {n: i for i, n in enumerate(self.param_names)}
        self.slices: dict[str, slice] = {}
        k = 0
        for e in self.effects:
            self.slices[e.name] = slice(k, k + len(e.params))
            k += len(e.params)
        self.required_drivers: list[str] = sorted({d for e in self.effects for d in e.drivers})

    # ------------------------------------------------------------------ basics
    @property
    def terms(self) -> list[str]:
        return self.term_names

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def __repr__(self) -> str:
        return f"Model({self.name!r}, {self.n_params} params)"

    def has(self, term: str) -> bool:
        return term in self.slices

    def initial_theta(self) -> np.ndarray:
        """Initial values (the documented starting point of every fit): S_ii = 1, a warm-up of typical
        size (w_i = 3 mg, tau_warmup_s = 100 s), everything else 0."""
        return np.array([p.initial for p in self.params], float)

    def params_dict(self, theta: np.ndarray) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.param_names, np.asarray(theta, float), strict=True)}

    def with_terms(self, add: Sequence[str], name: str | None = None) -> Model:
        """This model plus more terms (same effects file and reference temperature)."""
        new = [a for a in add if a not in self.term_names]
        nm = name or (self.name + "".join(f"+{a}" for a in new))
        return Model(
            self.term_names + new, effects_file=self.effects_file, t_ref_degC=self.t_ref_degC, name=nm
        )

    def to_spec(self) -> dict:
        """JSON-able description: terms, effects file (path, sha256), reference temperature."""
        ef = self.effects_file
        return {
            "name": self.name,
            "terms": list(self.term_names),
            "effects_file": ef.path if ef else None,
            "effects_file_sha256": ef.sha256 if ef else None,
            "t_ref_degC": self.t_ref_degC,
        }

    # ------------------------------------------------------------------ drivers
    def check_drivers(self, drivers: Mapping[str, np.ndarray], n: int) -> None:
        """ModelError naming the first missing driver and what to record; lengths must be n."""
        for e in self.effects:
            for d in e.drivers:
                if (d not in drivers or drivers[d] is None) and d not in DRIVER_HELP:
                    valid = ", ".join(sorted({*DRIVER_HELP, *drivers}))
                    raise ModelError(
                        f"effect {e.name!r} reads unknown driver {d!r}; valid driver signals: {valid} "
                        "(docs/effects.md; user signals are passed as drivers={...} to fit_model/diagnose)"
                    )
                if d not in drivers or drivers[d] is None:
                    raise ModelError(f"effect {e.name!r} needs driver {d!r}: {DRIVER_HELP[d]}")
                arr = np.asarray(drivers[d])
                if arr.shape[0] != n:
                    raise ModelError(f"driver {d!r} has {arr.shape[0]} rows, expected {n}")
                if not np.all(np.isfinite(arr)):
                    raise ModelError(f"driver {d!r} (needed by {e.name!r}) has NaN/inf values")

    # ------------------------------------------------------------------ pieces
    def _p(self, theta: np.ndarray, term: str) -> np.ndarray | None:
        s = self.slices.get(term)
        return None if s is None else theta[s]

    def _components(self, theta: np.ndarray, drivers: Mapping[str, np.ndarray]):
        """(k2, k3, G, sdiag, C, b): sdiag (3,) or (n,3); b (3,) or (n,3); None for absent terms."""
        theta = np.asarray(theta, float)
        k2 = self._p(theta, "nonlin2")
        k3 = self._p(theta, "nonlin3")
        g = self._p(theta, "g_cross")
        G = None if g is None else g.reshape(3, 3)
        sc = self._p(theta, "scale")
        sdiag = np.ones(3) if sc is None else sc.copy()
        C = np.zeros((3, 3))
        for term, names in (("cross_axis", CROSS_NAMES), ("misalignment_tri", TRI_NAMES)):
            v = self._p(theta, term)
            if v is not None:
                for nm, val in zip(names, v, strict=True):
                    C[S_INDEX[nm]] = val
        b0 = self._p(theta, "bias")
        b = np.zeros(3) if b0 is None else b0.copy()
        if any(self.has(t) for t in ("temp_bias", "temp_bias2", "temp_scale", "temp_scale2")):
            dT = (np.asarray(drivers["temp_degC"], float) - self.t_ref_degC)[:, None]
            for term, power, target in (
                ("temp_bias", 1, "b"),
                ("temp_bias2", 2, "b"),
                ("temp_scale", 1, "s"),
                ("temp_scale2", 2, "s"),
            ):
                v = self._p(theta, term)
                if v is None:
                    continue
                if target == "b":
                    b = b + v * dT**power
                else:
                    sdiag = sdiag + v * dT**power
        if self.has("time_drift") or self.has("warmup"):
            t = np.asarray(drivers["t_s"], float)[:, None]
            v = self._p(theta, "time_drift")
            if v is not None:
                b = b + v * t
            v = self._p(theta, "warmup")
            if v is not None:
                tau = max(float(v[3]), 1e-6)
                b = b + v[:3] * -np.expm1(-t / tau)
        return k2, k3, G, sdiag, C, b

    def _user_h(
        self, theta: np.ndarray, f: np.ndarray, drivers: Mapping[str, np.ndarray]
    ) -> np.ndarray | None:
        h = None
        for e in self.effects:
            if e.contribution is None:
                continue
            p = dict(zip(e.param_names, np.asarray(theta, float)[self.slices[e.name]], strict=True))
            c = np.asarray(e.contribution(p, f, drivers), float)
            if c.shape != f.shape:
                raise ModelError(f"user effect {e.name!r} returned shape {c.shape}, expected {f.shape}")
            h = c if h is None else h + c
        return h

    @staticmethod
    def _input(f: np.ndarray, k2, k3, G) -> np.ndarray:
        u = f
        if k2 is not None:
            u = u + k2 * f * f
        if k3 is not None:
            u = u + k3 * f * f * f
        if G is not None:
            prods = np.stack([f[:, 0] * f[:, 1], f[:, 0] * f[:, 2], f[:, 1] * f[:, 2]], axis=1)
            u = u + prods @ G.T
        return u

    # ------------------------------------------------------------------ public maths
    def predict(
        self, theta: np.ndarray, f_true_g: np.ndarray, drivers: Mapping[str, np.ndarray]
    ) -> np.ndarray:
        """Forward measurement equation: true specific force f (n,3) g -> reading a' (n,3) g."""
        f = np.atleast_2d(np.asarray(f_true_g, float))
        self.check_drivers(drivers, f.shape[0])
        k2, k3, G, sdiag, C, b = self._components(theta, drivers)
        u = self._input(f, k2, k3, G)
        a = sdiag * u + u @ C.T + b
        h = self._user_h(theta, f, drivers)
        return a if h is None else a + h

    def S_b(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear part at reference conditions (dT = 0, t = 0): S (3,3) and b (3,) in g."""
        theta = np.asarray(theta, float)
        sc = self._p(theta, "scale")
        S = np.diag(np.ones(3) if sc is None else sc)
        _, _, _, _, C, _ = self._components(
            theta, {"t_s": np.zeros(1), "temp_degC": np.full(1, self.t_ref_degC)}
        )
        b0 = self._p(theta, "bias")
        return S + C, (np.zeros(3) if b0 is None else b0.copy())

    def correct(
        self,
        theta: np.ndarray,
        meas_g: np.ndarray,
        drivers: Mapping[str, np.ndarray],
        *,
        tol_g: float = 1e-13,
        max_iter: int = 30,
    ) -> np.ndarray:
        """Inverse of predict: reading a' (N,3) g -> true specific force f (N,3) g.

        f = u^-1( M^-1 (a' - b - h(f)) ), M = diag(sdiag) + C; exact for linear models (one 3x3
        inverse, or a per-row adjugate inverse when S depends on temperature).
        """
        a = np.atleast_2d(np.asarray(meas_g, float))
        n = a.shape[0]
        self.check_drivers(drivers, n)
        k2, k3, G, sdiag, C, b = self._components(theta, drivers)
        has_user = any(e.contribution is not None for e in self.effects)
        v0 = a - b
        f = self._invert_core(v0, k2, k3, G, sdiag, C, tol_g, max_iter)
        if has_user:
            for _ in range(max_iter):
                h = self._user_h(theta, f, drivers)
                f_new = self._invert_core(v0 - h, k2, k3, G, sdiag, C, tol_g, max_iter)
                done = float(np.max(np.abs(f_new - f))) <= tol_g if f.size else True
                f = f_new
                if done:
                    break
        return f

    @staticmethod
    def _invert_core(v, k2, k3, G, sdiag, C, tol_g, max_iter) -> np.ndarray:
        if sdiag.ndim == 1:
            M = np.diag(sdiag) + C
            if abs(np.linalg.det(M)) < 1e-12:
                raise ModelError("scale matrix S is singular: cannot correct readings")
            u = v @ np.linalg.inv(M).T
        else:
            u = _solve_rows(sdiag, C, v)
        if k2 is None and k3 is None and G is None:
            return u
        f = u.copy()
        for _ in range(max_iter):
            r = Model._input(f, k2, k3, G) - u
            d = np.ones_like(f)
            if k2 is not None:
                d = d + 2.0 * k2 * f
            if k3 is not None:
                d = d + 3.0 * k3 * f * f
            step = r / d
            f -= step
            if not step.size or float(np.max(np.abs(step))) <= tol_g:
                break
        return f

    def truth_g(
        self,
        theta: np.ndarray,
        up_sensor: np.ndarray,
        q_sensor_to_world: np.ndarray | None,
        gravity_g: float = 1.0,
    ) -> np.ndarray:
        """True specific force of static poses (n,3) g: gravity_g * up, or with fixture_tilt
        f = R(q_tilt q_nominal)^T (0, 0, gravity_g), q_tilt = rotvec(tilt_x_rad, tilt_y_rad, 0)."""
        up = np.asarray(up_sensor, float)
        tilt = self._p(np.asarray(theta, float), "fixture_tilt")
        if tilt is None:
            return gravity_g * up
        if q_sensor_to_world is None or not np.all(np.isfinite(q_sensor_to_world)):
            raise ModelError(
                "fixture_tilt needs the nominal orientation of every pose (q_sensor_to_world): "
                "record with a protocol that labels orientations (e.g. the 24-pose protocol)"
            )
        q_tilt = quat_from_rotvec(np.array([tilt[0], tilt[1], 0.0]))
        z_tilted = rotate_inverse(q_tilt, np.array([0.0, 0.0, 1.0]))
        q = np.asarray(q_sensor_to_world, float)
        return gravity_g * rotate_inverse(q, np.broadcast_to(z_tilted, (q.shape[0], 3)))


def _solve_rows(sdiag: np.ndarray, C: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Solve (diag(sdiag_r) + C) u_r = v_r for every row r by the adjugate (vectorised)."""
    a = sdiag[:, 0]
    e = sdiag[:, 1]
    i = sdiag[:, 2]
    b, c, d, f, g, h = C[0, 1], C[0, 2], C[1, 0], C[1, 2], C[2, 0], C[2, 1]
    A = e * i - f * h
    B = -(d * i - f * g)
    Cc = d * h - e * g
    det = a * A + b * B + c * Cc
    if np.any(np.abs(det) < 1e-12):
        raise ModelError("scale matrix S is singular at some temperature: cannot correct readings")
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    u0 = A * x + (c * h - b * i) * y + (b * f - c * e) * z
    u1 = B * x + (a * i - c * g) * y + (c * d - a * f) * z
    u2 = Cc * x + (b * g - a * h) * y + (a * e - b * d) * z
    return np.stack([u0, u1, u2], axis=1) / det[:, None]


def build_model(
    spec: str,
    add: Sequence[str] | None = None,
    effects_file: str | os.PathLike | EffectsFile | None = None,
    *,
    t_ref_degC: float = 25.0,
) -> Model:
    """Model from a preset ('model1'..'model3') or '+'-joined effect names ('bias+scale'), plus
    `add`. Unknown names raise ModelError listing the valid names; a term named twice (bias+bias,
    model3+model3, model3+bias: a preset's terms included) raises ModelError naming it."""
    ef = load_effects_file(effects_file) if isinstance(effects_file, (str, os.PathLike)) else effects_file
    tokens = [t.strip() for t in spec.split("+") if t.strip()] + [a.strip() for a in (add or []) if a.strip()]
    if not tokens:
        raise ModelError("empty model: give a preset (model1, model2, model3) or effect names")
    terms: list[str] = []
    for t in tokens:
        terms.extend(PRESETS.get(t, (t,)))
    twice = list(dict.fromkeys(t for t in terms if terms.count(t) > 1))
    if twice:
        raise ModelError(
            f"model {'+'.join(tokens)!r} names {', '.join(map(repr, twice))} twice "
            "(a preset includes its terms: model1 = bias, model2 = bias+scale, model3 = bias+scale+cross_axis)"
        )
    name = spec.strip() + "".join(f"+{a.strip()}" for a in (add or []) if a.strip())
    return Model(terms, effects_file=ef, t_ref_degC=t_ref_degC, name=name)


def orientation_free_model(m: Model, where: str) -> Model:
    """m for an unlabelled (hand-held) session, fitted orientation-free (said in a note): cross_axis
    (3 of its 6 terms are a frame rotation, unobservable without labels) becomes misalignment_tri."""
    terms = ["misalignment_tri" if t == "cross_axis" else t for t in m.terms]
    swap = " with misalignment_tri for cross_axis" if terms != list(m.terms) else ""
    note(f"{where}: no pose labels: fitted orientation-free (|f| = g on the detected still intervals){swap}")
    return build_model("+".join(dict.fromkeys(terms)), effects_file=m.effects_file) if swap else m


def model_from_spec(spec: Mapping, effects_file: str | os.PathLike | EffectsFile | None = None) -> Model:
    """Inverse of Model.to_spec. A spec that needs user effects never loads code by itself: the
    effects file comes from the caller (the user's --effects-file); its SHA-256 is checked against
    the one the spec recorded before the file is executed."""
    try:
        terms = list(spec["terms"])
    except (KeyError, TypeError) as exc:
        raise ModelError("model spec has no 'terms' list") from exc
    if not all(isinstance(t, str) for t in terms):
        raise ModelError("model spec 'terms' must be effect names (strings)")
    user_terms = [t for t in terms if t not in LIBRARY]
    recorded = spec.get("effects_file")
    want = spec.get("effects_file_sha256")
    ef = None
    if user_terms:  # a recorded file whose effects the model does not use needs no code
        ef = _user_effects(user_terms, recorded, want, effects_file)
    try:
        t_ref = float(spec.get("t_ref_degC", 25.0))
    except (TypeError, ValueError):
        raise ModelError(f"model spec t_ref_degC = {spec.get('t_ref_degC')!r} is not a number") from None
    return Model(terms, effects_file=ef, t_ref_degC=t_ref, name=spec.get("name"))


def check_effects_hash(user_terms: Sequence[str], want: object) -> None:
    """ModelError unless a spec with user terms records the SHA-256 of their file (64 hex digits):
    without it no file could be checked before it runs, so none is run (null, missing or malformed)."""
    if not (isinstance(want, str) and re.fullmatch(r"[0-9a-f]{64}", want)):
        names = ", ".join(repr(t) for t in user_terms)
        raise ModelError(
            f"this calibration's model uses user effect(s) {names} but records no valid sha256 of "
            f"their effects file (effects_file_sha256 = {want!r}): no file is run for it; refit with "
            "--effects-file F.py"
        )


def _user_effects(user_terms, recorded, want, given) -> EffectsFile:
    """The user's effects file for a spec with user terms: given by the user, hash-checked first
    (check_effects_hash: a spec without a valid recorded hash runs nothing)."""
    names = ", ".join(repr(t) for t in user_terms) or "(none named)"
    check_effects_hash(user_terms, want)
    if given is None:
        raise ModelError(
            f"this calibration's model uses user effect(s) {names} from an effects file "
            f"(recorded as {Path(str(recorded)).name!r}, sha256 {want[:16]}…); accellog never runs code "
            "named inside a data file: pass --effects-file F.py to run that file"
        )
    if isinstance(given, EffectsFile):
        if given.sha256 != want:
            raise ModelError(
                f"effects file {given.path} has sha256 {given.sha256[:16]}…, the calibration was fitted "
                f"with {want[:16]}…: pass the file it was fitted with, or refit"
            )
        return given
    return load_effects_file(given, expect_sha256=want)
