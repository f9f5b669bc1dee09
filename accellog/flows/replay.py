"""Replay a recorded session through online correction + integration, paced in sensor time.

The session is a ``store.source.Source`` (an MCAP file read chunk group by chunk group: memory flat
in the session length; anything else, or a calibration reading dT/dt, in memory); the samples are fed batch by batch through ``accellog.navigate.online.OnlineIntegrator``
(one per track: the raw reading and each calibration) and logged to a ``RunRecording`` (or one in a
child process: present.rrd.offload) as they go (long series as min/max display envelopes, tracks
every k-th sample), sleeping so that sensor time advances ``speed`` times faster than wall time
(``speed=None``: as fast as possible).

For a session at rest with up vector u (sensor frame), every track is

    a = correct(reading) * mps2_per_unit - u * g_local     (m/s^2; raw: correct = identity)
    d = double trapezoid integral of a over the real timestamps (m)
    d_drift = d - (1/2 q2 t^2 + q1 t + q0)                 (when the calibration has a drift model)

which is exactly what ``accellog.navigate.evaluate`` computes in one batch (tested for equality).
``compare`` replays one test session with several calibrations side by side.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from accellog.calibrate.model.session_drivers import BlockDrivers, needs_whole_series
from accellog.core.errors import InputError
from accellog.core.session import Session
from accellog.core.timeseries import check_gap
from accellog.navigate.blocks import first_mean, mean_reading, nan_sums
from accellog.navigate.online import OnlineIntegrator
from accellog.present.rrd.entities import AXES, AXIS_COLORS, TRACKS, slug, track_color
from accellog.present.rrd.envelope import ENVELOPE_BUCKETS
from accellog.present.rrd.offload import Recording
from accellog.store.source import Source, open_source
from accellog.store.stream import ImuBlock, closed_after

MAX_BATCH_S = 60.0
"""Sensor seconds per batch when replaying as fast as possible (columnar logging)."""
PACED_UPDATES_PER_S = 20.0
"""Batches per wall-clock second when pacing (--speed 1, 4, ...)."""


@dataclass
class TrackResult:
    """Final state of one replayed track (m)."""

    label: str
    disp_end_m: np.ndarray
    disp_end_drift_m: np.ndarray | None = None
    calibration: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def final_m(self) -> np.ndarray:
        """Reported displacement: after the drift model when one was applied."""
        return self.disp_end_drift_m if self.disp_end_drift_m is not None else self.disp_end_m

    def to_dict(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "calibration": self.calibration,
            "disp_end_m": self.disp_end_m.tolist(),
            "disp_end_after_drift_m": None
            if self.disp_end_drift_m is None
            else self.disp_end_drift_m.tolist(),
            "final_m": self.final_m.tolist(),
            "final_norm_m": float(np.linalg.norm(self.final_m)),
            "notes": list(self.notes),
        }


@dataclass
class ReplayResult:
    """What a replay produced: per-track final displacement, timing, the orientation used."""

    session: str
    n: int
    t_end_s: float
    duration_s: float
    wall_s: float
    speed: float | None
    up_sensor: np.ndarray
    local_gravity_mps2: float
    tracks: list[TrackResult]
    rrd: str | None = None
    sink_report: str = ""  # what the guarded sink reports (failures), empty when all went well

    def track(self, label: str) -> TrackResult:
        for t in self.tracks:
            if t.label == label:
                return t
        raise KeyError(label)

    def to_dict(self) -> dict[str, Any]:
        return {
            "session": self.session,
            "samples": self.n,
            "t_end_s": self.t_end_s,
            "duration_s": self.duration_s,
            "wall_s": self.wall_s,
            "speed": self.speed,
            "up_sensor": self.up_sensor.tolist(),
            "local_gravity_mps2": self.local_gravity_mps2,
            "tracks": [t.to_dict() for t in self.tracks],
            "rrd": self.rrd,
        }

    def markdown(self) -> str:
        """Final drift table (markdown) for the .rrd document panel."""
        rows = [
            f"### Final displacement after {self.duration_s:.1f} s ({Path(self.session).name}, up "
            f"({self.up_sensor[0]:+.0f}, {self.up_sensor[1]:+.0f}, {self.up_sensor[2]:+.0f}), "
            f"g_local {self.local_gravity_mps2:.4f} m/s^2)\n",
            "| track | x (m) | y (m) | z (m) | abs (m) | drift model |",
            "|---|---|---|---|---|---|",
        ]
        for t in self.tracks:
            d = t.final_m
            rows.append(
                f"| {t.label} | {d[0]:+.3f} | {d[1]:+.3f} | {d[2]:+.3f} | {np.linalg.norm(d):.3f} | "
                f"{'applied' if t.disp_end_drift_m is not None else '-'} |"
            )
        notes = [n for t in self.tracks for n in t.notes]
        return "\n".join(rows) + ("\n\n" + "\n".join(f"- {n}" for n in notes) if notes else "") + "\n"


def parse_speed(text: str | float | None) -> float | None:
    """'max' -> None (no pacing); '1', '4', '0.5' -> that factor (sensor s per wall s)."""
    if text is None:
        return None
    if isinstance(text, (int, float)):
        v = float(text)
    else:
        s = str(text).strip().lower()
        if s in ("max", "inf", "0"):
            return None
        try:
            v = float(s[:-1] if s.endswith("x") else s)
        except ValueError:
            raise InputError(f"--speed {text!r}: give a factor such as 1, 4 or 'max'") from None
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"--speed {text!r}: must be a positive factor or 'max'")
    return v


def parse_up(text: str | Sequence[float] | None) -> np.ndarray | None:
    """'+z', '-x', ... or a 3-vector -> unit up vector (sensor frame); None stays None."""
    if text is None:
        return None
    if isinstance(text, str):
        from accellog.core.session import POSE_UP_VECTORS

        key = text.strip().lower()
        if key not in POSE_UP_VECTORS:
            raise InputError(f"--up {text!r}: use +x, -x, +y, -y, +z or -z")
        return np.asarray(POSE_UP_VECTORS[key], dtype=np.float64)
    v = np.asarray(text, dtype=np.float64).reshape(3)
    return v / np.linalg.norm(v)


def infer_up(session: Session) -> tuple[np.ndarray, str | None]:
    """Up vector of a static session: its single pose label, else the dominant axis of the mean."""
    return _infer_up(session.poses, lambda: np.nanmean(session.accel_g, axis=0))


def _infer_up(poses: Sequence[Any], mean: Callable[[], np.ndarray]) -> tuple[np.ndarray, str | None]:
    if len(poses) == 1:
        return np.asarray(poses[0].up_sensor, dtype=np.float64), None
    m = mean()
    i = int(np.argmax(np.abs(m)))
    up = np.zeros(3)
    up[i] = np.sign(m[i]) or 1.0
    why = "several pose labels" if poses else "no pose label"
    return up, f"orientation from the mean reading ({why}): {'+' if up[i] > 0 else '-'}{AXES[i]} up"


@dataclass
class _Track:
    label: str
    integ: OnlineIntegrator
    cal: Any = None
    needed: list[str] = field(default_factory=list)  # driver signals its calibration reads
    drift: Any = None
    notes: list[str] = field(default_factory=list)
    parts: list[np.ndarray] = field(default_factory=list)  # decimated displacement for the 3D strip
    last: np.ndarray | None = None  # displacement at the newest sample (m)


def _load_cal(c: Any):
    if isinstance(c, (str, os.PathLike)):
        from accellog.calibrate.calfile.calibration import load_calibration

        return load_calibration(c)
    return c


def _label_of(cal: Any, fallback: str) -> str:
    if getattr(cal, "path", None):
        return Path(cal.path).stem
    spec = getattr(cal, "model_spec", None) or {}
    return str(spec.get("name") or fallback)


def _tracks(cal_objs: list, labels, up: np.ndarray, g_local: float, include_raw: bool, apply_drift: bool):
    """One integrator per track: the raw reading (when include_raw), then each calibration."""
    tracks: list[_Track] = []
    if include_raw:
        tracks.append(_Track("raw", OnlineIntegrator(up_sensor=up, local_gravity_mps2=g_local)))
    used: set[str] = {t.label for t in tracks}
    for i, cal in enumerate(cal_objs):
        lab = labels[i] if labels is not None else _label_of(cal, f"cal{i + 1}")
        while lab in used:
            lab = f"{lab}'"
        used.add(lab)
        tr = _Track(lab, OnlineIntegrator.from_calibration(cal, up_sensor=up), cal=cal)
        tr.needed = list(cal.model.required_drivers)
        dm = getattr(cal, "drift", None)
        if dm is not None and apply_drift:
            if dm.up_sensor is not None and not np.allclose(dm.up_sensor, up, atol=1e-6):
                tr.notes.append(f"{lab}: drift model not applied (fitted with up {list(dm.up_sensor)})")
            else:
                tr.drift = dm
        tracks.append(tr)
    if not tracks:
        raise InputError("nothing to replay: no calibration given and the raw track is off")
    return tracks


def replay(
    session: Session | Source | str | os.PathLike,
    *,
    cals: Sequence[Any] = (),
    labels: Sequence[str] | None = None,
    speed: float | str | None = None,
    recording: Recording | None = None,
    up_sensor: str | Sequence[float] | None = None,
    include_raw: bool = True,
    apply_drift: bool = True,
    batch_s: float | None = None,
    sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] = time.monotonic,
) -> ReplayResult:
    """Replay a session (path or Session) through online correction + integration.

    A session file is streamed block by block (store.source: memory bounded by one chunk group
    plus the display series, whatever the session length) in one pass, its time stamps checked
    along it (a bad stamp refuses the file: nothing is returned; an up vector inferred from the mean
    reading: guessed from the first block, a second pass only when the whole mean disagrees); with a
    recording, which shows the samples as they go, the stamps are checked first, in the pass that
    infers the up vector when it must be (two passes). cals: Calibration
    objects or JSON paths (one track each, after the raw track when include_raw). speed: sensor seconds per wall second
    (None/'max': no pacing). recording: where to log (raw and calibrated accel and temperature as
    display envelopes, poses, events, decimated tracks, final table); None logs nothing.
    """
    t_wall0 = clock()
    speed_f = parse_speed(speed)
    cal_objs = [_load_cal(c) for c in cals]
    if labels is not None and len(labels) != len(cal_objs):
        raise InputError(f"{len(labels)} labels for {len(cal_objs)} calibrations")
    src = open_source(session, what="replay")
    if needs_whole_series({d for c in cal_objs for d in c.model.required_drivers}):
        src.whole()
    up = parse_up(up_sensor)
    mean: np.ndarray | None = None
    if recording is not None and _infers_up(up, src):  # what a recording was shown cannot be taken
        mean = src.run(mean_reading)  # back: the stamps first, in the mean reading's pass
    elif recording is not None:
        src.check()
    opts = dict(cal_objs=cal_objs, labels=labels, speed_f=speed_f, rec=recording, up=up, mean=mean,
                include_raw=include_raw, apply_drift=apply_drift, batch_s=batch_s, sleep=sleep, clock=clock,
                t_wall0=t_wall0)  # fmt: skip
    return src.run(lambda s: _replay(s, **opts))


def _infers_up(up: np.ndarray | None, src: Source) -> bool:
    """The up vector is inferred from the mean reading (none given, not one pose label)."""
    return up is None and len(src.poses) != 1


def _replay(
    src: Source, *, cal_objs, labels, speed_f, rec, up, mean, include_raw, apply_drift, batch_s, sleep, clock,
    t_wall0,
) -> ReplayResult:  # fmt: skip
    """replay's pass over the source, inside Source.run (it checks the stamps; afresh when the source
    is read again whole: no recording then, replay checked the stamps before). An up vector inferred
    from the mean reading (mean: the whole session's, known) is guessed from the first block's and
    the replay made again, a second pass, only when its own pass's mean has another face."""
    n_est, t0_s, span_s = src.extent()
    if n_est < 2:
        raise InputError(f"session has {n_est} samples: nothing to replay", where=src.where)
    notes: list[str] = []
    guessed = up is None and mean is None and len(src.poses) != 1
    given = up
    if up is None:
        up, note = _infer_up(src.poses, lambda: first_mean(src) if mean is None else mean)
        if note:
            notes.append(note)
    g_local = float(cal_objs[0].local_gravity_mps2) if cal_objs else float(src.meta.local_gravity_mps2)
    tracks = _tracks(cal_objs, labels, up, g_local, include_raw, apply_drift)
    if rec is not None:
        if src.poses:
            rec.log_poses(src.poses)
        if src.events:
            rec.log_events(src.events)
        rec.begin_batches(t0_s, t0_s + span_s, n_est)
    if batch_s is None:
        batch_s = MAX_BATCH_S if speed_f is None else max(speed_f / PACED_UPDATES_PER_S, 1e-3)
    n, t_end, mean_g = _run(src, (n_est, t0_s), tracks, rec, speed_f, batch_s, sleep, clock)
    if n < 2:
        raise InputError(f"session has {n} samples: nothing to replay", where=src.where)
    if guessed and not np.array_equal(_infer_up(src.poses, lambda: mean_g)[0], up):
        opts = dict(cal_objs=cal_objs, labels=labels, speed_f=speed_f, rec=rec, up=given, mean=mean_g,
                    include_raw=include_raw, apply_drift=apply_drift, batch_s=batch_s, sleep=sleep, clock=clock,
                    t_wall0=t_wall0)  # fmt: skip
        return _replay(src, **opts)  # the whole mean's face is not the first block's: a second pass
    results = []
    for k, tr in enumerate(tracks):
        d_end = tr.integ.disp_m
        d_drift = tr.drift.apply(np.array([t_end]), d_end[None, :])[0] if tr.drift is not None else None
        results.append(TrackResult(tr.label, d_end, d_drift, getattr(tr.cal, "path", None), notes=tr.notes))
        if rec is not None:
            final = d_drift if d_drift is not None else d_end
            rec.log_track_3d(tr.label, np.concatenate([*tr.parts, final[None, :]]), color=track_color(k))
    res = ReplayResult(
        session=str(src.where),
        n=n,
        t_end_s=t_end,
        duration_s=t_end - t0_s,
        wall_s=clock() - t_wall0,
        speed=speed_f,
        up_sensor=up,
        local_gravity_mps2=g_local,
        tracks=results,
    )
    res.tracks[0].notes[:0] = notes
    if rec is not None:
        rec.end_batches()
        rec.log_document("replay/final_displacement", res.markdown())
    return res


def _run(src, extent, tracks, rec, speed_f, batch_s, sleep, clock) -> tuple[int, float, np.ndarray]:
    """Feed every batch to every track (and the recording), paced when speed_f; returns the number
    of samples, the last sample time (s) and the mean reading (g, mean_reading's). Tracks are logged every k-th sample plus the last one,
    k = n / (2 ENVELOPE_BUCKETS) (smooth double integrals: no spike to lose); extent: (samples
    estimated, first time s)."""
    n_est, t0 = extent
    t_pace0 = clock()
    last_3d = clock()
    stride = max(1, n_est // 20_000)  # 3D strip
    slow = max(1, n_est // (2 * ENVELOPE_BUCKETS))  # displacement time series
    drivers = BlockDrivers(src.poses, src.session)
    n, t_end = 0, t0
    read_sum, read_n = np.zeros(3), np.zeros(3)
    with closed_after(batches(src.blocks(), t0, batch_s)) as cut:
        for b in cut:
            tb = b.t_s
            if speed_f is not None:
                check_gap(tb, t_end if n else None)  # a gap is refused, not slept through
                wait = t_pace0 + (float(tb[-1]) - t0) / speed_f - clock()
                if wait > 0:
                    sleep(wait)
            keep = slice(-n % slow, None, slow)  # replay samples k * slow (k * stride for the 3D strip)
            if rec is not None:
                rec.log_samples("raw", tb, b.sample_index, b.accel_g, "g")
                if b.temp_degC is not None:
                    rec.log_temperature(tb, b.temp_degC)
            for tr in tracks:
                step = tr.integ.push(tb, b.accel_g, drivers(b, n, tr.needed))
                if rec is None:  # the displacement is read from the integrator at the end
                    continue
                d = tr.drift.apply(tb, step.disp_m) if tr.drift is not None else step.disp_m
                tr.parts.append(d[-n % stride :: stride].copy())  # not a view: the batch is let go
                tr.last = d[-1]
                if tr.cal is not None:
                    rec.log_samples(tr.label, tb, None, step.f_g, "g")
                _log_track_rows(rec, tr, tb[keep], d[keep])
            n += b.n
            t_end = float(tb[-1])
            bs, bc = nan_sums(b.accel_g)
            read_sum += bs
            read_n += bc
            if rec is not None and speed_f is not None and clock() - last_3d > 1.0:
                last_3d = clock()
                for k, tr in enumerate(tracks):
                    rec.log_track_3d(
                        tr.label, np.concatenate([*tr.parts, tr.last[None, :]]), color=track_color(k)
                    )
    if rec is not None and (n - 1) % slow:  # a track ends at its final displacement
        for tr in tracks:
            _log_track_rows(rec, tr, np.array([t_end]), tr.last[None, :])
    return n, t_end, read_sum / np.maximum(read_n, 1)


def _log_track_rows(rec: Recording, tr: _Track, t_s: np.ndarray, disp_m: np.ndarray) -> None:
    names = [f"{tr.label} {a} (m)" for a in AXES]
    rec.log_series(
        f"{TRACKS}/{slug(tr.label)}", t_s, disp_m, names, role="track", colors=AXIS_COLORS, decimate=False
    )


def compare(
    test_session: Session | Source | str | os.PathLike,
    cals: Sequence[Any],
    *,
    labels: Sequence[str] | None = None,
    recording: Recording | None = None,
    up_sensor: str | Sequence[float] | None = None,
    include_raw: bool = True,
) -> ReplayResult:
    """Tracks of several calibrations of one static test session side by side (as fast as possible)."""
    if not cals:
        raise InputError("compare needs at least one --cal")
    return replay(
        test_session,
        cals=cals,
        labels=labels,
        speed=None,
        recording=recording,
        up_sensor=up_sensor,
        include_raw=include_raw,
    )


def batches(blocks, t0_s: float, batch_s: float):
    """The blocks cut where floor((t - t0) / batch_s) changes: batch k holds t0 + k batch_s <= t <
    t0 + (k+1) batch_s (s)."""
    for b in blocks:
        k = np.floor((b.t_s - t0_s) / batch_s)
        cuts = np.r_[0, np.flatnonzero(k[1:] != k[:-1]) + 1, b.n]
        for i0, i1 in zip(cuts[:-1].tolist(), cuts[1:].tolist(), strict=True):
            sl = slice(i0, i1)
            yield ImuBlock(b.meta, b.t_s[sl], b.sample_index[sl], b.accel_g[sl], _cut(b.gyro_dps, sl),
                           _cut(b.temp_degC, sl))  # fmt: skip


def _cut(a, sl: slice):
    return None if a is None else a[sl]
