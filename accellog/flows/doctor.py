"""`accellog doctor FILE`: what a log holds, what is wrong with it, and which calibrations it supports.

Timing, from the sample intervals dt_i = t_{i+1} - t_i and their median dt_m (rate = 1 / dt_m):
gaps dt > 1.5 dt_m (missing samples ~ round(dt / dt_m) - 1), duplicated stamps dt = 0, out-of-order
stamps dt < 0, bursts 0 < dt < 0.25 dt_m (samples delivered together, e.g. host-stamped FIFO reads),
jitter = 1.4826 MAD(dt) / dt_m over the regular intervals (flagged above 2 %, or when the 99th
percentile of |dt - dt_m| exceeds 25 % of dt_m). Clipping: raw counts at the 16-bit limits, or runs
of >= 3 consecutive samples at an axis's exact extreme value (a flat top) when that extreme lies more
than 8 robust standard deviations (1.4826 MAD) from the axis median. Events (gaps, FIFO
overflows, I2C errors) are counted by kind. Still intervals come from
``accellog.calibrate.observe.detect.detect_static``; what they allow decides the supported calibrations.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.jsonio import dumps
from accellog.core.plausible import (
    TIME_UNIT_NAME,
    TIME_UNIT_S,
    accel_unit_guess,
    gyro_counts_evidence,
    likely_time_unit,
    rate_ok,
)
from accellog.core.session import Session

GAP_FACTOR = 1.5
BURST_FACTOR = 0.25
JITTER_LIMIT = 0.02


@dataclass
class Finding:
    """One defect: kind, one-line detail, how many, and where (sensor times, s; at most 50 listed)."""

    kind: str
    detail: str
    count: int
    t_s: list[float] = field(default_factory=list)


@dataclass
class Support:
    calibration: str
    ok: bool
    why: str


@dataclass
class DoctorReport:
    path: str
    source: str
    device: dict
    """The session's device key (accellog.core.device.DeviceKey.to_dict(); empty fields unknown)."""
    samples: int
    duration_s: float
    rate_hz: float
    jitter_rel: float
    interval_ms: dict
    temperature_degC: dict | None
    events: dict
    still_intervals: list[dict]
    distinct_orientations: int
    findings: list[Finding]
    supports: list[Support]

    @property
    def healthy(self) -> bool:
        return not self.findings

    def to_dict(self) -> dict:
        d = asdict(self)
        d["healthy"] = self.healthy
        return d

    def to_json(self) -> str:
        return dumps(self.to_dict())


def _where(t: np.ndarray, idx: np.ndarray) -> list[float]:
    return [float(x) for x in t[idx[:50]]]


def timing(t: np.ndarray) -> tuple[dict, list[Finding], np.ndarray]:
    """Interval statistics and timing findings; also the dt array (s)."""
    dt = np.diff(t)
    pos = dt[dt > 0]
    med = float(np.median(pos)) if pos.size else 0.0
    f: list[Finding] = []
    if med <= 0:
        return {"median": 0.0}, [Finding("timing", "no two samples at distinct times", 1)], dt
    gaps = np.flatnonzero(dt > GAP_FACTOR * med)
    if gaps.size:
        missing = int(np.sum(np.round(dt[gaps] / med) - 1))
        f.append(Finding("gap", f"{gaps.size} gaps, ~{missing} samples missing, longest {dt[gaps].max():.4g} s",
                         int(gaps.size), _where(t, gaps)))  # fmt: skip
    dup = np.flatnonzero(dt == 0)
    if dup.size:
        f.append(Finding("duplicate", f"{dup.size} duplicated timestamps", int(dup.size), _where(t, dup + 1)))
    back = np.flatnonzero(dt < 0)
    if back.size:
        f.append(
            Finding(
                "out_of_order", f"{back.size} timestamps go backwards", int(back.size), _where(t, back + 1)
            )
        )
    burst = np.flatnonzero((dt > 0) & (dt < BURST_FACTOR * med))
    if burst.size > max(2, 0.001 * dt.size):
        f.append(Finding("burst", f"{burst.size} intervals < {BURST_FACTOR:g} x the median (samples arrive in bursts)",
                         int(burst.size), _where(t, burst + 1)))  # fmt: skip
    reg = dt[(dt >= BURST_FACTOR * med) & (dt <= GAP_FACTOR * med)]
    jit = float(1.4826 * np.median(np.abs(reg - med)) / med) if reg.size else 0.0
    p99 = float(np.percentile(np.abs(reg - med), 99) / med) if reg.size else 0.0
    if jit > JITTER_LIMIT or p99 > 0.25:
        f.append(Finding("jitter", f"interval jitter {100 * jit:.2g} % (99th pct |dt - median| = {100 * p99:.3g} % "
                         "of the median): integrate with the real stamps", int(reg.size)))  # fmt: skip
    stats = {
        "median": 1e3 * med,
        "p01": 1e3 * float(np.percentile(dt, 1)),
        "p99": 1e3 * float(np.percentile(dt, 99)),
        "max": 1e3 * float(dt.max()),
        "jitter_rel": jit,
    }
    return stats, f, dt


def clipping(s: Session) -> list[Finding]:
    """Saturated samples: 16-bit count limits, or flat tops (>= 3 consecutive at an exact extreme)."""
    out: list[Finding] = []
    for name, counts, values in (("accel", s.accel_counts, s.accel_g), ("gyro", s.gyro_counts, s.gyro_dps)):
        if values is None:
            continue
        if counts is not None:
            hit = np.flatnonzero(np.any((counts >= 32767) | (counts <= -32768), axis=1))
        else:
            flat = np.zeros(values.shape[0], bool)
            for k in range(3):
                v = values[:, k]
                med = float(np.median(v))
                spread = 1.4826 * float(np.median(np.abs(v - med)))
                for ext in (v.max(), v.min()):
                    if abs(ext - med) <= 8.0 * spread:  # a constant axis or quantised noise, not a clip
                        continue
                    at = (v == ext).astype(np.int8)
                    run3 = np.convolve(at, np.ones(3, np.int8), mode="valid") == 3
                    if run3.any():
                        idx = np.flatnonzero(run3)
                        flat[idx] = flat[idx + 1] = flat[idx + 2] = True
            hit = np.flatnonzero(flat)
        if hit.size:
            out.append(Finding("clipping", f"{name}: {hit.size} samples at full scale or a flat top",
                               int(hit.size), _where(s.t_s, hit)))  # fmt: skip
    return out


def units(s: Session, rate_hz: float) -> list[Finding]:
    """Implausible rate or units (thresholds: accellog.core.plausible): a rate outside 1 Hz .. 100 kHz
    (with the time unit that would fix it), a median |accel| far from 1 g (and the unit it looks
    like), gyro values stored as deg/s that only make sense as raw counts."""
    out: list[Finding] = []
    if rate_hz > 0 and not rate_ok(rate_hz):
        m = re.search(r" in (s|ms|us|ns)$", s.meta.extra.get("time_source", ""))
        declared = m.group(1) if m else "s"
        u = likely_time_unit(1.0 / rate_hz / TIME_UNIT_S[declared], declared)
        fix = (
            f"the stamps look like {TIME_UNIT_NAME[u]} read as {TIME_UNIT_NAME[declared]}: "
            f"re-import with --time-unit {u}"
            if u not in (None, declared)
            else "check the time stamps"
        )
        out.append(
            Finding("rate", f"sample rate {rate_hz:.3g} Hz is not an IMU rate (1 Hz .. 100 kHz): {fix}", 1)
        )
    step = max(1, s.n // 200_000)
    if s.n:
        med = float(np.median(np.linalg.norm(s.accel_g[::step], axis=1)))
        if not 0.5 <= med <= 2.0:
            guess = accel_unit_guess(med)
            looks = (
                "no unit makes it ~1 g"
                if guess is None
                else f"the values look like {guess[0]} stored as g: re-import with --unit {guess[0]}"
                + (f" --lsb-per-g {guess[1]:g}" if guess[1] else "")
            )
            out.append(
                Finding("unit", f"accel: median |a| {med:.4g} g (a recording reads ~1 g at rest): {looks}", 1)
            )
    if s.n and s.gyro_dps is not None and s.gyro_counts is None:
        why = gyro_counts_evidence(s.gyro_dps[::step], s.accel_counts is not None)
        if why:
            out.append(Finding("unit", f"gyro: values stored as deg/s {why}: they look like raw counts: "
                               "re-import with --gyro-unit counts --gyro-lsb-per-dps LSB", 1))  # fmt: skip
    return out


def _distinct(up: np.ndarray, angle_deg: float = 10.0) -> int:
    reps: list[np.ndarray] = []
    lim = np.cos(np.deg2rad(angle_deg))
    for d in up:
        if not reps or np.max(np.asarray(reps) @ d) < lim:
            reps.append(d)
    return len(reps)


def still(s: Session) -> list[dict]:
    """Still intervals (detect_static; none when the log is too short or never still)."""
    from accellog.calibrate.observe.detect import detect_static

    try:
        labels = detect_static(s, min_poses=1)
    except InputError:
        return []
    out = []
    for p in labels:
        sl = s.slice_time(p.start_s, p.end_s)
        temp = None if s.temp_degC is None else float(np.mean(s.temp_degC[sl]))
        out.append({"start_s": p.start_s, "end_s": p.end_s, "up": list(p.up_sensor), "temp_degC": temp})
    return out


def supports(s: Session, holds: list[dict], n_dir: int) -> list[Support]:
    """Which accellog calibrations the log supports, and what is missing for the others."""
    faces = {p.name for p in s.poses}
    longest = max((h["end_s"] - h["start_s"] for h in holds), default=0.0)
    temps = [h["temp_degC"] for h in holds if h["temp_degC"] is not None]
    span = (max(temps) - min(temps)) if temps else 0.0
    return [
        Support("model3 on labelled poses (fit)", len(faces) >= 6,
                f"{len(s.poses)} labelled holds, {len(faces)} distinct names (needs >= 6 faces)"),
        Support("orientation-free bias+scale+misalignment_tri (fit --orientation-free)", n_dir >= 9,
                f"{n_dir} distinct still orientations (needs >= 9)"),
        Support("gyro bias", s.gyro_dps is not None and len(holds) >= 2,
                "no gyro" if s.gyro_dps is None else f"{len(holds)} still intervals (needs >= 2)"),
        Support("temperature terms (temp_bias)", span >= 1.0,
                f"still-interval temperatures span {span:.2g} degC (needs >= 1; 3 for temp_scale)"),
        Support("noise density (export --to kalibr)", longest >= 60.0, f"longest still interval {longest:.0f} s (needs >= 60)"),
        Support("random walk (Allan, not a bound)", longest >= 3600.0, f"longest still interval {longest:.0f} s (needs >= 3600)"),
        Support("drift evaluation (evaluate / drift)", longest >= 30.0, f"longest still interval {longest:.0f} s (needs >= 30)"),
    ]  # fmt: skip


def examine(s: Session) -> DoctorReport:
    """The doctor's report on a loaded session."""
    t = s.t_s
    stats, findings, _ = timing(t)
    findings += units(s, 1e3 / stats["median"] if stats.get("median") else 0.0)
    findings += clipping(s)
    ev: dict[str, int] = {}
    lost = 0
    for e in s.events:
        ev[e.kind] = ev.get(e.kind, 0) + 1
        lost += e.lost_samples
    bad_ev = {
        k: v for k, v in ev.items() if k in ("gap", "fifo_overflow", "i2c_error", "misaligned", "recovered")
    }
    if bad_ev:
        detail = ", ".join(f"{v} {k}" for k, v in bad_ev.items()) + f"; {lost} samples lost"
        findings.append(Finding("events", detail, sum(bad_ev.values())))
    temp = None
    if s.temp_degC is not None and s.n:
        temp = {"min": float(np.min(s.temp_degC)), "max": float(np.max(s.temp_degC)),
                "span": float(np.ptp(s.temp_degC))}  # fmt: skip
    holds = still(s)
    n_dir = _distinct(np.array([h["up"] for h in holds])) if holds else 0
    return DoctorReport(
        path=s.path or "",
        source=s.meta.source,
        device=s.meta.device.to_dict(),
        samples=s.n,
        duration_s=float(t[-1] - t[0]) if s.n else 0.0,
        rate_hz=1e3 / stats["median"] if stats.get("median") else 0.0,
        jitter_rel=stats.get("jitter_rel", 0.0),
        interval_ms=stats,
        temperature_degC=temp,
        events={"by_kind": ev, "lost_samples": lost},
        still_intervals=holds,
        distinct_orientations=n_dir,
        findings=findings,
        supports=supports(s, holds, n_dir),
    )


def load_any(path: str | Path) -> Session:
    """Any input accellog reads as a Session: accellog MCAP, ROS 2 bag (.mcap dir/.db3), CSVs."""
    from accellog.flows.stages import load_input
    from accellog.store.importers.csv_checks import UnitsError
    from accellog.store.importers.ros2 import import_ros2

    p = Path(path)
    if p.is_dir() or p.suffix == ".db3":
        return import_ros2(p)
    try:
        s = load_input(p, check_times=False)  # duplicated / out-of-order times are findings here
    except InputError as exc:
        if p.suffix == ".mcap" and _is_ros2(p):
            return import_ros2(p)
        if p.suffix.lower() == ".csv" and (
            isinstance(exc, UnitsError) or "duplicated timestamp" in str(exc) or "backwards" in str(exc)
        ):
            return _lenient_csv(p)  # the doctor's job is to report these, not to refuse them
        raise
    if not isinstance(s, Session):
        raise InputError("doctor needs samples, not a pose table or observations", where=str(p))
    return s


def _lenient_csv(p: Path) -> Session:
    from accellog.store.importers.csv import CsvOptions, import_csv

    return import_csv(p, CsvOptions(strict_time=False, check_units=False))


def _is_ros2(p: Path) -> bool:
    from mcap.reader import make_reader

    try:
        with open(p, "rb") as f:
            return make_reader(f).get_header().profile == "ros2"
    except Exception:  # not an MCAP at all: the original error stands
        return False


def doctor(path: str | Path) -> DoctorReport:
    """Load ``path`` and examine it."""
    return examine(load_any(path))
