"""The workbench keeps only effects that earn their place out of sample.

Two checks on the effects the forward loop (accellog.flows.workbench.discover) added, judged with
the loop's own evidence (held-out sessions, leave one session out, or blocks of one session):

- backward step, after each addition: every earlier effect e is refitted away; e is dropped when

      s(model - e) - s(model) <= Z_IMPROVE se(model)

  (s: out-of-sample chi2 per equation; the forward step's own margin), i.e. a later effect has made
  it redundant, or it was a proxy for what the later one explains;
- proxies, at the end: with evidence from other sessions, a final model that still does not transfer
  (flows.workbench.held_out_ok) has not found all the physics. Its added effects are judged one by
  one on the common yardstick (every model with the same repeat-free between-hold scatter,
  calibrate.model.variance.yardstick): an effect whose removal does not worsen the held-out
  chi2/dof is dropped as a proxy, one that makes unseen data better stays (the in-library part of
  what is missing), and no model seen earlier in the search is better held out than the one kept.
  The verdict says what no library effect explains, names the driver the residual follows
  (accellog.calibrate.diagnosis.driver_signals) and points to writing a user effect (docs/effects.md).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from accellog.calibrate.diagnosis.choose import Z_IMPROVE
from accellog.calibrate.diagnosis.driver_signals import MIN_DRIVER_R2
from accellog.calibrate.diagnosis.transfer import Score
from accellog.calibrate.model.compose import Model, build_model
from accellog.calibrate.model.fit import FitResult, fit_model
from accellog.core.errors import ModelError
from accellog.core.session import ObsTable

ScoreFn = Callable[[dict[str, FitResult]], dict[str, Score]]


def backward_step(
    added: list[str],
    start: str,
    effects_file,
    obs: ObsTable,
    scores: ScoreFn,
    full: FitResult | None = None,
    fit: Callable[[ObsTable, Model], FitResult] = fit_model,
) -> tuple[str, str] | None:
    """(effect, why) for the earlier added effect whose removal costs least out of sample, when it
    costs no more than Z_IMPROVE standard errors (module doc); None when every one earns its place.
    full: the fit of start + added (refitted when not given); fit: fit_model, or
    fit_orientation_free for hand-held sessions."""
    if len(added) < 2:
        return None

    def fit_of(effects: list[str]) -> FitResult:
        return fit(obs, build_model(start, add=effects, effects_file=effects_file))

    fits = {"": full if full is not None else fit_of(added)}
    for e in added[:-1]:
        try:
            fits[e] = fit_of([a for a in added if a != e])
        except ModelError:
            continue
    sc = scores(fits)
    s_full = sc.pop("")
    if not sc:
        return None
    e = min(sc, key=lambda n: sc[n].chi2_per_eq if np.isfinite(sc[n].chi2_per_eq) else np.inf)
    cost = sc[e].chi2_per_eq - s_full.chi2_per_eq
    if not cost <= Z_IMPROVE * s_full.se:
        return None
    why = (
        f"dropped after {added[-1]} was added: without it the out-of-sample chi2/eq is "
        f"{sc[e].chi2_per_eq:.3g} vs {s_full.chi2_per_eq:.3g} with it (se {s_full.se:.2g}), "
        "so it no longer earns its place"
    )
    return e, why


def residual_driver(diagnosis, obs: ObsTable | None = None) -> str:
    """'<signal> on axis <a> (partial R^2 = ..)' for the strongest significant driver signal of a
    diagnosis's residual (or its strongest signal); for a hand-held diagnosis (no signal table)
    the driver that explains most of the gravity-norm residual (R^2 of a straight line; obs: its
    windows); '' when there is none."""
    sigs = getattr(diagnosis, "driver_signals", None) or []
    top = next((s for s in sigs if s.get("significant")), sigs[0] if sigs else None)
    if top is not None:
        if top["partial_r2"] < MIN_DRIVER_R2:  # a driver is named only when it explains a real share
            return ""
        return f"{top['signal']} on axis {top['axis']} (partial R^2 = {top['partial_r2']:.2f})"
    if obs is None:
        return ""
    from accellog.calibrate.model.fit import obs_drivers

    res = diagnosis.fit
    drv = obs_drivers(obs)
    f = res.model.correct(res.theta, np.asarray(obs.meas_g, float), drv)
    fn = np.linalg.norm(f, axis=1)
    e, fhat = fn - res.gravity_g, f / fn[:, None]
    best, r2 = "", 0.0
    for name in ("temp_degC", "dtemp_degC_per_s", "t_s", "t_in_pose_s"):
        x = drv.get(name)
        if x is None or np.ptp(x) == 0 or np.ptp(e) == 0:
            continue
        for i, a in enumerate("xyz"):  # a bias b_i(x) on axis i shows in the norm as fhat_i b_i(x)
            c = float(np.corrcoef(fhat[:, i] * (x - np.mean(x)), e)[0, 1]) ** 2
            if c > r2:
                best, r2 = f"{name} on axis {a}", c
    return f"{best} (R^2 = {r2:.2f} with the gravity-norm residual)" if best and r2 >= MIN_DRIVER_R2 else ""


def no_library_effect(
    diagnosis, proxies: Sequence[str] = (), norm: str = "", obs: ObsTable | None = None
) -> str:
    """The verdict part that says no library effect explains what is left (module doc)."""
    drv = residual_driver(diagnosis, obs)
    text = "no library effect explains what is left"
    if proxies:
        text += f" ({', '.join(proxies)} fitted here but did not make the {norm}model transfer: dropped as proxies)"
    text += f"; the residual follows {drv}" if drv else "; no single driver signal explains the residual"
    return text + "; write a user effect for it (docs/effects.md) and load it with --effects-file"


def prune(found, stats_of: Callable[[str], dict | None], seen: Sequence[str] = ()) -> list[tuple[str, str]]:
    """When the final model does not transfer: drop, one at a time, the added effect whose removal
    lowers the held-out chi2/dof on the common yardstick most, while a removal does not raise it
    (an effect that makes the held-out residual better stays: never all or nothing); then, if a
    model seen earlier in the search (seen: their names) is better held out, return to it. Returns
    (effect, why) per dropped effect; found.added shrinks. Nothing happens without out-of-session
    evidence or when the final model transfers."""
    if not found.added or found.heldout is None or found.transfers is not False:
        return []
    out: list[tuple[str, str]] = []
    cur = found.heldout

    def chi2(st: dict | None) -> float:
        return np.inf if st is None else float(st["heldout_chi2_dof"])

    while found.added:
        trials = {
            e: stats_of("+".join([found.start, *[a for a in found.added if a != e]])) for e in found.added
        }
        e = min(trials, key=lambda k: chi2(trials[k]))
        if chi2(trials[e]) > chi2(cur):
            break
        out.append((e, f"a proxy: without it the held-out chi2/dof is {chi2(trials[e]):.3g}, with it "
                       f"{chi2(cur):.3g} (the same yardstick): it does not help unseen data"))  # fmt: skip
        found.added.remove(e)
        cur = trials[e]
    best = min(seen, key=lambda n: chi2(stats_of(n)), default=None)
    if best is not None and chi2(stats_of(best)) < chi2(cur):
        terms = best.split("+")[1:] if best != found.start else []
        gone = [e for e in found.added if e not in terms]
        why = f"an earlier model of the search, {best}, predicts unseen data better ({chi2(stats_of(best)):.3g} vs {chi2(cur):.3g})"
        out += [(e, why) for e in gone]
        found.added = [e for e in found.added if e in terms]
    return out
