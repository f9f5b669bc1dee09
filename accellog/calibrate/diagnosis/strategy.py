"""The two residuals a discovery can judge a model by, behind one interface.

A session with pose labels is judged per axis (``LABELLED``: r = a' - predict(theta; u g), fitted by
``fit_model``); a session without them (hand-held, field) on the gravity norm (``NORM``:
e = |correct(theta; a')| - g, fitted by ``fit_orientation_free``). Everything the discovery loop
(accellog.flows.workbench.discover), the diagnosis and the held-out judgement need differs only in
these parts:

- ``fit(obs, model)``                     the least squares
- ``diagnose(obs, model, ...)``           the ranking of candidate effects (diagnose.diagnose, or
                                          diagnose.diagnose_handheld on the norm)
- ``heldout_score(res, heldout)``         chi2 per equation predicting other sessions
- ``blocked_scores(fits, obs)``           blocked validation within one session
- ``rho(res_a, res_b, base, obs)``        the canonical correlation of two candidates' columns
- ``heldout_stats(res, heldout)``         held-out RMS, noise and predictive chi2/dof of one session

(the last four: accellog.calibrate.diagnosis.transfer with norm=False or norm=True)

and are written once here on top of them: ``scores`` (the out-of-sample evidence: leave one session
out, held-out sessions, else blocks of one session) and ``choose`` (one step's choice,
accellog.calibrate.diagnosis.choose).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.diagnosis.choose import StepChoice, choose_effect, choose_pair
from accellog.calibrate.diagnosis.diagnose import (
    Diagnosis,
    diagnose,
    diagnose_handheld,
    nested_test,
    settle_choice,
)
from accellog.calibrate.diagnosis.loso import loso_score, loso_stats, mean_stats
from accellog.calibrate.diagnosis.transfer import (
    Score,
    blocked_scores,
    canonical_correlation,
    heldout_score,
    predictive_stats,
)
from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.fit import FitResult, fit_model, fit_orientation_free
from accellog.core.session import ObsTable

ScoreFn = Callable[[dict[str, FitResult]], dict[str, Score]]


@dataclass(frozen=True)
class Strategy:
    """One residual: its fit, diagnosis and out-of-sample scores (module doc)."""

    name: str
    """'labelled' or 'norm'."""
    norm: str
    """'' or 'norm ': how texts name the residual's chi2 ("held-out norm chi2/dof")."""
    fit: Callable[..., FitResult]
    diagnose_fn: Callable[..., Diagnosis]

    @property
    def on_norm(self) -> bool:
        """True for the gravity-norm residual (transfer's norm=True)."""
        return self.name == "norm"

    def heldout_score(self, res: FitResult, heldout: Sequence[ObsTable]) -> Score:
        """chi2 per equation of res predicting other sessions (transfer.heldout_score)."""
        return heldout_score(res, heldout, norm=self.on_norm)

    def blocked_scores(self, fits: dict[str, FitResult], obs: ObsTable) -> dict[str, Score]:
        """Blocked validation within one session (transfer.blocked_scores)."""
        return blocked_scores(fits, obs, norm=self.on_norm)

    def rho(self, res_a: FitResult, res_b: FitResult, base: Model, obs: ObsTable) -> float:
        """Canonical correlation of two candidates' columns (transfer.canonical_correlation)."""
        return canonical_correlation(res_a, res_b, base, obs, norm=self.on_norm)

    def heldout_stats(self, res: FitResult, heldout: ObsTable, scatter=None) -> dict[str, float]:
        """heldout_rms_g, heldout_noise_g, heldout_chi2_dof (predictive; scatter: the common
        yardstick, variance.yardstick) and heldout_chi2_dof_noise of res predicting one other
        session (transfer.predictive_stats on this residual)."""
        return predictive_stats(res, heldout, norm=self.on_norm, scatter=scatter)

    def mean_heldout_stats(
        self, res: FitResult, heldout: Sequence[ObsTable], scatter=None
    ) -> dict[str, float]:
        """heldout_stats averaged over the held-out sessions."""
        stats = [self.heldout_stats(res, h, scatter) for h in heldout]
        return {k: float(np.mean([s[k] for s in stats])) for k in stats[0]}

    def diagnose(self, obs: ObsTable, model: Model, **kw) -> Diagnosis:
        """The diagnosis of model on obs, its significant candidates judged out of sample unless
        validate=False (heldout: held-out sessions, else blocks of obs) by one ranking and one tie
        rule (labelled: diagnose.diagnose with its keywords; norm: diagnose.diagnose_handheld, then
        choose and diagnose.settle_choice)."""
        if not self.on_norm:
            return self.diagnose_fn(obs, model, **kw)
        d = self.diagnose_fn(obs, model, candidates=kw.get("candidates"))
        if kw.get("validate", True):
            self.choose(d, obs, kw.get("heldout") or [])
            settle_choice(d, obs)
        return d

    def scores(self, obs: ObsTable, held: Sequence[ObsTable], parts: Sequence[ObsTable] = ()) -> ScoreFn:
        """Out-of-sample scores of fits by name ('' = the base model): leave one session out with
        several calibration sessions (obs their concatenation), held-out sessions when given, else
        blocks of obs's temperature range and time."""
        held, parts = list(held), list(parts)

        def scores(fits: dict[str, FitResult]) -> dict[str, Score]:
            if len(parts) > 1:
                return {n: loso_score(parts, r.model, self.fit, self.heldout_score) for n, r in fits.items()}
            if held:
                return {n: self.heldout_score(r, held) for n, r in fits.items()}
            return self.blocked_scores(fits, obs)

        return scores

    def choose(
        self, d: Diagnosis, obs: ObsTable, held: Sequence[ObsTable], parts: Sequence[ObsTable] = ()
    ) -> StepChoice:
        """The out-of-sample choice among d's significant candidates (choose.choose_effect with
        this residual's scores and collinearity); also stored as d.choice."""
        d.choice = choose_effect(
            d.fit,
            d.candidates,
            d.fits,
            obs,
            scores=self.scores(obs, held, parts),
            rho=lambda a, b: self.rho(a, b, d.model, obs),
        )
        return d.choice

    def choose_pair(
        self, d: Diagnosis, obs: ObsTable, held: Sequence[ObsTable], parts: Sequence[ObsTable] = ()
    ) -> StepChoice | None:
        """Two of d's candidates that only together predict unseen data better, after d.choice chose
        no single one (choose.choose_pair with this residual's fit and scores)."""
        if d.choice is None or d.choice.chosen is not None:
            return None
        return choose_pair(d.fit, d.choice, d.fits, self.fit, obs, self.scores(obs, held, parts), nested_test)

    def final_stats(
        self,
        obs: ObsTable,
        model: Model,
        held: Sequence[ObsTable],
        parts: Sequence[ObsTable] = (),
        scatter=None,
    ) -> tuple[dict | None, list[dict | None] | None]:
        """(held-out statistics of model, per left-out session or None): averaged over the
        sessions left out one by one (several calibration sessions), or over the held-out
        sessions; (None, None) without either. scatter: the comparison's common yardstick."""
        if len(parts) > 1:
            per = loso_stats(parts, model, self.fit, lambda r, o: self.heldout_stats(r, o, scatter))
            return mean_stats(per), per
        if not held:
            return None, None
        return self.mean_heldout_stats(self.fit(obs, model), held, scatter), None


LABELLED = Strategy("labelled", "", fit_model, diagnose)
NORM = Strategy("norm", "norm ", fit_orientation_free, diagnose_handheld)
