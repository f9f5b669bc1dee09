"""Generic CSV: header row with t (s), ax, ay, az (unit given by the caller), optional temp (degC), gx, gy,
gz (deg/s), pose, true_x, true_y, true_z, qw, qx, qy, qz.
"""

from __future__ import annotations

import contextlib
import math
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.protocol import pose_spec
from accellog.core.session import PoseLabel, Session, SessionMeta
from accellog.core.units import ACCEL_LSB_PER_G, STANDARD_GRAVITY_MPS2
from accellog.store.importers.text import (
    check_time,
    hold_end,
    line_of_row,
    rate_hz,
    read_lines,
    read_table,
)

CSV_UNITS = ("g", "m/s^2", "counts")


# ---------------------------------------------------------------------------------------------
# generic CSV

_CSV_NUMERIC = [
    "t",
    "ax",
    "ay",
    "az",
    "temp",
    "gx",
    "gy",
    "gz",
    "true_x",
    "true_y",
    "true_z",
    "qw",
    "qx",
    "qy",
    "qz",
]
_CSV_OPTIONAL = ("true_x", "true_y", "true_z", "qw", "qx", "qy", "qz")


def _unit_check(path: Path, raw: np.ndarray, unit: str, lsb_per_g: float | None) -> None:
    """Reject values whose median |a| is not ~1 g in the declared unit, suggesting the right --unit."""
    m = float(np.median(np.linalg.norm(raw, axis=1)))
    to_g = {"g": 1.0, "m/s^2": 1.0 / STANDARD_GRAVITY_MPS2, "counts": 1.0 / (lsb_per_g or 1.0)}[unit]
    if 0.5 <= m * to_g <= 2.0:
        return
    if 0.5 <= m <= 2.0:
        hint = "they look like g: use --unit g"
    elif 4.9 <= m <= 19.6:
        hint = "they look like m/s^2: use --unit m/s^2"
    elif m >= 500:
        lsb = min(ACCEL_LSB_PER_G.values(), key=lambda v: abs(math.log(m / v)))
        hint = f"they look like raw counts: use --unit counts --lsb-per-g {lsb:g}"
    else:
        hint = "check --unit (g, m/s^2 or counts with --lsb-per-g)"
    if unit == "counts" and m >= 500:
        hint = f"with --lsb-per-g {lsb_per_g:g} that is {m * to_g:.3g} g: {hint}"
    raise InputError(
        f"accelerometer values declared as {unit} have a median magnitude of {m:.4g} {unit} "
        f"(a recording should read ~1 g at rest): {hint}",
        where=str(path),
    )


def import_csv(path: str | Path, *, unit: str = "g", lsb_per_g: float | None = None) -> Session:
    """Generic CSV -> Session.

    Header row; t (s, non-decreasing), ax, ay, az in ``unit`` ('g', 'm/s^2', or 'counts' with
    lsb_per_g counts per g); optional temp (degC), gx, gy, gz (deg/s); pose (name during a static hold,
    empty otherwise: consecutive rows with one name form a hold); true_x, true_y, true_z (unit up vector
    in the sensor frame, optional for +x..-z and '+z@90'-style names); qw, qx, qy, qz (orientation).
    """
    path = Path(path)
    if unit not in CSV_UNITS:
        raise InputError(f"unknown unit {unit!r}: use one of {', '.join(CSV_UNITS)}")
    if unit == "counts" and not lsb_per_g:
        raise InputError("--unit counts needs --lsb-per-g (e.g. 16384 for +-2 g)")
    if lsb_per_g is not None and lsb_per_g <= 0:
        raise InputError(f"--lsb-per-g must be positive, got {lsb_per_g:g}")
    lines = read_lines(path)
    if not lines:
        raise InputError("empty file", where=str(path))
    names = [h.strip() for h in lines[0].split(",")]
    missing = [c for c in ("t", "ax", "ay", "az") if c not in names]
    if missing:
        raise InputError(
            f"missing column(s) {', '.join(missing)} in the header {lines[0]!r}", where=f"{path}:1"
        )
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"duplicate column(s) {', '.join(dup)}", where=f"{path}:1")
    for group in (("gx", "gy", "gz"), ("true_x", "true_y", "true_z"), ("qw", "qx", "qy", "qz")):
        present = [c for c in group if c in names]
        if present and len(present) != len(group):
            raise InputError(f"columns {', '.join(group)} must be given together", where=f"{path}:1")
    strings = tuple(n for n in names if n not in _CSV_NUMERIC)  # 'pose' and any unknown column
    cols = read_table(path, lines, 2, names, strings=strings, optional=_CSV_OPTIONAL)
    t = cols["t"]
    n = t.shape[0]
    check_time(path, lines, 2, t)
    raw = np.stack([cols["ax"], cols["ay"], cols["az"]], 1)
    _unit_check(path, raw, unit, lsb_per_g)
    extra = {"source_file": path.name, "source_unit": unit}
    ignored = [c for c in strings if c != "pose"]
    if ignored:
        extra["ignored_columns"] = ",".join(ignored)
    counts = None
    if unit == "counts":
        frac = np.flatnonzero(np.any(raw != np.round(raw), axis=1) | np.any(np.abs(raw) > 2**31 - 1, axis=1))
        if frac.size:
            no = line_of_row(lines, 2, int(frac[0]))
            raise InputError("--unit counts but ax,ay,az are not integers", where=f"{path}:{no}")
        counts = raw.astype(np.int32)
        accel_g = counts / lsb_per_g
        extra["conversion"] = f"accel_g = counts / {lsb_per_g:g}"
    elif unit == "m/s^2":
        accel_g = raw / STANDARD_GRAVITY_MPS2
        extra["conversion"] = "accel_g = a_mps2 / 9.80665 (original: a_mps2 = accel_g * 9.80665)"
    else:
        accel_g = raw
    poses = _csv_poses(path, lines, t, cols) if "pose" in cols else []
    meta = SessionMeta(
        source="import:csv",
        chip="unknown",
        accel_lsb_per_g=float(lsb_per_g) if unit == "counts" else None,
        sample_rate_hz=rate_hz(t),
        protocol=",".join(p.name for p in poses),
        extra=extra,
    )
    gyro = np.stack([cols["gx"], cols["gy"], cols["gz"]], 1) if "gx" in cols else None
    return Session(
        meta=meta,
        t_s=t,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=accel_g,
        accel_counts=counts,
        gyro_dps=gyro,
        temp_degC=cols.get("temp"),
        poses=poses,
        path=str(path),
    )


def _csv_poses(path: Path, lines: list[str], t: np.ndarray, cols: dict) -> list[PoseLabel]:
    names = np.array(["" if v is None else str(v).strip() for v in cols["pose"]], dtype=object)
    n = names.shape[0]
    starts = np.concatenate([[0], np.flatnonzero(names[1:] != names[:-1]) + 1])
    ends = np.concatenate([starts[1:], [n]])
    true = np.stack([cols["true_x"], cols["true_y"], cols["true_z"]], 1) if "true_x" in cols else None
    quat = np.stack([cols["qw"], cols["qx"], cols["qy"], cols["qz"]], 1) if "qw" in cols else None
    poses: list[PoseLabel] = []
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        name = names[s]
        if not name:
            continue
        where = f"{path}:{line_of_row(lines, 2, s)}"
        spec = None
        with contextlib.suppress(InputError):  # unknown names need true_x,true_y,true_z
            spec = pose_spec(name, 0.0)
        up = q = None
        if true is not None:
            seg = true[s:e]
            ok = np.all(np.isfinite(seg), axis=1)
            if ok.any():
                up_v = seg[ok][0]
                diff = np.flatnonzero(ok & np.any(np.abs(seg - up_v) > 1e-9, axis=1))
                if diff.size:
                    no = line_of_row(lines, 2, s + int(diff[0]))
                    raise InputError(
                        f"pose {name!r}: true_x,true_y,true_z change within the hold", where=f"{path}:{no}"
                    )
                if abs(float(np.linalg.norm(up_v)) - 1.0) > 1e-3:
                    raise InputError(
                        f"pose {name!r}: true_x,true_y,true_z = {up_v.tolist()} is not a unit vector",
                        where=where,
                    )
                up = tuple(float(v) for v in up_v)
        if up is None:
            if spec is None:
                raise InputError(
                    f"unknown pose {name!r} without true_x,true_y,true_z: use +x,-x,+y,-y,+z,-z "
                    "(optionally '@<deg>') or give the up vector",
                    where=where,
                )
            up = spec.up_sensor
        if quat is not None:
            qs = quat[s:e]
            okq = np.all(np.isfinite(qs), axis=1)
            if okq.any():
                qv = qs[okq][0]
                if abs(float(np.linalg.norm(qv)) - 1.0) > 1e-3:
                    raise InputError(
                        f"pose {name!r}: qw,qx,qy,qz = {qv.tolist()} is not a unit quaternion", where=where
                    )
                q = tuple(float(v) for v in qv)
        if q is None and spec is not None and np.allclose(spec.up_sensor, up, atol=1e-9):
            q = spec.q_sensor_to_world
        poses.append(PoseLabel(name, float(t[s]), hold_end(t, e), up, q, len(poses)))
    return poses
