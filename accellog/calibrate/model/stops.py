"""What unlabelled stops (still intervals of a run: a robot's, a carried device's) determine by a
gravity-norm fit, from their design alone, before fitting: identify_stops names the identified
parameters, those seen only in combination (b_z + S_zz on level stops), those an axis's gravity
range cannot reveal (van Hees 2014: below -0.3 g and above +0.3 g) and those identified only weakly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.effects import AXES
from accellog.calibrate.model.identifiability import (
    GEOMETRY_EFFECTS,
    NORM_ONLY_LABELLED,
    effect_requirement,
    norm_blind_params,
)
from accellog.core.session import ObsTable

VAN_HEES_G = 0.3
"""An axis's scale needs gravity on it below -0.3 g and above +0.3 g (van Hees 2014; actipy's calib_cube)."""

COMBINED_TOL = 0.01
"""Relative singular value below which a parameter is seen only in combination (identify_stops)."""

WEAK_TOL = 0.1
"""Relative singular value below which an identified parameter is weakly determined (identify_stops)."""

_PRIORITY = {"bias": 0, "temp_bias": 1, "scale": 2, "misalignment_tri": 3, "cross_axis": 3}
"""Acceptance order: what ages most (bias) first, its partner in a combination is kept (b_z + S_zz)."""


@dataclass
class StopIdentification:
    """What the stops identify for a gravity-norm fit of `model` (identify_stops)."""

    n_rows: int
    axis_range_g: np.ndarray  # (3,2): lowest, highest gravity component seen per axis (unit direction)
    identified: list[str]
    unfitted: list[str]  # not determined by the stops: a prior keeps them, else they stay nominal
    reasons: dict[str, str]
    condition: float  # of the column-normalised norm Jacobian of the identified parameters
    weak: list[str] = field(default_factory=list)  # identified, but mostly along barely seen directions

    def lines(self, with_prior: bool) -> list[str]:
        """The identification in words (what was fitted, what was not, and what a next run needs)."""
        rng = ", ".join(
            f"{a} [{lo:+.2f}, {hi:+.2f}]" + ("" if lo < -VAN_HEES_G and hi > VAN_HEES_G else " (< +-0.3 g)")
            for a, (lo, hi) in zip(AXES, self.axis_range_g, strict=True)
        )
        keep = "kept at the prior's value" if with_prior else "held at nominal (not fitted)"
        out = [f"{self.n_rows} still windows; gravity seen per axis (g): {rng}"]
        out.append(f"the stops identify {', '.join(self.identified) or 'nothing'}")
        out += [f"{p} not identified: {self.reasons[p]}: {keep}" for p in self.unfitted]
        if self.weak:
            out.append(self.weak_line())
        return out

    def weak_line(self) -> str:
        """What the weakly determined parameters mean for the user and what pins them."""
        return (
            f"weakly determined by these {self.n_rows} still windows: {', '.join(self.weak)} (along "
            f"directions the stops barely see, relative singular value < {WEAK_TOL:g}): their sigmas are large and "
            "a new orientation or temperature may be off by several of the stops' noise; more stops in new "
            "orientations (>= 12), or revisits at another temperature, pin them"
        )

    def to_dict(self) -> dict:
        return {
            "n_rows": self.n_rows,
            "axis_range_g": self.axis_range_g.tolist(),
            "identified": list(self.identified),
            "not_identified": {p: self.reasons[p] for p in self.unfitted},
            "condition": float(min(self.condition, 1e300)),
            "weakly_determined": list(self.weak),
        }


def identify_stops(obs: ObsTable, model: Model, start: np.ndarray | None = None) -> StopIdentification:
    """Which parameters of `model` the stops in `obs` (unlabelled still windows) determine by a
    gravity-norm fit, from their design only (the gravity directions and drivers, not the noise):

    1. per axis, the range of the gravity direction seen: a scale or cross-axis term of an axis
       that never saw below -0.3 g and above +0.3 g is not identified (van Hees 2014);
    2. effect requirements (a temperature term needs the temperature to move; effect_requirement);
    3. the norm Jacobian at `start` (default Model.initial_theta), column-normalised: parameters are
       accepted in _PRIORITY order while the smallest relative singular value of the accepted set
       stays >= COMBINED_TOL; a parameter that would break it is seen only in combination with
       the accepted ones it projects on (b_z + S_zz on level stops; b_x + S_zx near level);
    4. weakly determined (`weak`): accepted parameters that carry the most of, or > 25 % of, the
       directions of relative singular value < WEAK_TOL (10 stops warming up: S_yx, bT_x, bT_y)."""
    meas = np.asarray(obs.meas_g, float)
    dirs = meas / np.linalg.norm(meas, axis=1, keepdims=True)
    lo_hi = np.stack([dirs.min(axis=0), dirs.max(axis=0)], axis=1)
    drv = {k: np.asarray(v, float) for k in ("t_s", "t_in_pose_s", "temp_degC", "dtemp_degC_per_s")
           if (v := getattr(obs, k)) is not None and np.all(np.isfinite(v))}  # fmt: skip
    th = model.initial_theta() if start is None else np.asarray(start, float)
    J = _norm_columns(model, th, meas, drv)
    norms = np.linalg.norm(J, axis=0)
    blind = set(norm_blind_params(model))
    reasons: dict[str, str] = {}
    passes = [bool(lo < -VAN_HEES_G and hi > VAN_HEES_G) for lo, hi in lo_hi]
    rank = np.full(model.n_params, 4)
    for e in model.effects:
        rank[model.slices[e.name]] = _PRIORITY.get(e.name, 4)
    order = np.argsort(rank, kind="stable")
    accepted: list[int] = []
    for k in order:
        why = _gate(model, k, obs, drv, blind, norms[k])
        if why is None:
            s = np.linalg.svd(J[:, [*accepted, k]] / norms[[*accepted, k]], compute_uv=False)
            why = _combined(model, J, norms, accepted, k) if s[-1] < COMBINED_TOL * s[0] else None
        why = why or _van_hees(model.param_names[k], lo_hi, passes)
        if why is None:
            accepted.append(k)
        else:
            reasons[model.param_names[k]] = why
    sel = sorted(accepted)
    s, weak = np.ones(1), []
    if sel:
        _, s, vt = np.linalg.svd(J[:, sel] / norms[sel], full_matrices=False)
        few = vt[s < WEAK_TOL * s[0]] ** 2  # the directions the stops barely see, in the accepted parameters
        most = set(np.argmax(few, axis=1).tolist())  # each direction's main parameter
        weak = [model.param_names[k] for i, k in enumerate(sel) if i in most or few[:, i].sum() > 0.25]
    return StopIdentification(
        n_rows=obs.n,
        axis_range_g=lo_hi,
        identified=[model.param_names[k] for k in sel],
        unfitted=[p for p in model.param_names if p in reasons],
        reasons=reasons,
        condition=float(s[0] / s[-1]) if s[-1] > 0 else float("inf"),
        weak=weak,
    )


def _norm_columns(model: Model, th: np.ndarray, meas: np.ndarray, drv) -> np.ndarray:
    """d(|correct(theta, a')| - g)/d theta per row: central differences (any effect)."""
    steps = np.maximum(1e-4 * model.param_typical, 1e-7 * np.abs(th))
    J = np.empty((meas.shape[0], th.size))
    for k in range(th.size):
        e = np.zeros_like(th)
        e[k] = steps[k]
        fp = np.linalg.norm(model.correct(th + e, meas, drv), axis=1)
        fm = np.linalg.norm(model.correct(th - e, meas, drv), axis=1)
        J[:, k] = (fp - fm) / (2.0 * steps[k])
    return J


def _gate(model: Model, k: int, obs, drv, blind, norm: float) -> str | None:
    """Why parameter k cannot be identified whatever the Jacobian says (None: it may be)."""
    name = model.param_names[k]
    if name in blind:
        return NORM_ONLY_LABELLED
    if not norm > 0:
        return "it does not enter the gravity norm"
    for e in model.effects:
        if name in e.param_names and e.name not in GEOMETRY_EFFECTS:
            return effect_requirement(e.name, obs, drv, model)
    return None


def _van_hees(name: str, lo_hi: np.ndarray, passes: list[bool]) -> str | None:
    """Why an S-matrix term of an axis that never saw < -0.3 g and > +0.3 g is not identified."""
    axes = name[2:] if name.startswith("S_") and len(name) == 4 else name[-1] if name.startswith("sT") else ""
    bad = [a for a in dict.fromkeys(axes) if not passes[AXES.index(a)]]
    if not bad:
        return None
    lo, hi = lo_hi[AXES.index(bad[0])]
    return (
        f"axis {bad[0]} saw gravity only between {lo:+.2f} and {hi:+.2f} g (needs < -0.3 and > +0.3 g, "
        f"van Hees 2014): tilt {bad[0]} past +-{np.degrees(np.arcsin(VAN_HEES_G)):.0f} deg both ways"
    )


def _combined(model: Model, J: np.ndarray, norms: np.ndarray, accepted: list[int], k: int) -> str:
    """'only as b_z + S_zz': the accepted parameters column k projects on (|coefficient| > 0.2)."""
    A = J[:, accepted] / norms[accepted]
    c, *_ = np.linalg.lstsq(A, J[:, k] / norms[k], rcond=None)
    partners = [model.param_names[accepted[i]] for i in np.flatnonzero(np.abs(c) > 0.2)]
    both = " + ".join([*partners, model.param_names[k]])
    return f"seen only as {both} (together with {', '.join(partners)})" if partners else "barely excited"
