"""The workbench's search as it went: every model tried, in order, with its held-out residual on the
common yardstick (accellog.flows.workbench: the one between-hold scatter every model is judged with).

Rows, in the order the search met them (k: the forward step that tried them):

    start        the start model
    +e  kept     an effect added at step k that is in the final model
    +e  dropped  added at step k, removed later (a backward step, or a proxy at the end)
    +e  tied     an alternative the data could not tell from the effect added at step k (not taken)
    +e  rejected a candidate of the last step that did not predict unseen data better
    -e  backward the model after a backward step removed e (a later effect made it redundant)
    -e  proxy    the model after pruning removed e (without it the held-out residual is no worse)

The path (start, +e added, -e) is what the search walked; its held-out chi2/dof per row is the
curve that should fall. Tied and rejected rows are side branches at their step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

STATUSES = ("start", "kept", "dropped", "tied", "rejected", "backward", "proxy")
REJECTED_SHOWN = 3
"""Candidates of a last step that chose nothing shown on the trail (best out-of-sample score first)."""


@dataclass
class TrailStep:
    """One model the search tried (module doc). heldout: its held-out statistics on the common
    yardstick (heldout_chi2_dof, heldout_rms_g, heldout_noise_g; None without a held-out session
    or other calibration sessions); score: the out-of-sample chi2 per equation the step judged it
    by (held-out, leave one session out or blocked validation; None for a removal)."""

    step: int
    change: str
    model: str
    status: str
    why: str = ""
    heldout: dict | None = None
    score: float | None = None
    final: bool = False

    @property
    def on_path(self) -> bool:
        """A model the search walked through (not a side branch: tied, rejected)."""
        return self.status not in ("tied", "rejected")

    @property
    def heldout_chi2_dof(self) -> float | None:
        return None if self.heldout is None else float(self.heldout["heldout_chi2_dof"])

    @property
    def heldout_rms_mg(self) -> float | None:
        return None if self.heldout is None else 1e3 * float(self.heldout["heldout_rms_g"])

    def to_dict(self) -> dict:
        return {
            "step": self.step,
            "change": self.change,
            "model": self.model,
            "status": self.status,
            "why": self.why,
            "final": self.final,
            "heldout_chi2_dof": self.heldout_chi2_dof,
            "heldout_rms_mg": self.heldout_rms_mg,
            "score_chi2_per_eq": self.score,
        }


def _name(start: str, effects) -> str:
    return "+".join([start, *effects])


def _score(choice, effect: str) -> float | None:
    s = choice.scores.get(effect)
    return None if s is None else float(s.chi2_per_eq)


def note_start(out, choice) -> None:
    """The start row (its out-of-sample score: the first step's base), once."""
    if out.trail:
        return
    base = None if choice is None else float(choice.base_score.chi2_per_eq)
    out.trail.append(TrailStep(0, out.start, out.start, "start", score=base))


def note_added(out, choice) -> None:
    """Step k added choice.chosen (out.added already holds it): its row and its tied alternatives."""
    k = len(out.choices)
    before = [e for e in out.added if e not in choice.chosen.split("+")]  # a pair: 'a+b'
    out.trail.append(
        TrailStep(
            k,
            f"+{choice.chosen}",
            _name(out.start, out.added),
            "kept",
            choice.reason,
            score=_score(choice, choice.chosen),
        )
    )
    for alt in choice.undecided:
        out.trail.append(
            TrailStep(
                k,
                f"+{alt}",
                _name(out.start, [*before, alt]),
                "tied",
                f"tied with {choice.chosen} at step {k}: the data cannot tell them apart",
                score=_score(choice, alt),
            )
        )


def note_rejected(out, choice) -> None:
    """When the last step chose nothing: its best candidates, each with why it was not taken."""
    if choice is None or choice.chosen is not None:
        return
    k = len(out.choices)
    ranked = sorted(choice.scores, key=lambda e: choice.scores[e].chi2_per_eq)
    base = float(choice.base_score.chi2_per_eq)
    for e in [e for e in ranked if e not in out.added][:REJECTED_SHOWN]:
        s = _score(choice, e)
        why = f"does not predict unseen data better ({choice.evidence} chi2/eq {base:.3g} -> {s:.3g})"
        out.trail.append(TrailStep(k, f"+{e}", _name(out.start, [*out.added, e]), "rejected", why, score=s))


def note_removed(out, effect: str, status: str, why: str, effects=None) -> None:
    """effect was removed, leaving effects (default out.added): status 'backward' or 'proxy'; the
    row that added it becomes 'dropped'."""
    k = len(out.choices)
    for row in out.trail:
        if effect in row.change[1:].split("+") and row.change[0] == "+" and row.status == "kept":
            row.status, row.why = "dropped", f"{row.why}; later removed: {why}" if row.why else why
    left = out.added if effects is None else effects
    out.trail.append(TrailStep(k, f"-{effect}", _name(out.start, left), status, why))


def finish_trail(out, stats_of: Callable[[str], dict | None] | None) -> None:
    """Each row's held-out statistics on the common yardstick (stats_of: model name -> statistics;
    None without out-of-session evidence), and the final model's row marked."""
    if stats_of is not None:
        for row in out.trail:
            row.heldout = stats_of(row.model)
    path = [r for r in out.trail if r.on_path and r.model == out.final_model]
    if path:
        path[-1].final = True
