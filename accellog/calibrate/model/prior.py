"""A calibration as prior knowledge of a fit (a Bayesian update by new data, e.g. a robot's stops).

The prior's parameters theta_p with covariance C_p = C_cal + diag(q^2) are observations too: the fit
(accellog.calibrate.model.fit.fit_orientation_free with prior=) minimises

    sum_r e_r(theta)^2 + |W (theta - theta_p)|^2,    W = L^-1,  C_p = L L^T  (Cholesky)

so a direction of theta the data do not see stays at theta_p with the prior's sigma, and one they
see moves. q (AGING, parameter units) is how far a parameter may have moved since the calibration
was made (months of use: a bias ages by milli-g); without it a lab sigma of 0.05 mg would pin an aged
bias. After the fit, r_k = var_post / var_prior says which source determined parameter k: 'prior'
(r > PRIOR_ABOVE), 'data' (r < DATA_BELOW) or 'both'; moved_sigma = (theta_k - theta_p,k) / sigma_p,k.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from accellog.calibrate.model.compose import Model
from accellog.core.errors import ModelError

AGING: dict[str, float] = {"bias": 0.01, "scale": 2e-3, "cross_axis": 5e-4, "misalignment_tri": 5e-4}
"""Default 1-sigma (parameter units: g for bias, 1 for S) a parameter may have moved since the
prior was fitted, added in quadrature to its covariance; effects not named here: 0 (the prior's own
sigma). A bias ages by milli-g over months; the sensitivity and the axes far less."""

UNTEMPERED_SPAN_DEGC = 2.0
"""Stops spanning this many degC need a temperature term: a prior without one fits one bias to every
temperature (on the emulated robot warming 20 -> 36 degC such an update, b_z moved 20 prior sigmas
and the scales by 10 %, was worse than the lab calibration alone; with temp_bias added at its
typical size 0.015x its vector error)."""


def untempered_warning(model: Model, temp_degC, what: str) -> str | None:
    """The warning for stops spanning UNTEMPERED_SPAN_DEGC or more fitted with a prior (what) whose
    model has no temperature term: one bias is then fitted to every temperature; None otherwise."""
    if temp_degC is None or "temp_degC" in model.required_drivers:
        return None
    T = np.asarray(temp_degC, float)
    if not np.isfinite(T).all() or np.ptp(T) < UNTEMPERED_SPAN_DEGC:
        return None
    return (f"the stops span {T.min():.1f}-{T.max():.1f} degC and {what} has no temperature term: one bias "
            "is fitted to all of them; give --add temp_bias to fit the tempco from the stops")  # fmt: skip


PRIOR_ABOVE = 0.8
"""var_post / var_prior above this: the prior determined the parameter."""
DATA_BELOW = 0.2
"""var_post / var_prior below this: the data determined it."""


@dataclass(frozen=True)
class Prior:
    """theta_p (n,) and covariance C_p (n,n) in the order of a model's param_names; `what` names it
    (the calibration file). whiten: W = L^-1, C_p = L L^T."""

    names: tuple[str, ...]
    theta: np.ndarray
    cov: np.ndarray
    whiten: np.ndarray
    what: str = "prior"

    @classmethod
    def of(
        cls,
        names: Sequence[str],
        theta: np.ndarray,
        cov: np.ndarray,
        model: Model,
        *,
        aging: Mapping[str, float] | None = None,
        what: str = "prior",
    ) -> Prior:
        """The prior (names, theta, cov: a calibration's) for `model`, every parameter of which it
        must hold (ModelError naming the missing ones); aging: q per effect (default AGING)."""
        names = list(names)
        missing = [p for p in model.param_names if p not in names]
        if missing:
            raise ModelError(
                f"{what} has no value for {', '.join(missing)}: fit its model ({' + '.join(model.terms)})"
            )
        idx = [names.index(p) for p in model.param_names]
        th = np.asarray(theta, float)[idx]
        C = np.asarray(cov, float)[np.ix_(idx, idx)].copy()
        q = aging_sigma(model, AGING if aging is None else aging)
        floor = (1e-6 * model.param_typical) ** 2  # a parameter the calibration held fixed (sigma 0)
        C[np.diag_indices_from(C)] += q**2 + floor
        try:
            L = np.linalg.cholesky(C)
        except np.linalg.LinAlgError:
            raise ModelError(f"{what}: its covariance is not positive definite") from None
        W = np.linalg.solve(L, np.eye(th.size))
        return cls(tuple(model.param_names), th, C, W, what)

    @property
    def sigma(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def rows(self, theta: np.ndarray) -> np.ndarray:
        """W (theta - theta_p): the prior's whitened residual rows."""
        return self.whiten @ (np.asarray(theta, float) - self.theta)

    def sources(self, theta: np.ndarray, cov: np.ndarray) -> list[dict]:
        """Per parameter: prior and posterior value and sigma, var_post / var_prior, moved_sigma and
        the source that determined it (module doc)."""
        sp = self.sigma
        s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        out = []
        for k, name in enumerate(self.names):
            r = float(s[k] ** 2 / sp[k] ** 2)
            out.append(
                {
                    "name": name,
                    "prior": float(self.theta[k]),
                    "prior_sigma": float(sp[k]),
                    "value": float(theta[k]),
                    "sigma": float(s[k]),
                    "variance_ratio": r,
                    "moved_sigma": float((theta[k] - self.theta[k]) / sp[k]),
                    "source": "prior" if r > PRIOR_ABOVE else "data" if r < DATA_BELOW else "both",
                }
            )
        return out


def aging_sigma(model: Model, aging: Mapping[str, float]) -> np.ndarray:
    """q per parameter of `model` from q per effect (0 for effects not named)."""
    q = np.zeros(model.n_params)
    for e in model.effects:
        q[model.slices[e.name]] = float(aging.get(e.name, 0.0))
    return q


def source_line(row: dict) -> str:
    """One parameter's provenance in words: 'b_z: data (variance 0.02x the prior's, moved +4.1 sigma)'."""
    return (
        f"{row['name']}: {row['source']} (variance {row['variance_ratio']:.2g}x the prior's, "
        f"moved {row['moved_sigma']:+.1f} sigma)"
    )
