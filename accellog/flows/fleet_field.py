"""Field sessions in a fleet: a session without pose labels (a robot's run: stops in ordinary use)
is not calibrated from scratch but updates its device's last lab calibration (run_fit with that
calibration as the prior: accellog.calibrate.model.prior); `fleet report` compares the update with
that calibration and flags "recalibrate" when a parameter moved beyond its uncertainty, the update
being the proposed calibration (fleet_report.device_history).

A fleet run has two passes (accellog.flows.fleet.run_fleet): the first runs every session; a field
session comes back as a pending row (its device's calibration may be made in the same pass). The
second runs the field sessions whose row did not update their device's latest lab calibration
(pending, or a lab session of the device came since), each task given that calibration's file.
A device with field sessions and no lab session keeps their pending rows, errors that say so. A
run whose temperatures span UNTEMPERED_SPAN_DEGC (calibrate.model.prior) with a lab calibration
without a temperature term gets temp_bias added to the prior (Calibration.with_effects; a flag
says so); its row holds the lab's parameters, its calibration file the tempco too.

Rows of field sessions have field = True and prior_calibration = the FLEET-relative file of the
calibration they updated.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

PENDING = "a field session (no pose labels): no lab calibration of this device in the fleet to update"


def lab_calibrations(rows: list[dict[str, Any]]) -> dict[str, str]:
    """device -> FLEET-relative calibration file of its latest lab (labelled) session, of its richest
    model (most parameters), from rows of fleet.parquet."""
    best: dict[str, tuple[tuple, str]] = {}
    for r in rows:
        if r.get("error") or r.get("field") or not r.get("calibration"):
            continue
        key = (r.get("start_time_unix_ns") or 0, r["session"], len(r["values"]))
        if r["device"] not in best or key > best[r["device"]][0]:
            best[r["device"]] = (key, r["calibration"])
    return {d: cal for d, (_, cal) in best.items()}


def stale_field_sessions(rows: list[dict[str, Any]], labs: dict[str, str]) -> list[str]:
    """The field sessions to (re)run in the second pass: their row did not update the device's latest
    lab calibration (pending, or a newer one since), and the device has one."""
    return sorted(
        {
            r["session"]
            for r in rows
            if r.get("field") and r.get("device") in labs and r.get("prior_calibration") != labs[r["device"]]
        }
    )


def field_priors(sessions_rows: list[dict[str, Any]], labs: dict[str, str], out: Path) -> dict[str, dict]:
    """What the second pass's tasks need: device -> {'calibration': FLEET-relative file, 'text': its
    JSON} for the devices of the given rows (small: a few kB per device)."""
    devices = {r["device"] for r in sessions_rows if r.get("device") in labs}
    return {d: {"calibration": labs[d], "text": (out / labs[d]).read_text()} for d in sorted(devices)}


def untempered(lab, temps) -> tuple:
    """(prior, flags): the lab calibration, with temp_bias added at its typical size when the run's
    temperatures span UNTEMPERED_SPAN_DEGC or more and it has no temperature term (flags say so)."""
    from accellog.calibrate.model.prior import UNTEMPERED_SPAN_DEGC

    t = np.asarray(temps if temps is not None else [], float)
    if not t.size or not np.isfinite(t).all() or np.ptp(t) < UNTEMPERED_SPAN_DEGC:
        return lab, []
    if "temp_degC" in lab.model.required_drivers:
        return lab, []
    return lab.with_effects(["temp_bias"]), [
        f"temp_bias added to the prior: the run spans {np.ptp(t):.1f} degC"
    ]


def field_result(data, base: dict[str, Any], priors: dict[str, dict]) -> dict[str, Any]:
    """session_task of a field session: {'rows', 'cals'} of the update of the device's calibration
    (priors: field_priors), or one pending row when the task was given none for the device."""
    from accellog.calibrate.calfile.calibration import calibration_from_dict
    from accellog.flows.stages import run_fit

    entry = priors.get(base.get("device") or "")
    if entry is None:
        return {"rows": [{**base, "model": "", "field": True, "error": PENDING}], "cals": {}}
    lab = calibration_from_dict(json.loads(entry["text"]), where=entry["calibration"])
    prior, flags = untempered(lab, data.temp_degC)
    fo = run_fit(data, prior=prior)
    keep = [fo.cal.param_names.index(n) for n in lab.param_names]  # the row: the lab's parameters
    row = {
        **base,
        "model": lab.model.name,
        "field": True,
        "prior_calibration": entry["calibration"],
        "param_names": list(lab.param_names),
        "param_units": list(lab.param_units),
        "values": [float(fo.cal.theta[k]) for k in keep],
        "sigmas": [float(fo.cal.sigma[k]) for k in keep],
        "chi2_dof": float(fo.fit.chi2_dof),
        "rms_g": float(fo.fit.rms_g),
        "heldout_rms_g": float("nan"),  # the stops' held-out score needs labels (the lab's own)
        "heldout_noise_g": float("nan"),
        "noise_std_g": [float(v) for v in np.mean(fo.obs.std_g, axis=0)],
        "n_obs": int(fo.obs.n),
        "flags": flags + list(fo.fit.warnings),
        "error": "",
    }
    return {"rows": [row], "cals": {row["model"]: fo.cal.to_dict()}}
