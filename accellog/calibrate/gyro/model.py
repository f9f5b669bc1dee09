"""The gyro model a calibration carries: w_meas = M w_true + b0 + b_T dT + b_T2 dT^2 (deg/s,
dT = T - T_ref degC), with 1-sigma uncertainties (fitted by accellog.calibrate.gyro.stream with the
fits of gyro.fit). b_T2 is fitted only when asked (the accelerometer model has temp_bias2); a file
without it is a linear model, and it is written only when fitted (earlier files read back byte for
byte)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from accellog.core.errors import InputError

PARAM_NAMES = [f"M{'xyz'[i]}{'xyz'[j]}" for i in range(3) for j in range(3)]
"""Names of the entries of M (row-major): M_ij maps true rate j into measured axis i."""


@dataclass
class GyroCalibration:
    """Gyro model w_meas = M w_true + b0 + b_T dT + b_T2 dT^2 (deg/s, dT = T - T_ref), with 1-sigma
    uncertainties."""

    bias_dps: np.ndarray
    bias_sigma_dps: np.ndarray
    temp_bias_dps_per_degC: np.ndarray = field(default_factory=lambda: np.zeros(3))
    temp_bias_sigma_dps_per_degC: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    t_ref_degC: float = 25.0
    temp_bias2_dps_per_degC2: np.ndarray | None = None
    """b_T2 (deg/s/degC^2), None when the bias is linear in temperature (not fitted)."""
    temp_bias2_sigma_dps_per_degC2: np.ndarray | None = None
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    """M (3,3): scale on the diagonal (1 + s), cross-axis off the diagonal."""
    matrix_sigma: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    effects: list[str] = field(default_factory=lambda: ["bias"])
    undetermined: list[str] = field(default_factory=list)
    """Entries of M the rotations did not determine (held at the identity)."""
    n_holds: int = 0
    rotation_rms_deg: float = float("nan")
    """RMS of the rotation residuals after the scale/misalignment fit (deg)."""
    clipped_moves: int = 0
    """Moves between holds left out of the scale/misalignment fit: the rate reached CLIP_NEAR of the
    gyro full scale on some axis in them (a clipped rate integrates to a wrong rotation). Not a key
    of the file: `fit` states it as a warning of the fit."""

    def bias_at(self, temp_degC: np.ndarray | float | None = None) -> np.ndarray:
        """Bias (deg/s): b0 + b_T dT + b_T2 dT^2; (3,) without temperature, (N,3) with an (N,) array."""
        if temp_degC is None:
            return np.asarray(self.bias_dps, float)
        dt = np.asarray(temp_degC, float) - self.t_ref_degC
        b = self.bias_dps + np.multiply.outer(dt, self.temp_bias_dps_per_degC)
        if self.temp_bias2_dps_per_degC2 is not None:
            b = b + np.multiply.outer(dt**2, self.temp_bias2_dps_per_degC2)
        return b

    @property
    def temp_poly_dps(self) -> np.ndarray:
        """(2,3) [b_T, b_T2] (deg/s/degC^k): the bias polynomial in dT without b0 (b_T2 zero if linear)."""
        b2 = np.zeros(3) if self.temp_bias2_dps_per_degC2 is None else self.temp_bias2_dps_per_degC2
        return np.nan_to_num(
            np.stack([np.asarray(self.temp_bias_dps_per_degC, float), np.asarray(b2, float)])
        )

    def correct(self, gyro_dps: np.ndarray, temp_degC: np.ndarray | None = None) -> np.ndarray:
        """w_true = M^-1 (w_meas - b(T)) for (N,3) rates in deg/s (temperature in degC or None)."""
        tc = temp_degC if np.any(self.temp_poly_dps != 0) else None
        w = np.asarray(gyro_dps, float) - self.bias_at(tc)
        return np.linalg.solve(self.matrix, w.T).T

    def to_dict(self) -> dict:
        """JSON-ready dict (NaN -> None), keys with units."""

        def lst(x):
            a = np.asarray(x, float)
            return np.where(np.isfinite(a), a, np.nan).tolist() if a.ndim else float(a)

        def clean(v):
            if isinstance(v, list):
                return [clean(x) for x in v]
            return None if isinstance(v, float) and not np.isfinite(v) else v

        quad = {}
        if self.temp_bias2_dps_per_degC2 is not None:
            quad = {
                "temp_bias2_dps_per_degC2": clean(lst(self.temp_bias2_dps_per_degC2)),
                "temp_bias2_sigma_dps_per_degC2": clean(lst(self.temp_bias2_sigma_dps_per_degC2)),
            }
        return {
            "model": "w_meas = M w_true + b0 + b_T (T - T_ref)" + (" + b_T2 (T - T_ref)^2" if quad else ""),
            "units": "deg/s, degC",
            "bias_dps": clean(lst(self.bias_dps)),
            "bias_sigma_dps": clean(lst(self.bias_sigma_dps)),
            "temp_bias_dps_per_degC": clean(lst(self.temp_bias_dps_per_degC)),
            "temp_bias_sigma_dps_per_degC": clean(lst(self.temp_bias_sigma_dps_per_degC)),
            **quad,
            "t_ref_degC": float(self.t_ref_degC),
            "matrix": clean(lst(self.matrix)),
            "matrix_sigma": clean(lst(self.matrix_sigma)),
            "effects": list(self.effects),
            "undetermined": list(self.undetermined),
            "n_holds": int(self.n_holds),
            "rotation_rms_deg": clean(float(self.rotation_rms_deg)),
        }

    @classmethod
    def from_dict(cls, d: dict) -> GyroCalibration:
        """Inverse of to_dict (None -> NaN). Raises InputError on missing/malformed keys."""

        def arr(key, shape, default=None):
            v = d.get(key, default)
            if v is None:
                raise InputError(f"gyro calibration lacks {key!r}")
            a = np.array(v, dtype=object)
            a = np.where(a == None, np.nan, a).astype(float)  # noqa: E711
            if a.shape != shape:
                raise InputError(f"gyro calibration {key!r} has shape {a.shape}, expected {shape}")
            return a

        quad = d.get("temp_bias2_dps_per_degC2") is not None
        try:
            rms = d.get("rotation_rms_deg")
            return cls(
                bias_dps=arr("bias_dps", (3,)),
                bias_sigma_dps=arr("bias_sigma_dps", (3,)),
                temp_bias_dps_per_degC=arr("temp_bias_dps_per_degC", (3,), [0.0] * 3),
                temp_bias_sigma_dps_per_degC=arr("temp_bias_sigma_dps_per_degC", (3,), [None] * 3),
                t_ref_degC=float(d.get("t_ref_degC", 25.0)),
                temp_bias2_dps_per_degC2=arr("temp_bias2_dps_per_degC2", (3,)) if quad else None,
                temp_bias2_sigma_dps_per_degC2=(
                    arr("temp_bias2_sigma_dps_per_degC2", (3,), [None] * 3) if quad else None
                ),
                matrix=arr("matrix", (3, 3), np.eye(3).tolist()),
                matrix_sigma=arr("matrix_sigma", (3, 3), [[None] * 3] * 3),
                effects=[str(e) for e in d.get("effects", ["bias"])],
                undetermined=[str(e) for e in d.get("undetermined", [])],
                n_holds=int(d.get("n_holds", 0)),
                rotation_rms_deg=float("nan") if rms is None else float(rms),
            )
        except (TypeError, ValueError) as exc:
            raise InputError(f"malformed gyro calibration: {exc}") from None
