"""The verdict an autopilot does not give: an export judged on a session it was not fitted on.

`accellog export cal.json --to px4|ardupilot --heldout other.mcap`: the held-out session's hold means
(its labelled holds; the window means of accellog.calibrate.observe.segment averaged per hold) go
through what the autopilot computes with the exported parameters (present.thermal_params.
held_correction: diagonal scale, offsets, the bias polynomial clamped to the exported span) and
through the full calibration (cal.correct, which extrapolates), against gravity along each hold's up
vector (g_local). Per axis: RMS (mg; gyro deg/s at rest) inside the exported temperature span, and
chi2/dof against the hold means' own noise (sigma of a hold mean = sqrt(sum sigma_w^2) / n_w over its
windows); holds outside the span are counted and their RMS given apart (the firmware holds the
correction flat there).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from accellog.calibrate.calfile.calibration import Calibration
from accellog.calibrate.observe.segment import observations
from accellog.core.errors import InputError
from accellog.core.jsonio import JsonResult
from accellog.core.units import STANDARD_GRAVITY_MPS2 as G0
from accellog.present.export_frames import temperature_span
from accellog.present.thermal_params import held_correction
from accellog.store.source import open_source


@dataclass
class ExportVerdict(JsonResult):
    """Held-out residuals of an export and of its calibration, per axis (module doc)."""

    target: str
    session: str
    span_degC: tuple[float, float]
    n_in: int
    n_out: int
    export_rms_mg: list[float]
    fit_rms_mg: list[float]
    export_chi2_dof: list[float]
    outside_rms_mg: list[float] | None
    export_gyro_rms_dps: list[float] | None
    fit_gyro_rms_dps: list[float] | None
    holds: dict = field(default_factory=dict, repr=False)
    """Per hold (not in the JSON): temp_degC (n,), after_mg (n,3) the residual with the export's
    terms, thermal_mg (n,3) what its thermal terms subtract (scaled), for the picture (write_rrd)."""

    def to_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "holds"}

    def write_rrd(self, path: str | os.PathLike) -> None:
        """The picture: per axis, the held-out hold residual against temperature without the export's
        thermal terms (what they must explain) with what they subtract drawn over it, and after
        them; the exported span marked (present.residual_views)."""
        from accellog.present.residual_views import Panel, log_panels
        from accellog.present.rrd.recording import RunRecording

        h = self.holds
        heat = np.ones(len(h["temp_degC"]), bool)
        before, after = f"{self.target} without its thermal terms", f"{self.target} export"
        items = [
            Panel(
                "temp_degC", before, h["temp_degC"], h["after_mg"] + h["thermal_mg"], heat, h["thermal_mg"]
            ),
            Panel("temp_degC", after, h["temp_degC"], h["after_mg"], heat),
        ]
        lo, hi = self.span_degC
        with RunRecording(f"save:{path}") as rec:
            marks = [(lo, f"TMIN {lo:.3g} degC"), (hi, f"TMAX {hi:.3g} degC")]
            log_panels(rec, items, main="temp_degC", marks=marks, dots="what the thermal terms subtract")

    def lines(self) -> list[str]:
        """What the header and the terminal say, one line each."""

        def three(v, f="{:.3g}"):
            return "/".join(f.format(x) for x in v) + " (x/y/z)"

        lo, hi = self.span_degC
        out = [f"held out on {self.session}: {self.n_in} holds in {lo:.3g}..{hi:.3g} degC: {self.target} leaves "
               f"{three(self.export_rms_mg)} mg RMS, chi2/dof {three(self.export_chi2_dof)} against the hold "
               f"means' noise; the full calibration {three(self.fit_rms_mg)} mg"]  # fmt: skip
        if self.export_gyro_rms_dps is not None:
            out.append(f"held out, gyro at rest: {self.target} leaves {three(self.export_gyro_rms_dps)} deg/s RMS; "
                       f"the full calibration {three(self.fit_gyro_rms_dps)} deg/s")  # fmt: skip
        if self.n_out:
            out.append(f"held out: {self.n_out} hold{'s' if self.n_out > 1 else ''} outside {lo:.3g}..{hi:.3g} degC, where {self.target} holds "
                       f"the correction flat: {three(self.outside_rms_mg)} mg RMS there")  # fmt: skip
        return out


def _rms(x: np.ndarray) -> list[float]:
    return [float(v) for v in np.sqrt(np.mean(x**2, axis=0))] if len(x) else [float("nan")] * 3


def export_verdict(cal: Calibration, target: str, heldout: str | os.PathLike) -> ExportVerdict:
    """The held-out verdict of cal exported to target on the labelled session heldout (module doc)."""
    src = open_source(heldout, what="export --heldout")
    if not src.poses:
        raise InputError(
            "--heldout needs a session with labelled holds (its hold means are judged)", where=src.where
        )
    obs = observations(src)
    starts = np.array([p.start_s for p in src.poses])
    hold = np.searchsorted(starts, obs.t_s, side="right") - 1  # the hold of each window
    ids = np.unique(hold)
    n_w = np.array([np.sum(hold == k) for k in ids])

    def per_hold(x):
        return np.array([np.asarray(x)[hold == k].mean(0) for k in ids])

    drivers = {d: getattr(obs, d) for d in cal.model.required_drivers}
    temp_w = np.asarray(obs.temp_degC, float)
    acc_w, _ = held_correction(cal, obs.meas_g, temp_w)
    thermal_w = held_correction(cal, obs.meas_g, np.full_like(temp_w, cal.model.t_ref_degC))[0] - acc_w
    truth_w = obs.up_sensor * src.meta.local_gravity_mps2
    acc, full = per_hold(acc_w - truth_w), per_hold(cal.correct_mps2(obs.meas_g, drivers) - truth_w)
    temp = per_hold(temp_w)
    sig_g = np.array([np.sqrt((obs.sigma_g[hold == k] ** 2).sum(0)) for k in ids]) / n_w[:, None]
    session, gyro = src.whole(), None
    if session.gyro_dps is not None and cal.gyro is not None:
        cut = [
            (session.t_s >= src.poses[k].start_s + 0.5) & (session.t_s <= src.poses[k].end_s - 0.5)
            for k in ids
        ]
        gyro = np.array([session.gyro_dps[m].mean(0) for m in cut])
        temp_g = (
            np.array([session.temp_degC[m].mean() for m in cut]) if session.temp_degC is not None else temp
        )
    (lo, hi), _ = temperature_span(cal)
    inside = (temp >= lo) & (temp <= hi)
    err, err_fit = acc / G0 * 1e3, full / G0 * 1e3
    chi = np.mean((acc[inside] / (G0 * sig_g[inside])) ** 2, axis=0) if inside.any() else np.full(3, np.nan)
    g_exp = g_fit = None
    if gyro is not None and cal.gyro is not None:
        g_exp = _rms(held_correction(cal, np.zeros_like(gyro), temp_g, gyro)[1][inside])
        g_fit = _rms(cal.gyro.correct(gyro, temp_g)[inside])
    return ExportVerdict(
        target=target,
        session=src.where,
        span_degC=(float(lo), float(hi)),
        n_in=int(inside.sum()),
        n_out=int((~inside).sum()),
        export_rms_mg=_rms(err[inside]),
        fit_rms_mg=_rms(err_fit[inside]),
        export_chi2_dof=[float(x) for x in chi],
        outside_rms_mg=_rms(err[~inside]) if (~inside).any() else None,
        export_gyro_rms_dps=g_exp,
        fit_gyro_rms_dps=g_fit,
        holds={"temp_degC": temp, "after_mg": err, "thermal_mg": per_hold(thermal_w) / G0 * 1e3},
    )
