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

Memory is flat in the session's length: one pass over ``store.source`` blocks feeds every check
(``doctor_scan``), a second over the stamps locates gaps and bursts when there are any. Exact as on
the whole series: counts, locations, extremes, temperature, and the interval quantiles while the
intervals take <= 2^18 distinct values (any session of <= 2^18 samples; stamps on a grid), else
rounded to ~1e-12 relative. Three checks need the whole series at once and get every m-th sample
of a session longer than 2^18 samples (m a power of 2): still intervals (their ends move inward by
~50 m samples, holds < ~101 m samples are missed), the units' medians and the clip gate's median
and MAD. A session in memory anyway (CSV, ROS 2 bag, a damaged file) is examined exactly.
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from accellog.calibrate.gyro.fit import BIAS_TRIM_S, BIAS_WINDOW_S, bias_window_times
from accellog.core.errors import InputError
from accellog.core.jsonio import dumps
from accellog.core.plausible import (
    GYRO_WINDOW_S,
    TIME_UNIT_NAME,
    TIME_UNIT_S,
    GravityTurns,
    accel_scale_guess,
    accel_unit_guess,
    gyro_counts_evidence,
    likely_time_unit,
    rate_ok,
)
from accellog.core.session import Session
from accellog.flows.doctor_scan import Gaps, Scan, Tally, flat_tops, kept_times
from accellog.store.source import Source, open_source
from accellog.store.stream import closed_after

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


def timing(scan: Scan, src: Source) -> tuple[dict, list[Finding]]:
    """Interval statistics and timing findings from the scan's interval tally; gaps and bursts are
    located in a second pass over the stamps, made only when there are any (or the tally is rounded)."""
    tally = scan.dt.done()
    med = tally.where(lambda v: v > 0).median() if tally.count(lambda v: v > 0) else 0.0
    f: list[Finding] = []
    if med <= 0:
        return {"median": 0.0}, [Finding("timing", "no two samples at distinct times", 1)]
    n_dt = tally.n
    n_gap = tally.count(lambda v: v > GAP_FACTOR * med)
    n_burst = tally.count(lambda v: (v > 0) & (v < BURST_FACTOR * med))
    g = Gaps(med, GAP_FACTOR, BURST_FACTOR)
    if not tally.exact or n_gap or n_burst > max(2, 0.001 * n_dt):
        with closed_after(src.blocks()) as blocks:
            for b in blocks:
                g.add(b.t_s)
    if g.gaps.count:
        f.append(Finding("gap", f"{g.gaps.count} gaps, ~{g.missing} samples missing, longest {g.longest_s:.4g} s",
                         g.gaps.count, g.gaps.t_s))  # fmt: skip
    if scan.dup.count:
        f.append(
            Finding("duplicate", f"{scan.dup.count} duplicated timestamps", scan.dup.count, scan.dup.t_s)
        )
    if scan.back.count:
        f.append(Finding("out_of_order", f"{scan.back.count} timestamps go backwards", scan.back.count,
                         scan.back.t_s))  # fmt: skip
    if g.bursts.count > max(2, 0.001 * n_dt):
        f.append(Finding("burst", f"{g.bursts.count} intervals < {BURST_FACTOR:g} x the median (samples arrive in bursts)",
                         g.bursts.count, g.bursts.t_s))  # fmt: skip
    reg = tally.where(lambda v: (v >= BURST_FACTOR * med) & (v <= GAP_FACTOR * med))
    dev = Tally.of(np.abs(reg.values - med), reg.counts)
    jit = float(1.4826 * dev.median() / med) if reg.n else 0.0
    p99 = float(dev.percentile(99) / med) if reg.n else 0.0
    if jit > JITTER_LIMIT or p99 > 0.25:
        f.append(Finding("jitter", f"interval jitter {100 * jit:.2g} % (99th pct |dt - median| = {100 * p99:.3g} % "
                         "of the median): integrate with the real stamps", reg.n))  # fmt: skip
    stats = {
        "median": 1e3 * med,
        "p01": 1e3 * tally.percentile(1),
        "p99": 1e3 * tally.percentile(99),
        "max": 1e3 * float(scan.dt_max),
        "jitter_rel": jit,
    }
    return stats, f


def clipping(scan: Scan, thin: Session) -> list[Finding]:
    """Saturated samples: 16-bit count limits, or flat tops (>= 3 consecutive at an exact extreme
    lying > 8 robust standard deviations from the axis median; median and MAD of the thinned series)."""
    out: list[Finding] = []
    for name, _, key in Scan.SENSORS:
        if not scan.has[name]:
            continue
        if scan.counted[name]:
            count, where = scan.sat[name].count, scan.sat[name].t_s
        else:
            values, kept = getattr(thin, key), []
            for k in range(3):
                v = values[:, k]
                med = float(np.median(v))
                spread = 1.4826 * float(np.median(np.abs(v - med)))
                for e in scan.ext[name][2 * k : 2 * k + 2]:
                    if e.value is not None and not abs(e.value - med) <= 8.0 * spread:
                        kept.append(e)  # else a constant axis or quantised noise, not a clip
            count, where = flat_tops(kept, kept_times)
        if count:
            out.append(
                Finding("clipping", f"{name}: {count} samples at full scale or a flat top", count, where)
            )
    return out


def units(scan: Scan, s: Session, m: int, rate_hz: float) -> list[Finding]:
    """Implausible rate or units (thresholds: accellog.core.plausible): a rate outside 1 Hz .. 100 kHz
    (with the time unit that would fix it), a median |accel| far from 1 g (and the unit it looks
    like), gyro values stored as deg/s that only make sense as raw counts. s: the scan's series,
    every m-th sample; the medians take every max(1, n // 200000)-th sample of the n (at least every
    m-th)."""
    out: list[Finding] = []
    if rate_hz > 0 and not rate_ok(rate_hz):
        unit = re.search(r" in (s|ms|us|ns)$", s.meta.extra.get("time_source", ""))
        declared = unit.group(1) if unit else "s"
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
    step = max(1, scan.n // 200_000 // m)
    if s.n:
        med = float(np.median(np.linalg.norm(s.accel_g[::step], axis=1)))
        if not 0.5 <= med <= 2.0:
            guess, k = accel_unit_guess(med), accel_scale_guess(med)
            looks = (
                f"x{k:g} makes it ~1 g (a full-scale mismatch): re-import with --accel-scale {k:g}"
                if guess is None and k is not None
                else "no unit or scale makes it ~1 g"
                if guess is None
                else f"the values look like {guess[0]} stored as g: re-import with --unit {guess[0]}"
                + (f" --lsb-per-g {guess[1]:g}" if guess[1] else "")
            )
            out.append(
                Finding("unit", f"accel: median |a| {med:.4g} g (a recording reads ~1 g at rest): {looks}", 1)
            )
    if s.n and s.gyro_dps is not None and not scan.counted["gyro"]:
        why = gyro_counts_evidence(s.gyro_dps[::step], scan.counted["accel"])
        if why:
            out.append(Finding("unit", f"gyro: values stored as deg/s {why}: they look like raw counts: "
                               "re-import with --gyro-unit counts --gyro-lsb-per-dps LSB", 1))  # fmt: skip
    return out


GYRO_SHORT_FACTOR = 10.0
"""The gyro integrates to less than 1/this of the turn gravity shows: its values are too small."""


def gyro_scale(s: Session, rate_hz: float) -> list[Finding]:
    """A gyro that integrates to far less than the turns gravity shows between rests (the importer's
    check, core.plausible.GravityTurns, over the scan's series s at rate_hz): r = turn / gyro
    integral > GYRO_SHORT_FACTOR is a defect; r near 180/pi is rad/s stored as deg/s."""
    if s.gyro_dps is None or s.t_s.shape[0] < 2:
        return []
    turns = GravityTurns(max(1, round(GYRO_WINDOW_S * rate_hz)))
    turns.feed(np.asarray(s.t_s, float), np.asarray(s.accel_g, float), np.asarray(s.gyro_dps, float))
    turns.finish()
    r = turns.ratio()
    if r is None or r <= GYRO_SHORT_FACTOR:
        return []
    fix = (
        "the values look like rad/s stored as deg/s: re-import with --gyro-unit rad/s"
        if turns.looks_like_rad_s()
        else "check the gyro's unit and scale (--gyro-unit, --gyro-lsb-per-dps)"
    )
    detail = (
        f"gyro: the moves between rests turn gravity by {turns.turn_deg:.0f} deg but the gyro "
        f"integrates to {turns.gyro_deg:.3g} deg ({r:.3g}x less): {fix}"
    )
    return [Finding("unit", detail, 1)]


def _distinct(up: np.ndarray, angle_deg: float = 10.0) -> int:
    reps: list[np.ndarray] = []
    lim = np.cos(np.deg2rad(angle_deg))
    for d in up:
        if not reps or np.max(np.asarray(reps) @ d) < lim:
            reps.append(d)
    return len(reps)


def still(s: Session) -> list[dict]:
    """Still intervals (detect_static; none when the log is too short or never still). s: the whole
    series, or every m-th sample of a long one (doctor_scan.Thinned): detect_static's 101-sample
    window then spans 101 m samples, intervals lose ~50 m samples at each end and holds shorter than
    ~101 m samples are missed."""
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


def supports(poses: list, has_gyro: bool, holds: list[dict], n_dir: int) -> list[Support]:
    """Which accellog calibrations the log supports, and what is missing for the others (the gyro bias:
    >= 2 whole windows of the gyro fit's, accellog.calibrate.gyro.fit.bias_window_times)."""
    faces = {p.name for p in poses}
    longest = max((h["end_s"] - h["start_s"] for h in holds), default=0.0)
    temps = [h["temp_degC"] for h in holds if h["temp_degC"] is not None]
    span = (max(temps) - min(temps)) if temps else 0.0
    iv = np.array([[h["start_s"], h["end_s"]] for h in holds], float).reshape(-1, 2)
    windows = sum(w.size - 1 for w in bias_window_times(iv, BIAS_WINDOW_S, BIAS_TRIM_S))
    return [
        Support("model3 on labelled poses (fit)", len(faces) >= 6,
                f"{len(poses)} labelled holds, {len(faces)} distinct names (needs >= 6 faces)"),
        Support("orientation-free bias+scale+misalignment_tri (fit --orientation-free)", n_dir >= 9,
                f"{n_dir} distinct still orientations (needs >= 9)"),
        Support("gyro bias", has_gyro and windows >= 2,
                "no gyro" if not has_gyro else f"{windows} whole {BIAS_WINDOW_S:g} s windows in "
                f"{len(holds)} still intervals (needs >= 2 windows)"),
        Support("temperature terms (temp_bias)", span >= 1.0,
                f"still-interval temperatures span {span:.2g} degC (needs >= 1; 3 for temp_scale)"),
        Support("noise density (export --to kalibr)", longest >= 60.0, f"longest still interval {longest:.0f} s (needs >= 60)"),
        Support("random walk (Allan, not a bound)", longest >= 3600.0, f"longest still interval {longest:.0f} s (needs >= 3600)"),
        Support("drift evaluation (evaluate / drift)", longest >= 30.0, f"longest still interval {longest:.0f} s (needs >= 30)"),
    ]  # fmt: skip


def examine(x: Source | Session, *, keep_times: bool = False) -> tuple[DoctorReport, np.ndarray | None]:
    """The doctor's report on a session (one pass over its blocks, a second over the stamps only when
    there are gaps or bursts to locate; memory flat in the length: accellog.flows.doctor_scan), and
    with keep_times every sample time (s; for the --rrd interval plot)."""
    src = open_source(x, what="doctor", check_times=False)
    return src.run(lambda s: _examine(s, keep_times))


def _examine(src: Source, keep_times: bool) -> tuple[DoctorReport, np.ndarray | None]:
    scan = Scan(bounded=not src.in_memory, keep_times=keep_times and not src.in_memory)
    with closed_after(src.blocks()) as blocks:
        for b in blocks:
            scan.add(b)
    path = (src.session.path if src.session is not None else None) or src.where
    thin, m = src.session, 1
    if thin is None:
        thin, m = scan.thin.session(src.meta, src.poses, src.events, path), scan.thin.m
    stats, findings = timing(scan, src)
    rate_hz = 1e3 / stats["median"] if stats.get("median") else 0.0
    holds = still(thin)
    findings += units(scan, thin, m, rate_hz) + gyro_scale(thin, rate_hz / m)
    findings += clipping(scan, thin)
    ev: dict[str, int] = {}
    lost = 0
    for e in src.events:
        ev[e.kind] = ev.get(e.kind, 0) + 1
        lost += e.lost_samples
    bad_ev = {
        k: v
        for k, v in ev.items()
        if k in ("gap", "fifo_overflow", "i2c_error", "misaligned", "recovered", "skipped_row")
    }
    if bad_ev:
        detail = ", ".join(f"{v} {k}" for k, v in bad_ev.items()) + f"; {lost} samples lost"
        findings.append(Finding("events", detail, sum(bad_ev.values())))
    temp = None
    if scan.temp is not None and scan.n:
        lo, hi = float(scan.temp[0]), float(scan.temp[1])
        temp = {"min": lo, "max": hi, "span": float(np.float64(hi) - np.float64(lo))}
    n_dir = _distinct(np.array([h["up"] for h in holds])) if holds else 0
    report = DoctorReport(
        path=path or "",
        source=src.meta.source,
        device=src.meta.device.to_dict(),
        samples=scan.n,
        duration_s=float(scan.last - scan.t0) if scan.last is not None and scan.t0 is not None else 0.0,
        rate_hz=rate_hz,
        jitter_rel=stats.get("jitter_rel", 0.0),
        interval_ms=stats,
        temperature_degC=temp,
        events={"by_kind": ev, "lost_samples": lost},
        still_intervals=holds,
        distinct_orientations=n_dir,
        findings=findings,
        supports=supports(src.poses, scan.has["gyro"], holds, n_dir),
    )
    times = None
    if keep_times:
        times = src.session.t_s if src.session is not None else np.concatenate(scan.times or [np.empty(0)])
    return report, times


def open_any(path: str | Path) -> Source:
    """Any input accellog reads as a session (accellog MCAP, ROS 2 bag (.mcap dir/.db3), CSVs), its
    bad stamps not refused (they are findings here)."""
    from accellog.store.importers.csv_checks import UnitsError

    p = Path(path)
    try:
        return open_source(p, what="doctor", check_times=False)
    except InputError as exc:
        if p.suffix.lower() == ".csv" and (
            isinstance(exc, UnitsError) or "duplicated timestamp" in str(exc) or "backwards" in str(exc)
        ):
            return open_source(_lenient_csv(p))  # the doctor's job is to report these, not to refuse them
        raise


def _lenient_csv(p: Path) -> Session:
    from accellog.store.importers.csv import CsvOptions, import_csv

    return import_csv(p, CsvOptions(strict_time=False, check_units=False))


def doctor(path: str | Path) -> DoctorReport:
    """Open ``path`` and examine it."""
    return examine(open_any(path))[0]
