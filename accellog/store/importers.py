"""Importers: other tools' recordings -> Session (-> MCAP with ``accellog.store.writer.write_session``).

- capstone (willward20/UCA-Honors-Capstone): the static test files (``t`` in s, uneven; x,y,z in g with
  quantum 1/16384 g -> stored as counts with accel_lsb_per_g = 16384 when exact) and the
  six_position_data pose tables (pose *statistics*: ``load_capstone_pose_table``).
- imucal (mad-lab-fau/imucal): a Ferraris session CSV + section list JSON (102.4 Hz, m/s^2, deg/s) or
  the pre-cut annotated_session.csv (raw counts, 204.8 Hz).
- generic CSV: header row with t (s), ax, ay, az (unit given by the caller), optional temp (degC),
  gx, gy, gz (deg/s), pose, true_x, true_y, true_z, qw, qx, qy, qz.

m/s^2 inputs are converted with g0 = 9.80665 (accel_g = a_mps2 / 9.80665); the source unit and the
conversion are recorded in meta.extra, so nothing is silently altered. Every bad input raises a
one-line InputError naming the file and line.
"""

from __future__ import annotations

import contextlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from accellog.core.errors import InputError
from accellog.core.protocol import pose_spec
from accellog.core.session import POSE_UP_VECTORS, Event, PoseLabel, Session, SessionMeta
from accellog.core.units import ACCEL_LSB_PER_G, SEED_LOCAL_GRAVITY_MPS2, STANDARD_GRAVITY_MPS2

CAPSTONE_LSB_PER_G = 16384.0
"""The capstone data are in g with quantum 1/16384 g (MPU-9250 at +-2 g)."""
IMUCAL_FERRARIS_RATE_HZ = 102.4
IMUCAL_ANNOTATED_RATE_HZ = 204.8
IMUCAL_ACCEL_LSB_PER_G = 2048.0
"""annotated_session.csv counts: 16-bit at +-16 g (inferred from imucal's K_a = 2048/9.81 per m/s^2)."""
IMUCAL_GYRO_LSB_PER_DPS = 16.384
"""annotated_session.csv gyro counts: 16-bit at +-2000 deg/s (inferred)."""
IMUCAL_POSES = {"x_p": "+x", "x_a": "-x", "y_p": "+y", "y_a": "-y", "z_p": "+z", "z_a": "-z"}
IMUCAL_ROTATIONS = ("x_rot", "y_rot", "z_rot")
CSV_UNITS = ("g", "m/s^2", "counts")


# ---------------------------------------------------------------------------------------------
# CSV helpers: fast parse with pyarrow, exact line diagnosis in Python only when something is wrong


def _lines(path: Path) -> list[str]:
    if not path.is_file():
        raise InputError("no such file", where=str(path))
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError:
        raise InputError("not a text (UTF-8) CSV file", where=str(path)) from None


def _diagnose(path: Path, lines: list[str], first: int, names: list[str], strings=(), optional=()) -> None:
    """Raise InputError at the first bad data line (1-based numbering; data starts at line ``first``)."""
    for no, line in enumerate(lines[first - 1 :], start=first):
        if not line.strip():
            continue
        parts = line.split(",")
        if len(parts) != len(names):
            raise InputError(
                f"expected {len(names)} columns ({','.join(names)}), found {len(parts)}", where=f"{path}:{no}"
            )
        for name, v in zip(names, parts, strict=True):
            v = v.strip()
            if name in strings:
                continue
            if v == "":
                if name in optional:
                    continue
                raise InputError(f"empty value in column {name!r}", where=f"{path}:{no}")
            try:
                x = float(v)
            except ValueError:
                raise InputError(f"column {name!r}: {v!r} is not a number", where=f"{path}:{no}") from None
            if not math.isfinite(x):
                raise InputError(f"column {name!r}: {v!r} is not a finite number", where=f"{path}:{no}")


def _line_of_row(lines: list[str], first: int, row: int) -> int:
    """1-based line number of data row ``row`` (blank lines are skipped by the parser)."""
    k = -1
    for no, line in enumerate(lines[first - 1 :], start=first):
        if line.strip():
            k += 1
            if k == row:
                return no
    return len(lines)


def _read_table(
    path: Path, lines: list[str], first: int, names: list[str], strings=(), optional=()
) -> dict[str, np.ndarray]:
    """Columns of the data lines from ``first`` on: float64 (NaN where an optional value is empty), str."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    if not any(line.strip() for line in lines[first - 1 :]):
        raise InputError("no data rows", where=str(path))
    types = {n: (pa.string() if n in strings else pa.float64()) for n in names}
    try:
        table = pacsv.read_csv(
            path,
            read_options=pacsv.ReadOptions(skip_rows=first - 1, column_names=names, encoding="utf8"),
            convert_options=pacsv.ConvertOptions(
                column_types=types, strings_can_be_null=False, null_values=[""]
            ),
        )
    except (pa.ArrowInvalid, UnicodeDecodeError) as exc:
        _diagnose(path, lines, first, names, strings, optional)
        raise InputError(f"cannot parse CSV: {str(exc).splitlines()[0]}", where=str(path)) from None
    out: dict[str, np.ndarray] = {}
    bad = False
    for n in names:
        col = table.column(n)
        if n in strings:
            out[n] = np.asarray(col.to_pylist(), dtype=object)
            continue
        arr = col.to_numpy(zero_copy_only=False).astype(np.float64, copy=False)
        null = np.asarray(col.is_null().to_numpy(zero_copy_only=False), dtype=bool)
        if (null.any() and n not in optional) or (~np.isfinite(arr) & ~null).any():
            bad = True
        out[n] = np.where(null, np.nan, arr)
    if bad:
        _diagnose(path, lines, first, names, strings, optional)
    return out


def _check_time(path: Path, lines: list[str], first: int, t: np.ndarray) -> None:
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        no = _line_of_row(lines, first, i)
        raise InputError(f"time goes backwards ({t[i - 1]:.9g} s -> {t[i]:.9g} s)", where=f"{path}:{no}")


def _hold_end(t: np.ndarray, end_row: int) -> float:
    """End (exclusive) of a hold ending before row end_row: that row's time, or one median dt past the end."""
    if end_row < t.shape[0]:
        return float(t[end_row])
    dt = float(np.median(np.diff(t))) if t.shape[0] > 1 else 0.0
    return float(t[-1]) + dt


def _rate_hz(t: np.ndarray) -> float:
    if t.shape[0] < 2:
        return 0.0
    dt = float(np.median(np.diff(t)))
    return 1.0 / dt if dt > 0 else 0.0


def _face_label(name: str, start_s: float, end_s: float, hold_index: int) -> PoseLabel:
    spec = pose_spec(name, end_s - start_s)
    return PoseLabel(name, start_s, end_s, spec.up_sensor, spec.q_sensor_to_world, hold_index)


# ---------------------------------------------------------------------------------------------
# capstone


@dataclass
class PoseTable:
    """Per-pose statistics (one row per pose, in g): truth, mean and standard deviation of the reading."""

    names: list[str]
    truth_g: np.ndarray  # (P,3) nominal reading (+-1 g on one axis)
    mean_g: np.ndarray  # (P,3) mean reading over the hold
    std_g: np.ndarray  # (P,3) sample standard deviation over the hold
    path: str = ""


_CAPSTONE_TABLE_COLS = ["x_true", "x_mean", "x_std", "y_true", "y_mean", "y_std", "z_true", "z_mean", "z_std"]


def load_capstone_pose_table(path: str | Path) -> PoseTable:
    """six_position_data*.csv: columns x_true (g),x_mean (g),x_std,y_true (g),... -> PoseTable (g)."""
    path = Path(path)
    lines = _lines(path)
    header = [h.split("(")[0].strip() for h in (lines[0].split(",") if lines else [])]
    if header != _CAPSTONE_TABLE_COLS:
        raise InputError(
            "not a capstone pose table: expected header x_true (g),x_mean (g),x_std,y_true (g),...,z_std",
            where=f"{path}:1",
        )
    cols = _read_table(path, lines, 2, _CAPSTONE_TABLE_COLS)
    truth = np.stack([cols["x_true"], cols["y_true"], cols["z_true"]], 1)
    mean = np.stack([cols["x_mean"], cols["y_mean"], cols["z_mean"]], 1)
    std = np.stack([cols["x_std"], cols["y_std"], cols["z_std"]], 1)
    by_vec = {v: k for k, v in POSE_UP_VECTORS.items()}
    names = [by_vec.get(tuple(float(x) for x in row), f"pose{i}") for i, row in enumerate(truth)]
    return PoseTable(names, truth, mean, std, str(path))


def import_capstone(path: str | Path) -> Session:
    """A capstone static test file (60 s or 300 s, z up) -> Session with one '+z' hold over the file.

    Lines 1-2 are a title and a malformed header ('time (s)x (g),y (g),z (g)'); rows are t (s), x, y,
    z (g). Values that are exact multiples of 1/16384 g are stored as counts (lossless), otherwise as
    accel_g doubles.
    """
    path = Path(path)
    lines = _lines(path)
    if lines and lines[0].replace(" ", "").startswith("x_true"):
        raise InputError(
            "this is a capstone pose table (per-pose means, not samples): "
            "load it with accellog.store.importers.load_capstone_pose_table",
            where=f"{path}:1",
        )
    if len(lines) < 3 or "time" not in lines[1].lower() or "x" not in lines[1].lower():
        raise InputError(
            "not a capstone test file: expected a title on line 1 and 'time (s)x (g),y (g),z (g)' on line 2",
            where=f"{path}:2",
        )
    cols = _read_table(path, lines, 3, ["t", "x", "y", "z"])
    t = cols["t"]
    _check_time(path, lines, 3, t)
    acc = np.stack([cols["x"], cols["y"], cols["z"]], 1)
    scaled = acc * CAPSTONE_LSB_PER_G
    exact = bool(np.all(scaled == np.round(scaled)) and np.all(np.abs(scaled) <= 32768))
    counts = scaled.astype(np.int32) if exact else None
    n = t.shape[0]
    extra = {
        "source_file": path.name,
        "title": lines[0].strip(),
        "source_unit": "g",
        "time": "t column, s since logging start (time.time() based, uneven)",
        "storage": "counts = g * 16384 (exact)"
        if exact
        else "accel_g doubles (values not multiples of 1/16384 g)",
    }
    meta = SessionMeta(
        source="import:capstone",
        accel_range_g=2.0,
        accel_lsb_per_g=CAPSTONE_LSB_PER_G if exact else None,
        sample_rate_hz=_rate_hz(t),
        local_gravity_mps2=SEED_LOCAL_GRAVITY_MPS2,
        protocol="static +z",
        extra=extra,
    )
    return Session(
        meta=meta,
        t_s=t,
        sample_index=np.arange(n, dtype=np.int64),
        accel_g=counts / CAPSTONE_LSB_PER_G if exact else acc,
        accel_counts=counts,
        poses=[_face_label("+z", float(t[0]), _hold_end(t, n), 0)],
        path=str(path),
    )


# ---------------------------------------------------------------------------------------------
# imucal


def _imucal_sections(path: Path, sections: Path | None, n: int) -> dict[str, tuple[int, int]]:
    sections = sections or path.with_name(path.stem + "_list.json")
    if not sections.is_file():
        raise InputError(
            f"an imucal Ferraris session needs its section list (start/end rows per label): {sections} not found",
            where=str(path),
        )
    try:
        raw = json.loads(sections.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(
            f"invalid JSON: {exc.msg if hasattr(exc, 'msg') else exc}", where=str(sections)
        ) from None
    if not isinstance(raw, dict):
        raise InputError("section list must be an object {label: {start, end}}", where=str(sections))
    out = {}
    for label, se in raw.items():
        if label not in IMUCAL_POSES and label not in IMUCAL_ROTATIONS:
            known = ", ".join([*IMUCAL_POSES, *IMUCAL_ROTATIONS])
            raise InputError(f"unknown section label {label!r} (known: {known})", where=str(sections))
        try:
            start, end = int(se["start"]), int(se["end"])
        except (TypeError, KeyError, ValueError):
            raise InputError(
                f"section {label!r} needs integer 'start' and 'end' rows", where=str(sections)
            ) from None
        if not 0 <= start < end <= n:
            raise InputError(
                f"section {label!r} rows [{start}, {end}) outside the {n} data rows", where=str(sections)
            )
        out[label] = (start, end)
    return out


def _imucal_labels(t: np.ndarray, parts: dict[str, tuple[int, int]], sample_index: np.ndarray):
    poses, events = [], []
    for label, (s, e) in sorted(parts.items(), key=lambda kv: kv[1][0]):
        end_s = _hold_end(t, e)
        if label in IMUCAL_POSES:
            poses.append(_face_label(IMUCAL_POSES[label], float(t[s]), end_s, len(poses)))
        else:
            detail = json.dumps({"label": label, "axis": label[0], "start_s": float(t[s]), "end_s": end_s})
            events.append(Event(float(t[s]), "motion_segment", detail, int(sample_index[s])))
    return poses, events


def import_imucal(
    path: str | Path, sections: str | Path | None = None, *, sample_rate_hz: float | None = None
) -> Session:
    """imucal recordings -> Session.

    - example_ferraris_session.csv (n_samples,gyr_*,acc_* in deg/s, m/s^2; 102.4 Hz) with its section
      list JSON ({label: {start, end}} rows, default <stem>_list.json): static labels x_p, x_a, ...
      become poses +x, -x, ...; x_rot/y_rot/z_rot become 'motion_segment' events.
    - annotated_session.csv (part,samples,acc_*,gyr_* raw counts; 204.8 Hz): parts as above.
    """
    path = Path(path)
    lines = _lines(path)
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    base_extra = {"source_file": path.name, "imucal_labels": json.dumps(IMUCAL_POSES)}
    if header[:1] == ["n_samples"] and set(header[1:]) == {
        "gyr_x",
        "gyr_y",
        "gyr_z",
        "acc_x",
        "acc_y",
        "acc_z",
    }:
        fs = sample_rate_hz or IMUCAL_FERRARIS_RATE_HZ
        cols = _read_table(path, lines, 2, header)
        idx = cols["n_samples"]
        if np.any(idx != np.round(idx)):
            row = int(np.flatnonzero(idx != np.round(idx))[0])
            raise InputError("n_samples must be an integer", where=f"{path}:{_line_of_row(lines, 2, row)}")
        idx = idx.astype(np.int64)
        t = idx / fs
        _check_time(path, lines, 2, t)
        parts = _imucal_sections(path, Path(sections) if sections else None, t.shape[0])
        acc_mps2 = np.stack([cols["acc_x"], cols["acc_y"], cols["acc_z"]], 1)
        gyro = np.stack([cols["gyr_x"], cols["gyr_y"], cols["gyr_z"]], 1)
        poses, events = _imucal_labels(t, parts, idx)
        extra = base_extra | {
            "source_unit": "m/s^2",
            "conversion": "accel_g = acc_mps2 / 9.80665 (original: acc_mps2 = accel_g * 9.80665)",
            "imucal_gravity_mps2": "9.81 (imucal's g for its Ferraris fit)",
            "gyro_unit": "deg/s",
            "sections": json.dumps({k: list(v) for k, v in parts.items()}),
        }
        meta = SessionMeta(
            source="import:imucal",
            chip="unknown (imucal example)",
            sample_rate_hz=fs,
            protocol="ferraris",
            extra=extra,
        )
        return Session(
            meta=meta,
            t_s=t,
            sample_index=idx,
            accel_g=acc_mps2 / STANDARD_GRAVITY_MPS2,
            gyro_dps=gyro,
            poses=poses,
            events=events,
            path=str(path),
        )
    if header == ["part", "samples", "acc_x", "acc_y", "acc_z", "gyr_x", "gyr_y", "gyr_z"]:
        fs = sample_rate_hz or IMUCAL_ANNOTATED_RATE_HZ
        cols = _read_table(path, lines, 2, header, strings=("part",))
        num = np.stack([cols[c] for c in header[1:]], 1)
        if np.any(num != np.round(num)):
            row = int(np.flatnonzero(np.any(num != np.round(num), axis=1))[0])
            raise InputError(
                "annotated session values must be integer counts",
                where=f"{path}:{_line_of_row(lines, 2, row)}",
            )
        order = np.argsort(cols["samples"], kind="stable")  # file rows are grouped by part
        num, part = num[order].astype(np.int64), cols["part"][order]
        idx = num[:, 0]
        if np.any(np.diff(idx) == 0):
            raise InputError(
                f"duplicate sample {int(idx[np.flatnonzero(np.diff(idx) == 0)[0]])}", where=str(path)
            )
        unknown = sorted(set(part.tolist()) - set(IMUCAL_POSES) - set(IMUCAL_ROTATIONS))
        if unknown:
            raise InputError(f"unknown part label(s) {unknown}", where=str(path))
        starts = np.concatenate([[0], np.flatnonzero(part[1:] != part[:-1]) + 1])
        ends = np.concatenate([starts[1:], [part.shape[0]]])
        t = idx / fs
        parts_rows = {}
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
            if part[s] in parts_rows:
                raise InputError(f"part {part[s]!r} is not one contiguous block of samples", where=str(path))
            parts_rows[part[s]] = (s, e)
        poses, events = _imucal_labels(t, parts_rows, idx)
        jumps = np.flatnonzero(np.diff(idx) > 1)
        events += [
            Event(
                float(t[j + 1]),
                "gap",
                "samples not in the pre-cut file",
                int(idx[j + 1]),
                int(idx[j + 1] - idx[j] - 1),
            )
            for j in jumps.tolist()
        ]
        events.sort(key=lambda e: e.t_s)
        acc_c, gyr_c = num[:, 1:4].astype(np.int32), num[:, 4:7].astype(np.int32)
        extra = base_extra | {
            "source_unit": "counts (a.u.)",
            "scale": "inferred: 2048 counts/g (+-16 g), 16.384 counts/(deg/s) (+-2000 deg/s)",
        }
        meta = SessionMeta(
            source="import:imucal",
            chip="unknown (imucal example, 16-bit)",
            accel_range_g=16.0,
            gyro_range_dps=2000.0,
            accel_lsb_per_g=IMUCAL_ACCEL_LSB_PER_G,
            gyro_lsb_per_dps=IMUCAL_GYRO_LSB_PER_DPS,
            sample_rate_hz=fs,
            protocol="ferraris",
            extra=extra,
        )
        return Session(
            meta=meta,
            t_s=t,
            sample_index=idx,
            accel_g=acc_c / IMUCAL_ACCEL_LSB_PER_G,
            accel_counts=acc_c,
            gyro_dps=gyr_c / IMUCAL_GYRO_LSB_PER_DPS,
            gyro_counts=gyr_c,
            poses=poses,
            events=events,
            path=str(path),
        )
    raise InputError(
        "not an imucal file: expected header 'n_samples,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z' "
        "or 'part,samples,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z'",
        where=f"{path}:1",
    )


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
    lines = _lines(path)
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
    cols = _read_table(path, lines, 2, names, strings=strings, optional=_CSV_OPTIONAL)
    t = cols["t"]
    n = t.shape[0]
    _check_time(path, lines, 2, t)
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
            no = _line_of_row(lines, 2, int(frac[0]))
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
        sample_rate_hz=_rate_hz(t),
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
        where = f"{path}:{_line_of_row(lines, 2, s)}"
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
                    no = _line_of_row(lines, 2, s + int(diff[0]))
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
        poses.append(PoseLabel(name, float(t[s]), _hold_end(t, e), up, q, len(poses)))
    return poses


def import_file(kind: str, path: str | Path, **options) -> Session:
    """Dispatch: kind 'capstone' | 'imucal' | 'csv' (options passed on)."""
    if kind == "capstone":
        return import_capstone(path)
    if kind == "imucal":
        return import_imucal(path, **options)
    if kind == "csv":
        return import_csv(path, **options)
    raise InputError(f"unknown import kind {kind!r}: use capstone, imucal or csv")
