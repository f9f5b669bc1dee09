"""Fleet report: per-device history, change detection ("recalibrate") and fleet distributions.

Input: FLEET/fleet.parquet written by ``accellog fleet run`` (accellog.flows.fleet).

Change detection. For each device, each pair of consecutive sessions (i, j) and each parameter p:

    sigma_eff = sigma * sqrt(max(1, chi2/dof))          (a poor fit widens its own sigmas)
    dp = p_j - p_i,    sigma_c = sqrt(sigma_eff_i^2 + sigma_eff_j^2),    z = |dp| / sigma_c

A change with z > k_sigma flags the device "recalibrate" and is reported with its size (dp in the
parameter's unit, and z). A lab session is compared with the device's previous lab session; a field
session (accellog.flows.fleet_field: the update of the device's lab calibration by a robot's stops)
with the lab calibration it updated, and when it flags, its update is the proposed calibration (a
parameter the stops did not identify stays at the prior's value: it cannot flag). k_sigma = 5 by default: a fleet of 40 devices x 3 sessions x 12
parameters makes ~1000 comparisons, so k = 1 ("larger than its combined uncertainty") would flag
almost every healthy device by chance, while at 5 sigma a Gaussian false alarm has p ~ 6e-7 per
comparison.

Distributions. The latest good session of each device gives one value per parameter; the fleet's
mean, standard deviation and range are set against the MPU-9250 datasheet limits (PS-MPU-9250A-01
Table 2: zero-g offset +-60 mg X/Y, +-80 mg Z; sensitivity +-3 %; cross-axis +-2 %). Devices
outside a limit, or further than 5 robust sigmas (1.4826 MAD) from the fleet median, are named.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from accellog.core.device import DeviceKey
from accellog.core.errors import InputError
from accellog.flows.fleet_table import TABLE_NAME, read_table

DATASHEET_LIMITS: dict[str, tuple[float, str]] = {
    "b_x": (0.060, "zero-g offset X +-60 mg (PS T2)"),
    "b_y": (0.060, "zero-g offset Y +-60 mg (PS T2)"),
    "b_z": (0.080, "zero-g offset Z +-80 mg (PS T2)"),
    **{f"S_{a}{a}": (0.03, "sensitivity tolerance +-3 % (PS T2)") for a in "xyz"},
    **{f"S_{a}{b}": (0.02, "cross-axis +-2 % (PS T2)") for a in "xyz" for b in "xyz" if a != b},
}
"""Parameter -> (limit on |deviation from nominal|, source). Nominal: 1 for S_aa, else 0."""

ROBUST_OUTLIER_SIGMAS = 5.0
ROBUST_MIN_DEVICES = 10
"""Below this many devices the MAD is too uncertain to name robust outliers."""


def nominal(param: str) -> float:
    """Ideal value of a parameter: 1 for the diagonal of S, 0 otherwise."""
    return 1.0 if len(param) == 4 and param.startswith("S_") and param[2] == param[3] else 0.0


@dataclass
class Change:
    """A parameter change between two consecutive sessions of one device."""

    param: str
    unit: str
    from_session: str
    to_session: str
    from_time_unix_ns: int
    to_time_unix_ns: int
    delta: float
    sigma_combined: float
    proposed: str | None = None
    """A field session's update (FLEET-relative calibration file) when to_session is one."""

    @property
    def z(self) -> float:
        return abs(self.delta) / self.sigma_combined if self.sigma_combined > 0 else math.inf

    def to_dict(self) -> dict[str, Any]:
        return {
            "param": self.param,
            "unit": self.unit,
            "from_session": self.from_session,
            "to_session": self.to_session,
            "from_time_unix_ns": self.from_time_unix_ns,
            "to_time_unix_ns": self.to_time_unix_ns,
            "delta": self.delta,
            "sigma_combined": self.sigma_combined,
            "z": self.z,
            "proposed_calibration": self.proposed,
        }


@dataclass
class DeviceHistory:
    """One device: its key, its sessions in time order and the changes above threshold."""

    device: str
    key: DeviceKey
    sessions: list[dict[str, Any]] = field(default_factory=list)
    """Rows of fleet.parquet (one model), sorted by start time."""
    flagged: list[Change] = field(default_factory=list)
    largest: Change | None = None
    """The largest change in z (flagged or not): how close a healthy device came."""

    @property
    def recalibrate(self) -> bool:
        return bool(self.flagged)

    @property
    def proposed(self) -> str | None:
        """The calibration proposed for the device: the latest field update that flagged, if any."""
        field = [c for c in self.flagged if c.proposed]
        return max(field, key=lambda c: c.to_time_unix_ns).proposed if field else None

    def to_dict(self) -> dict[str, Any]:
        return {
            "device": self.device,
            "key": self.key.to_dict(),
            "recalibrate": self.recalibrate,
            "n_sessions": len(self.sessions),
            "sessions": [
                {
                    "session": r["session"],
                    "time_unix_ns": r.get("start_time_unix_ns"),
                    "params": dict(zip(r["param_names"], r["values"], strict=True)),
                    "sigmas": dict(zip(r["param_names"], r["sigmas"], strict=True)),
                    "chi2_dof": r.get("chi2_dof"),
                    "heldout_rms_g": r.get("heldout_rms_g"),
                }
                for r in self.sessions
            ],
            "flagged": [c.to_dict() for c in self.flagged],
            "proposed_calibration": self.proposed,
            "largest_change": self.largest.to_dict() if self.largest else None,
        }


@dataclass
class ParamDistribution:
    """One parameter over the fleet (latest good session of each device)."""

    param: str
    unit: str
    n: int
    mean: float
    std: float
    min: float
    max: float
    limit: float | None
    limit_source: str
    outside_limit: list[str] = field(default_factory=list)
    robust_outliers: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class FleetReport:
    """Everything `accellog fleet report` shows (to_dict / to_json for --json)."""

    fleet_dir: str
    model: str
    k_sigma: float
    devices: list[DeviceHistory] = field(default_factory=list)
    distributions: list[ParamDistribution] = field(default_factory=list)
    errors: list[dict[str, str]] = field(default_factory=list)
    latest: dict[str, dict[str, Any]] = field(default_factory=dict)
    """device -> its latest good row (used for the fleet scatter)."""

    @property
    def flagged(self) -> list[DeviceHistory]:
        return [d for d in self.devices if d.recalibrate]

    @property
    def outliers(self) -> list[str]:
        names = {n for p in self.distributions for n in p.outside_limit + p.robust_outliers}
        return sorted(names)

    def to_dict(self) -> dict[str, Any]:
        return {
            "fleet_dir": self.fleet_dir,
            "model": self.model,
            "k_sigma": self.k_sigma,
            "n_devices": len(self.devices),
            "recalibrate": [d.device for d in self.flagged],
            "outliers": self.outliers,
            "devices": [d.to_dict() for d in self.devices],
            "distributions": [p.to_dict() for p in self.distributions],
            "errors": list(self.errors),
        }

    def to_json(self) -> str:
        from accellog.core.jsonio import dumps

        return dumps(self.to_dict())


def _sigma_eff(row: dict[str, Any]) -> np.ndarray:
    s = np.asarray(row["sigmas"], float)
    c = row.get("chi2_dof")
    return s * math.sqrt(max(1.0, c)) if c is not None and np.isfinite(c) else s


def device_history(device: str, rows: list[dict[str, Any]], k_sigma: float) -> DeviceHistory:
    """History and flagged changes of one device from its rows (one model, any order)."""
    rows = sorted(rows, key=lambda r: (r.get("start_time_unix_ns") or 0, r["session"]))
    h = DeviceHistory(device=device, key=DeviceKey.from_dict(rows[-1]), sessions=rows)
    for a, b in _compared(rows):
        va, vb = np.asarray(a["values"], float), np.asarray(b["values"], float)
        sc = np.hypot(_sigma_eff(a), _sigma_eff(b))
        for i, name in enumerate(a["param_names"]):
            ch = Change(
                param=name,
                unit=a["param_units"][i],
                from_session=a["session"],
                to_session=b["session"],
                from_time_unix_ns=int(a.get("start_time_unix_ns") or 0),
                to_time_unix_ns=int(b.get("start_time_unix_ns") or 0),
                delta=float(vb[i] - va[i]),
                sigma_combined=float(sc[i]),
                proposed=b.get("calibration") if b.get("field") else None,
            )
            if h.largest is None or ch.z > h.largest.z:
                h.largest = ch
            if ch.z > k_sigma:
                h.flagged.append(ch)
    h.flagged.sort(key=lambda c: -c.z)
    return h


def _compared(rows: list[dict[str, Any]]):
    """(earlier, later) row pairs of one device in time order (module doc): each lab row with the
    lab row before it, each field row with the lab row whose calibration it updated."""
    by_cal = {r.get("calibration"): r for r in rows if not r.get("field")}
    lab = None
    for b in rows:
        a = by_cal.get(b.get("prior_calibration")) if b.get("field") else lab
        if not b.get("field"):
            lab = b
        if a is not None and a["param_names"] == b["param_names"]:
            yield a, b


def distributions(latest: dict[str, dict[str, Any]]) -> list[ParamDistribution]:
    """Per-parameter fleet statistics against the datasheet limits, outlier devices named."""
    if not latest:
        return []
    devices = sorted(latest)
    names = latest[devices[0]]["param_names"]
    units = latest[devices[0]]["param_units"]
    devices = [d for d in devices if latest[d]["param_names"] == names]
    vals = np.array([latest[d]["values"] for d in devices], float)
    out = []
    for i, name in enumerate(names):
        v = vals[:, i]
        med = float(np.median(v))
        mad = 1.4826 * float(np.median(np.abs(v - med)))
        lim, src = DATASHEET_LIMITS.get(name, (None, ""))
        dev = v - nominal(name)
        out.append(
            ParamDistribution(
                param=name,
                unit=units[i],
                n=int(v.size),
                mean=float(v.mean()),
                std=float(v.std(ddof=1)) if v.size > 1 else 0.0,
                min=float(v.min()),
                max=float(v.max()),
                limit=lim,
                limit_source=src,
                outside_limit=[
                    d for d, x in zip(devices, dev, strict=True) if lim is not None and abs(x) > lim
                ],
                robust_outliers=[
                    d
                    for d, x in zip(devices, v, strict=True)
                    if v.size >= ROBUST_MIN_DEVICES and mad > 0 and abs(x - med) > ROBUST_OUTLIER_SIGMAS * mad
                ],
            )
        )
    return out


def fleet_report(fleet_dir: str | Path, *, model: str | None = None, k_sigma: float = 5.0) -> FleetReport:
    """Read FLEET/fleet.parquet and build the report for one model (default: the richest present)."""
    if not k_sigma > 0:
        raise InputError(f"k_sigma={k_sigma:g} must be > 0")
    d = Path(fleet_dir)
    table = d / TABLE_NAME if d.is_dir() else d
    if not table.exists():
        raise InputError(f"no {TABLE_NAME} here: run `accellog fleet run` first", where=str(d))
    rows = read_table(table)
    good = [r for r in rows if not r.get("error")]
    models = sorted(
        {r["model"] for r in good}, key=lambda m: max(len(r["values"]) for r in good if r["model"] == m)
    )
    if model is None:
        if not models:
            raise InputError("the fleet table has no calibrated session", where=str(table))
        model = models[-1]
    elif model not in models:
        raise InputError(f"model {model!r} is not in the fleet table (has {models})", where=str(table))
    rep = FleetReport(fleet_dir=str(d), model=model, k_sigma=float(k_sigma))
    rep.errors = [
        {"device": r.get("device") or "", "session": r["session"], "error": r["error"]}
        for r in rows
        if r.get("error")
    ]
    by_dev: dict[str, list[dict[str, Any]]] = {}
    for r in good:
        if r["model"] == model:
            by_dev.setdefault(r["device"], []).append(r)
    for dev in sorted(by_dev):
        h = device_history(dev, by_dev[dev], k_sigma)
        rep.devices.append(h)
        rep.latest[dev] = h.sessions[-1]
    rep.distributions = distributions(rep.latest)
    return rep
