"""The model ladder: one typed row per model-building step (model1 -> model2 -> model3 -> + each
found effect), judged on the calibration windows (chi^2/dof, RMS), on a held-out session (RMS and
noise floor, g) and, optionally, by the |displacement| of a static test integrated with the model
(m at drift_at_s). Built here once; rendered by accellog.present.tables.ladder_table, logged by
accellog.present.rrd.recording.RunRecording.log_ladder, serialised by LadderRow.to_dict.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from accellog.calibrate.diagnosis.transfer import predictive_stats
from accellog.calibrate.model.compose import Model
from accellog.calibrate.model.fit import FitResult, fit_model
from accellog.core.jsonio import JsonResult
from accellog.core.session import ObsTable

_HELD = ("heldout_rms_g", "heldout_noise_g", "heldout_chi2_dof", "heldout_chi2_dof_noise")


def _num(v: Any) -> float | None:
    """Finite float or None (JSON null)."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


@dataclass
class LadderRow(JsonResult):
    """One model-building step.

    chi2_dof, rms_g: fit quality on the calibration windows (rms in g); heldout_rms_g /
    heldout_noise_g: RMS of the held-out residuals and RMS of their sigma_g (g); heldout_chi2_dof:
    held-out chi2 per equation with the predictive covariance (calibrate.transfer.predictive_chi2:
    ~1 when the model predicts the other session as well as it fits its own), heldout_chi2_dof_noise:
    mean (r / sigma)^2 against the window noise alone (how far from the noise floor); drift_m: |displacement| (m) of the static test integrated with this
    model at drift_at_s (s). fit (FitOutcome or FitResult) and residual_g ((n,3) g on the calibration
    windows) are kept for plots and the calibration file, never serialised.
    """

    model: str
    n_params: int
    chi2_dof: float | None
    rms_g: float | None = None
    added: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    heldout_rms_g: float | None = None
    heldout_noise_g: float | None = None
    heldout_chi2_dof: float | None = None
    heldout_chi2_dof_noise: float | None = None
    drift_m: float | None = None
    drift_at_s: float | None = None
    fit: Any = field(default=None, repr=False, compare=False)
    residual_g: np.ndarray | None = field(default=None, repr=False, compare=False)

    @property
    def drift_key(self) -> str | None:
        """The documented JSON key of the drift column, ``drift_<at_s>s_m`` (e.g. drift_60s_m)."""
        return None if self.drift_at_s is None else f"drift_{self.drift_at_s:g}s_m"

    def to_dict(self) -> dict:
        """The workbench --json ladder row: model, added, n_params, chi2_dof, rms_g, warnings, and
        when measured heldout_* (g), drift_at_s (s) with drift_<at_s>s_m (m, the older key)."""
        d: dict[str, Any] = {
            "model": self.model,
            "added": list(self.added),
            "n_params": int(self.n_params),
            "chi2_dof": _num(self.chi2_dof),
            "rms_g": _num(self.rms_g),
            "warnings": list(self.warnings),
        }
        for k in _HELD:
            if getattr(self, k) is not None:
                d[k] = _num(getattr(self, k))
        if self.drift_at_s is not None and self.drift_key is not None:
            d["drift_at_s"] = float(self.drift_at_s)
            d[self.drift_key] = _num(self.drift_m)
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> LadderRow:
        """A row read back from --json output. Files written before drift_at_s existed carry only
        the ``drift_<at_s>s_m`` key: its horizon is read from that key once, here."""
        at = d.get("drift_at_s")
        if at is None:
            old = [k for k in d if k.startswith("drift_") and k.endswith("s_m")]
            at = float(old[0][len("drift_") : -len("s_m")]) if old else None
        held: dict[str, Any] = {k: _num(d.get(k)) for k in _HELD}  # the held-out statistics
        return cls(
            model=str(d["model"]),
            n_params=int(d["n_params"]),
            chi2_dof=_num(d.get("chi2_dof")),
            rms_g=_num(d.get("rms_g")),
            added=list(d.get("added") or []),
            warnings=list(d.get("warnings") or []),
            **held,
            drift_m=None if at is None else _num(d.get(f"drift_{float(at):g}s_m")),
            drift_at_s=None if at is None else float(at),
        )


def ladder_row(
    res: FitResult,
    *,
    added: Sequence[str] = (),
    heldout: ObsTable | None = None,
    fit: Any = None,
    model: str | None = None,
    scatter=None,
) -> LadderRow:
    """The row of one fitted model; held-out statistics when heldout is given (scatter: the
    search's common yardstick, variance.yardstick). fit: the object kept with the row (default
    res); model: display name (default the model's name)."""
    row = LadderRow(
        model=model or res.model.name,
        n_params=res.model.n_params,
        chi2_dof=_num(res.chi2_dof),
        rms_g=_num(res.rms_g),
        added=list(added),
        warnings=list(res.warnings),
        fit=res if fit is None else fit,
        residual_g=np.asarray(res.residual_g, dtype=np.float64),
    )
    if heldout is not None:
        for k, v in predictive_stats(res, heldout, norm=False, scatter=scatter).items():
            setattr(row, k, v)
    return row


def ladder(
    obs: ObsTable,
    steps: Sequence[Model],
    heldout_obs: ObsTable | None = None,
    *,
    weighted: bool = True,
    gravity_g: float = 1.0,
) -> list[LadderRow]:
    """One row per model fitted to obs: n_params, chi2/dof and RMS on the calibration data,
    held-out RMS (g) and noise floor (RMS of sigma_g) when heldout_obs is given."""
    return [
        ladder_row(fit_model(obs, m, weighted=weighted, gravity_g=gravity_g), heldout=heldout_obs)
        for m in steps
    ]
